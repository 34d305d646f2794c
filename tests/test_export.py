"""Store → kit CSV (``python -m gateway export``): simulated kit records stored through the ingest
write path in a real SQLite file, exported, read back by the kit CSV reader and used by a tool."""

from __future__ import annotations

import json
import sqlite3
from pathlib import Path

import numpy as np
import pytest

from gateway import protocol as p
from gateway.cli import main
from gateway.kitcsv import read_kit_csv
from gateway.store import Store
from tests.cli_mistakes_common import one_error_line
from training.simulate import simulate

STUCK = slice(600, 640)  # 40 minutes of a frozen inside reading
SPIKE = 900


@pytest.fixture(scope="module")
def kit() -> tuple[np.ndarray, dict[str, np.ndarray]]:
    r = simulate(plant="prototype", weather="biskra", days=1, seed=4, step=60)
    cols = {c: np.array(r.columns[c], dtype=float) for c in p.CHANNELS if c in r.columns}
    cols.setdefault("rain", np.zeros(len(r.time)))
    cols["t_in"][STUCK] = cols["t_in"][STUCK.start] + 0.37  # a value no neighbour has
    cols["t_in"][SPIKE] += 12.0
    return r.time, cols


def store_records(db: Path, time: np.ndarray, cols: dict[str, np.ndarray], device: int = 7) -> None:
    """One record per minute, stamped mid-minute by the gateway, as the ingest writer stores it."""
    seconds = time.astype("datetime64[s]").astype(np.int64)
    items = []
    for k, t in enumerate(seconds):
        values = tuple(None if not np.isfinite(cols[c][k]) else float(cols[c][k]) for c in p.CHANNELS)
        status = tuple(p.ST_TIMEOUT if v is None else p.ST_OK for v in values)
        items.append((p.Record(device, 1, k, k * 60_000, 0, 60.0, values, status), float(t) + 30.0))
    store = Store(db)
    try:
        for a in range(0, len(items), 500):  # batches, like the ingest service
            store.write_batch(items[a : a + 500])
    finally:
        store.close()


