"""``make demo`` end to end (shortened): the offline demo's four steps run and leave their outputs."""

from training.__main__ import main


def test_demo_runs_the_whole_loop(tmp_path, capsys):
    assert main(["demo", "--out", str(tmp_path), "--days", "3"]) == 0
    out = capsys.readouterr().out
    for step in ("1/4 simulate", "2/4 calibrate", "3/4 replay", "4/4 diagnose"):
        assert step in out
    for name in ("almeria.csv", "params.toml", "replay.png", "predictions.csv",
                 "diagnosis/report.md"):
        assert (tmp_path / name).stat().st_size > 0
