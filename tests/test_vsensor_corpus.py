"""The vsensor corpus's third climate (Sevilla, opt-in ``HOT_DRY``; docs/vsensor.md, eleventh
pass; its winter run, twelfth pass): its synthetic weather against the normals it was set from,
month by month and over each run's own days, the runs written only when asked, and their own
site x season groups."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from training.simulate.weather import synthetic
from training.vsensor import corpus
from training.vsensor import holdout_groups as hg
from training.vsensor.cli import main as vsensor_main

# AEMET normals 1981-2010, Sevilla Aeropuerto: monthly mean, mean daily max, mean daily min [°C].
AEMET_SEVILLA = {"2021-01-01": (10.9, 16.0, 5.7), "2021-07-01": (28.2, 36.0, 20.3)}


@pytest.mark.parametrize("start", sorted(AEMET_SEVILLA))
def test_sevilla_weather_has_the_normals_monthly_means(start):
    """January and July over 8 seeds: the monthly mean and the mean daily max and min within
    1.5 K of the normals. The day-to-day anomaly is a random walk (0.72 K a day), so one 31-day
    month's mean spreads by ~2 K; over 8 seeds ~0.7 K, and 1.5 K is about two of those."""
    days = 31
    got = []
    for seed in range(8):
        t = synthetic("seville", np.datetime64(start), float(days), seed=seed).t_out
        daily = t.reshape(days, -1)
        got.append((t.mean(), daily.max(axis=1).mean(), daily.min(axis=1).mean()))
    np.testing.assert_allclose(np.mean(got, axis=0), AEMET_SEVILLA[start], atol=1.5)


def normals_of(run: corpus.Run) -> tuple[float, float, float] | None:
    """The AEMET normals of the month ``run`` starts in (None: a month the table does not have)."""
    return next((v for k, v in AEMET_SEVILLA.items() if k[:7] == run.start[:7]), None)


@pytest.mark.parametrize("run", [r for r in corpus.HOT_DRY if normals_of(r) is not None],
                         ids=lambda r: r.name)
def test_hot_dry_runs_days_have_their_months_normals(run):
    """A run's own days (6 of them, not the month) over 8 seeds: mean, mean daily max and min
    within 1.5 K of its month's normals (one seed's 6-day window spreads by ~1.1 K, 8 seeds' mean
    by ~0.4 K), and the run's own seed within 3.5 K (three of that one-seed spread): the file is
    plausibly that month at Sevilla, not merely the climate's average."""
    normals = normals_of(run)

    def stats(seed: int) -> tuple[float, float, float]:
        t = synthetic(run.weather, np.datetime64(run.start), float(run.days), seed=seed).t_out
        daily = t.reshape(int(run.days), -1)
        return t.mean(), daily.max(axis=1).mean(), daily.min(axis=1).mean()

    np.testing.assert_allclose(np.mean([stats(s) for s in range(8)], axis=0), normals, atol=1.5)
    np.testing.assert_allclose(stats(run.seed), normals, atol=3.5)


def fake_generate(run: corpus.Run, path: Path) -> Path:
    """Stands in for the simulator: the file says which run it is."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(f"{run.weather}\n", encoding="utf-8")
    return path


def written(root: Path) -> dict[str, list[str]]:
    return {d.name: sorted(p.stem for p in d.glob("*.csv")) for d in sorted(root.iterdir())}


def test_corpus_writes_the_hot_dry_runs_only_when_asked(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(corpus, "generate", fake_generate)
    assert vsensor_main(["corpus", "--out", str(tmp_path / "plain")]) == 0
    plain = written(tmp_path / "plain")
    assert "hot-dry" not in plain
    assert plain["train"] == sorted(r.name for r in corpus.TRAIN)
    assert not any("seville" in stem for stems in plain.values() for stem in stems)

    assert vsensor_main(["corpus", "--out", str(tmp_path / "all"), "--hot-dry"]) == 0
    every = written(tmp_path / "all")
    assert every.pop("hot-dry") == sorted(r.name for r in corpus.HOT_DRY)
    assert every == plain  # the other parts, train/ above all, are the same with the flag
    assert all((tmp_path / "all" / "hot-dry" / f"{r.name}.csv").read_text() == "seville\n"
               for r in corpus.HOT_DRY)

    for run in corpus.HOT_DRY:  # an opt-in run is not known without the flag, alone with it
        name, out = run.name, tmp_path / run.name
        assert vsensor_main(["corpus", "--out", str(out), "--only", name]) == 2
        assert f"no run named {name}" in capsys.readouterr().err
        assert vsensor_main(["corpus", "--out", str(out), "--only", name, "--hot-dry"]) == 0
        assert written(out) == {"hot-dry": [name]}


def test_hot_dry_runs_are_their_own_groups_and_never_the_test_site_or_season():
    groups = [hg.group_of(r.name) for r in corpus.HOT_DRY]
    assert groups == ["seville-summer", "seville-autumn", "seville-winter"]
    assert len(set(groups)) == len(groups)  # one run per season: no group of two
    train_groups = {hg.group_of(r.name) for r in corpus.TRAIN}
    assert not train_groups & {hg.group_of(r.name) for r in corpus.HOT_DRY}
    assert not set(corpus.HOT_DRY) & set(corpus.TRAIN + corpus.TEST + corpus.FRESH + corpus.OTHER)
    assert all(r.weather == "seville" and "spring" not in r.name for r in corpus.HOT_DRY)
    assert set(corpus.UTC_OFFSET) >= {r.weather for r in corpus.HOT_DRY}


def test_more_test_runs_are_new_draws_of_the_test_site_and_season_written_only_when_asked(
        tmp_path, monkeypatch):
    """``MORE_TEST`` (docs/vsensor.md, "More Biskra spring files"): the test group only, new seeds
    and days, in no other part, and written to ``more-test/`` only with ``--more-test``."""
    test_groups = {hg.group_of(r.name) for r in corpus.TEST}
    assert {hg.group_of(r.name) for r in corpus.MORE_TEST} == test_groups == {"biskra-spring"}
    others = corpus.TRAIN + corpus.TEST + corpus.FRESH + corpus.OTHER + corpus.HOT_DRY
    assert not {r.seed for r in corpus.MORE_TEST} & {r.seed for r in others}
    assert not {r.start for r in corpus.MORE_TEST} & {r.start for r in corpus.TEST}
    assert {hg.vents_of(r.name) for r in corpus.MORE_TEST} == {"grower", "controller"}
    assert all(r.start[5:7] in ("03", "04", "05") for r in corpus.MORE_TEST)  # spring months

    monkeypatch.setattr(corpus, "generate", fake_generate)
    assert vsensor_main(["corpus", "--out", str(tmp_path / "plain")]) == 0
    assert "more-test" not in written(tmp_path / "plain")
    assert vsensor_main(["corpus", "--out", str(tmp_path / "all"), "--more-test"]) == 0
    every = written(tmp_path / "all")
    assert every.pop("more-test") == sorted(r.name for r in corpus.MORE_TEST)
    assert every == written(tmp_path / "plain")
