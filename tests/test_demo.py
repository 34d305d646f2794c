"""``make demo`` end to end (shortened): the offline demo's four steps run and leave their outputs."""

import pytest

from training.__main__ import main

QUICK = ["--set", "t_in.iterations=2", "--set", "t_in.bats=4", "--set", "t_in.every=15",
         "--set", "i_in.iterations=2", "--set", "i_in.bats=4"]
"""A quicker replay (step 3 at the default 50 iterations × 20 bats was over 2/3 of this test's
141 s, 57 s at 10 × 20, 21 s at 2 × 4, the vsensor tests' budget; at 2 × 4 the air's search at
every sample was still 32 of the 57 s of the loop, 13 s when it runs every 15th sample); what
the test checks is that the four steps run and leave their outputs, not the replay's error."""


def test_demo_runs_the_whole_loop(tmp_path, capsys, monkeypatch):
    import gateway.cli

    calls, real = [], gateway.cli.main

    def spy(argv):  # the real command, its arguments noted
        calls.append(argv)
        return real(argv)

    monkeypatch.setattr(gateway.cli, "main", spy)
    assert main(["demo", "--out", str(tmp_path), "--days", "3", *QUICK]) == 0
    assert [c[0] for c in calls] == ["calibrate", "replay", "diagnose"]
    assert " ".join(QUICK) in " ".join(calls[1])  # the settings reach the replay alone
    assert "--set" not in calls[0] + calls[2]
    out = capsys.readouterr().out
    for step in ("1/4 simulate", "2/4 calibrate", "3/4 replay", "4/4 diagnose"):
        assert step in out
    for name in ("almeria.csv", "params.toml", "replay.png", "predictions.csv",
                 "diagnosis/report.md"):
        assert (tmp_path / name).stat().st_size > 0


def test_the_change_follows_the_length():
    """The undeclared heater starts at 41/72 of the length: 16:40 on day 6 of the default 10."""
    from training.demo import DAYS, effect_spec

    assert DAYS == 10
    assert effect_spec(10) == "heater@2009-10-31T16:40:power=25"  # 5.69 d
    assert effect_spec(6) == "heater@2009-10-29T10:00:power=25"  # 3.42 d
    assert effect_spec(3) == "heater@2009-10-27T17:00:power=25"  # 1.71 d


def test_demo_help_says_the_length_and_the_change(capsys):
    with pytest.raises(SystemExit):
        main(["demo", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "simulate 10 days" in text and "2009-10-31T16:40Z" in text and "heater" in text


@pytest.mark.parametrize("argv, says", [
    (["--days", "0"], "must be at least 3"),
    (["--days", "nan"], "must be at least 3"),
    (["--days", "two"], "not a number"),
])
def test_demo_refuses_a_bad_length(argv, says, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["demo", *argv])
    assert exc.value.code == 2 and says in capsys.readouterr().err


@pytest.mark.parametrize("item, says", [("t_in.windw=3", "unknown key 'windw'"),
                                         ("t_in.iterations", "OUTPUT.KEY=NUMBER")])
def test_demo_refuses_a_bad_setting_before_it_simulates(item, says, tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["demo", "--out", str(tmp_path / "demo"), "--set", item])
    assert exc.value.code == 2 and says in capsys.readouterr().err
    assert not (tmp_path / "demo").exists()


def test_demo_refuses_an_out_that_is_a_file(tmp_path, capsys):
    f = tmp_path / "file.txt"
    f.write_text("x")
    for out in (f, f / "sub"):
        with pytest.raises(SystemExit) as exc:
            main(["demo", "--out", str(out)])
        assert exc.value.code == 2 and "exists and is not a folder" in capsys.readouterr().err