def test_export_round_trip_with_qc_and_a_tool_reads_it(tmp_path, kit, capsys):
    time, cols = kit
    db, out = tmp_path / "g.db", tmp_path / "kit.csv"
    store_records(db, time, cols)
    assert main(["export", "--db", str(db), "--out", str(out), "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["device"] == 7 and report["rows"] == len(time)
    assert report["aggregated"] == len(time)  # nothing was aggregated before: caught up first
    # the frozen sensor: flagged from its 30th identical minute on; the +12 K jump: a spike
    # (and the minute after it, which jumps back)
    assert report["dropped"]["t_in"]["stuck"] == STUCK.stop - STUCK.start - 29
    assert report["dropped"]["t_in"]["spike"] == 2
    data = read_kit_csv(out)
    np.testing.assert_array_equal(data.time, time.astype("datetime64[s]"))
    got, want = data.columns["t_in"], cols["t_in"]
    blank = ~np.isfinite(got)
    assert blank[STUCK.start + 29 : STUCK.stop].all() and blank[SPIKE]
    both = np.isfinite(want) & ~blank
    np.testing.assert_allclose(got[both], want[both], atol=1e-4)
    for c in ("rh_in", "t_out", "i_glob", "wind"):
        ok = np.isfinite(cols[c])
        np.testing.assert_allclose(data.columns[c][ok], cols[c][ok], rtol=1e-5, atol=1e-4)
        assert (np.isfinite(data.columns[c]) == ok).all()  # failed reads stay missing
    # what the kit stored goes straight into the tools
    assert main(["calibrate", "--data", str(out), "--greenhouse", "biskra-prototype", "--model",
                 "prototype", "--iterations", "5", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["metrics"]["calibration"]["one_step"]["n"] > 1000
    with sqlite3.connect(db) as c:  # the export changed no sample
        assert c.execute("SELECT count(*) FROM samples").fetchone()[0] == len(time)


def test_export_span_and_device_choice(tmp_path, kit, capsys):
    time, cols = kit
    db, out = tmp_path / "g.db", tmp_path / "kit.csv"
    store_records(db, time[:120], {c: v[:120] for c, v in cols.items()}, device=7)
    store_records(db, time[:60], {c: v[:60] for c, v in cols.items()}, device=9)
    assert main(["export", "--db", str(db), "--out", str(out)]) == 2
    assert "2 devices (7, 9): pick one with --device" in capsys.readouterr().err
    assert main(["export", "--db", str(db), "--out", str(out), "--device", "8"]) == 2
    assert "no device 8 in the store (devices: 7, 9)" in capsys.readouterr().err
    t0 = str(time[30]) + "Z"
    t1 = str(time[90]) + "+00:00"
    assert main(["export", "--db", str(db), "--out", str(out), "--device", "7",
                 "--from", t0, "--to", t1]) == 0
    assert "60 minutes" in capsys.readouterr().out
    assert len(read_kit_csv(out).time) == 60
    assert main(["export", "--db", str(db), "--out", str(out), "--device", "9", "--from",
                 str(time[100]) + "Z"]) == 2
    assert "device 9: no minute in the span" in capsys.readouterr().err
    assert main(["export", "--db", str(tmp_path / "none.db"), "--out", str(out)]) == 2
    assert "no such store" in capsys.readouterr().err
    assert not (tmp_path / "none.db").exists()  # not created by a typo
    assert main(["export", "--db", str(db), "--out", str(out), "--from", "yesterday"]) == 2
    assert "--from: bad time 'yesterday'" in capsys.readouterr().err



def test_export_span_without_an_offset_is_utc_as_in_calibrate_on(tmp_path, kit, capsys):
    time, cols = kit
    db, out = tmp_path / "g.db", tmp_path / "kit.csv"
    store_records(db, time[:120], {c: v[:120] for c, v in cols.items()})
    t0, t1 = str(time[30])[:16], str(time[90])[:16]  # 2009-...T00:30, no offset, no seconds
    assert main(["export", "--db", str(db), "--out", str(out), "--from", t0, "--to", t1]) == 0
    assert "60 minutes" in capsys.readouterr().out
    assert str(read_kit_csv(out).time[0]) == str(time[30])
    day = str(time[0])[:10]  # a date alone is its midnight UTC: the whole stored span
    assert main(["export", "--db", str(db), "--out", str(out), "--from", day]) == 0
    assert "120 minutes" in capsys.readouterr().out
    assert main(["export", "--db", str(db), "--out", str(out), "--to", "2009-1-5"]) == 2
    assert one_error_line(capsys) == ("error: --to: bad time '2009-1-5': not an ISO 8601 date or "
                                      "time, e.g. 2026-03-01 or 2026-03-01T06:00Z")


def test_export_says_its_rows_are_minute_means_and_how_calibrate_reads_them(tmp_path, kit, capsys):
    """calibrate reads rows as instants unless told (--sampling mean); the export, whose rows are
    minute means, said nothing of it (docs/data-format.md, docs/model.md)."""
    time, cols = kit
    db, out = tmp_path / "g.db", tmp_path / "kit.csv"
    store_records(db, time[:30], {c: v[:30] for c, v in cols.items()})
    assert main(["export", "--db", str(db), "--out", str(out)]) == 0
    captured = capsys.readouterr()
    assert captured.out.startswith(f"wrote {out}: device 7, 30 minutes")
    assert "each row is the mean over its minute: calibrate reads such rows with --sampling mean" \
        in captured.err

def test_export_of_a_partly_aggregated_store_equals_the_fully_aggregated_one(tmp_path, kit):
    """The read-only export computes the minutes the service has not aggregated yet in memory,
    with the same QC, across the boundary (here inside the frozen-sensor run)."""
    from gateway.store import aggregate as agg

    time, cols = kit
    db = tmp_path / "g.db"
    store_records(db, time, cols)
    store = Store(db)
    try:
        assert agg.aggregate(store.conn, max_rows=STUCK.start + 20) > 0  # the service, halfway
        assert main(["export", "--db", str(db), "--out", str(tmp_path / "part.csv")]) == 0
        while agg.aggregate(store.conn):
            pass
    finally:
        store.close()
    assert main(["export", "--db", str(db), "--out", str(tmp_path / "full.csv")]) == 0
    assert (tmp_path / "part.csv").read_bytes() == (tmp_path / "full.csv").read_bytes()


def test_export_out_dash_writes_the_csv_on_stdout_and_says_what_on_stderr(tmp_path, kit, capsys):
    """``--out -``: the kit CSV on stdout (a pipe into another tool), what was written on
    stderr; with --json the two would share stdout, so that is refused naming the options."""
    time, cols = kit
    db = tmp_path / "g.db"
    store_records(db, time, cols)
    assert main(["export", "--db", str(db), "--out", "-"]) == 0
    out, err = capsys.readouterr()
    (tmp_path / "piped.csv").write_text(out)
    assert len(read_kit_csv(tmp_path / "piped.csv")) == len(time)
    assert err.startswith(f"wrote the CSV on stdout: device 7, {len(time)} minutes")
    assert not (tmp_path / "-").exists() and not Path("-").exists()
    assert main(["export", "--db", str(db), "--out", "-", "--json"]) == 2
    assert capsys.readouterr().err.startswith("error: --out - with --json: ")
