"""What the daily diagnosis keeps of ``diagnose``'s notes: the exported CSV's path (a file in
the gateway's work folder, gone after the run) is not what the grower or the cloud should read;
the notes name the data as the greenhouse's last days instead."""

from __future__ import annotations

from pathlib import Path

from gateway.service.diagnosis import named_data


def test_the_exported_file_is_named_as_the_greenhouses_days(tmp_path: Path) -> None:
    path = tmp_path / "diagnosis-north.csv"
    notes = [{"code": "site_time_mismatch", "level": "warning",
              "message": f"{path}: daylight falls in the site's night (seen in {path})"},
             {"code": "short_heldout", "level": "note", "message": "3 held-out days"},
             {"code": "odd", "level": "note"}, "not a record"]
    named = named_data(notes, path, "north's last 1.8 days")
    assert named[0] == {"code": "site_time_mismatch", "level": "warning",
                        "message": "north's last 1.8 days: daylight falls in the site's night "
                                   "(seen in north's last 1.8 days)"}
    assert named[1:] == notes[1:]  # no path: as it was; a record without words or none: kept
    assert str(tmp_path) not in repr(named) and notes[0]["message"].startswith(str(path))
