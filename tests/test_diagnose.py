"""Diagnosis (issue 4) on the reference simulator's data with undeclared effects.

Each case simulates 6 days on synthetic Almería weather (seed 2), injects one effect 3.6 days
in (inside the held-out half), resamples to 5 min to keep the suite fast, and runs the whole
diagnosis. The requirement: the first finding names the effect (or its documented equivalent,
docs/effects.md) and cuts the held-out free-run MAE by at least 30 %.

The 6-day cases test the library's naming and start times, not the judge's level, and run with
the piece judge (``piece_judge``): a change at day 3.6 leaves 2 held-out days, on which the
shipped day test cannot judge anything (``judge.MIN_DAYS``). The day test itself is checked on
10-day records with the change at day 5.6 (``test_day_test_names_the_effect_on_ten_days``).
"""

from __future__ import annotations

import copy
import functools

import numpy as np
import pytest

from gateway.diagnose import EFFECTS, diagnose, to_json
from gateway.diagnose import judge as jd
from gateway.diagnose.effects import LIBRARY
from gateway.greenhouse import load_greenhouse
from gateway.model import build_model
from gateway.series import load_series
from training.simulate import simulate

STEP = 300.0
DAYS = 6
LONG_DAYS, LONG_AT = 10, 5.6
"""The day test's records: 10 days, the change at day 5.6 (4.4 held-out days after it)."""
PRESET = {"almeria": "almeria-palmerillas", "prototype": "biskra-prototype"}
EQUIVALENT = {
    "cover_transmission": {"solar_gain_change"},
    "extra_leakage": {"extra_ventilation"},
    "heater": {"heat_source", "night_heat_source"},
    "thermal_mass": {"thermal_mass", "heat_store_added"},
    "sensor_radiation_bias": {"sensor_radiation_bias"},
    "sensor_drift": {"sensor_drift"},
}
"""Simulator effect → library effect(s) that count as naming it (docs/effects.md)."""
SPECS = {
    "cover_transmission": {"almeria": "factor=0.5", "prototype": "factor=0.5"},
    "extra_leakage": {"almeria": "ach=4", "prototype": "ach=30"},
    "heater": {"almeria": "power=25", "prototype": "power=25"},
    "thermal_mass": {"almeria": "factor=3", "prototype": "factor=10"},
    "sensor_radiation_bias": {"almeria": "k=0.006", "prototype": "k=0.006"},
    "sensor_drift": {"almeria": "rate=0.5", "prototype": "rate=0.5"},
}
"""Effect sizes a grower would care about (docs/effects.md, "Effect sizes in the tests"):
whitewash halving the transmission; both doors of the 877 m2 house open (4 air changes per
hour) or the 0.76 m3 box's door ajar (30 h-1, about 6 L/s); a 25 W m-2 heater (22 kW for the
Almería house, 17 W for the box); water barrels tripling the Almería air+fast-mass capacity
(+20 kJ m-2 K-1, 5 L of water per m2) or 6 L of water jugs in the box (x 10); an unshielded
sensor (+3 to +5 K at noon); a sensor drifting 0.5 K per day."""
# Cases the diagnosis does not yet get right on this data: kept as expected failures so that
# the suite shows them, not hides them (docs/effects.md, "Known limits").
KNOWN_MISSES: set[tuple[str, str]] = {("almeria", "sensor_drift")}
"""sensor_drift/almeria: with 3 held-out days the drift's cut (29 %) is not significant (one-
sided p = 0.08 over the 8 pieces after its start: a ramp from zero gives few pieces of gain);
the issue-10 judge asks p ≤ 0.05 (docs/effects.md, "How the diagnosis decides"). Before it,
extra_leakage/prototype was one until the base could take the night-time deficit as a long-
wave loss to the sky instead of a constant sensor offset (docs/effects.md, "Base structure")."""
START_TOLERANCE_H = {"sensor_drift": 18.0, "thermal_mass": 6.0}
"""How far the estimated start may be from the truth [h]: 3 h for a step; a ramp starts from
zero and only rises above the 0.1 K resolution hours later (0.5 K/d: 5 h), so its start is
less sharp; a capacity change shows only while the temperature swings (the reported start is
the best-fitting one, 3.2 h early on Almería)."""


@pytest.fixture
def piece_judge(monkeypatch):
    """The judge on 6-hour pieces (``judge.DAY_TEST`` off) for the 6-day records: they test the
    library's naming and starts, and the shipped day test needs ``judge.MIN_DAYS`` held-out
    days after a change where these leave 2 (docs/effects.md, "What switching it on costs on
    short records")."""
    monkeypatch.setattr(jd, "DAY_TEST", False)


@functools.cache
def _clean(plant: str, days: int):
    """The clean record: one simulation per plant and length per worker, whose first time every
    case reads and which the effect-free cases take (a copy each: ``post`` may change it)."""
    return simulate(plant=plant, weather="almeria", days=days, seed=2, step=60)


def _first_time(plant: str, days: int) -> np.datetime64:
    """The clean record's first time (it was simulated again for every case only to read this)."""
    return _clean(plant, days).time[0]


def _data(tmp_path, plant: str, effect: str | None, post=None, at: float = 3.6,
          days: int | None = None):
    days = DAYS if days is None else days  # read at call time (day_test_study.py sets DAYS)
    t0 = str(_first_time(plant, days) + np.timedelta64(int(at * 86400), "s"))
    if effect is None:  # the clean record, simulated once (the same call without effects)
        r = copy.deepcopy(_clean(plant, days))
    else:
        r = simulate(plant=plant, weather="almeria", days=days, seed=2, step=60,
                     effects=[f"{effect}@{t0}:{SPECS[effect][plant]}"])
    if post is not None:
        post(r)
    path = tmp_path / f"{plant}.csv"
    r.write(path)
    gh = load_greenhouse(PRESET[plant])
    model = build_model(plant, gh)
    return load_series(path, step=STEP, required=model.requires), gh, model, t0


@pytest.fixture(scope="module")
def whitened_prototype(tmp_path_factory):
    """(series, gh, model, t0, diagnosis) of the 6-day prototype record whitened at day 3.6,
    diagnosed with the piece judge: computed once for the two tests that only read it (its
    first-finding case and the public-entry round, which compares its search with it)."""
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(jd, "DAY_TEST", False)  # as ``piece_judge``
        series, gh, model, t0 = _data(tmp_path_factory.mktemp("whitened"), "prototype",
                                      "cover_transmission")
        return series, gh, model, t0, diagnose(series, gh, model)


def test_library_is_documented_and_bounded():
    text = open("docs/effects.md", encoding="utf-8").read()
    for e in LIBRARY:
        assert f"`{e.name}`" in text, e.name
        assert e.lower <= e.neutral <= e.upper
    for names in EQUIVALENT.values():
        assert names <= set(EFFECTS)


@pytest.mark.slow
@pytest.mark.usefixtures("piece_judge")
@pytest.mark.parametrize("plant", ["almeria", "prototype"])
@pytest.mark.parametrize("effect", list(SPECS))
def test_injected_effect_is_first_finding(tmp_path, plant, effect, request):
    if (plant, effect) in KNOWN_MISSES:
        request.applymarker(pytest.mark.xfail(reason="known miss, see docs/effects.md", strict=False))
    if (plant, effect) == ("prototype", "cover_transmission"):  # the record the next tests use
        series, gh, model, t0, d = request.getfixturevalue("whitened_prototype")
    else:
        series, gh, model, t0 = _data(tmp_path, plant, effect)
        d = diagnose(series, gh, model)
    assert d.findings, f"nothing found; rejected: {d.rejected}"
    first = d.findings[0]
    assert first.effect.name in EQUIVALENT[effect]
    gain = 1.0 - d.after["free_run"]["mae"] / d.before["free_run"]["mae"]
    assert gain >= 0.30, f"held-out free-run MAE only cut by {gain:.0%}"
    # the start time is estimated near the truth
    assert first.start is not None
    lag = abs(np.datetime64(first.start.rstrip("Z")) - np.datetime64(t0)) / np.timedelta64(1, "h")
    assert lag <= START_TOLERANCE_H.get(effect, 3.0)


@pytest.mark.slow
@pytest.mark.parametrize(("plant", "effect"), [
    ("almeria", "heater"), ("prototype", "heater"), ("almeria", "cover_transmission"),
    ("prototype", "cover_transmission")])
def test_day_test_names_the_effect_on_ten_days(tmp_path, plant, effect):
    """The judge as shipped (``judge.DAY_TEST``) on 10-day records, the change at day 5.6: the
    first finding names it, significant over the held-out days after its start, its start
    within 3 h (measured on all 12 cases: right first in 9 of 12, the heaters at day p 0.003
    and 0.010, the whitewash 0.003 and 0.008; docs/effects.md, "What switching it on costs on
    short records")."""
    assert jd.DAY_TEST
    truth = {}
    series, gh, model, t0 = _data(tmp_path, plant, effect, at=LONG_AT, days=LONG_DAYS,
                                  post=lambda r: truth.update(r.series))
    d = diagnose(series, gh, model)
    assert d.findings, f"nothing found; rejected: {d.rejected}"
    first = d.findings[0]
    assert first.effect.name in EQUIVALENT[effect]
    if effect == "heater":
        # what the temperatures fix is the warming rate P / C, not P (the base is scale-free):
        # within 35 % of the simulator's 25 W m-2 into its air + fast-mass node (measured:
        # +25 % almeria, -24 % prototype, where P itself is +18 % and -60 %)
        rate = 25.0 * 3600.0 / float(np.nanmedian(truth["cap_air"]))
        assert abs(first.heating_rate / rate - 1.0) <= 0.35, (first.heating_rate, rate)
        assert to_json(d)["findings"][0]["heating_rate_K_per_h"] == first.heating_rate
    kept = next(t for t in d.trials if t["effect"] == first.effect.name and t["ok"])
    assert kept["p"] == kept["p_days"] <= jd.ALPHA and len(kept["day_means"]) >= 4, kept
    assert 1.0 - d.after["free_run"]["mae"] / d.before["free_run"]["mae"] >= 0.30
    lag = abs(np.datetime64(first.start.rstrip("Z")) - np.datetime64(t0)) / np.timedelta64(1, "h")
    assert lag <= 3.0


@pytest.mark.slow
@pytest.mark.parametrize(("plant", "effect"), [
    pytest.param("almeria", "cover_transmission", marks=pytest.mark.xfail(
        reason="the base chosen on the inner validation split (days 2-3 all whitened) carries "
               "the change: held-out MAE 0.225 K without it, the clean-data level; docs/effects.md",
        strict=False)),
    ("prototype", "sensor_radiation_bias")])
def test_effect_starting_in_the_calibration_part(tmp_path, plant, effect):
    """An effect from day 1.5 contaminates the base calibration (first 3 days); the joint refit
    with the effect still names it, with its start, and cuts the held-out error."""
    series, gh, model, t0 = _data(tmp_path, plant, effect, at=1.5)
    d = diagnose(series, gh, model)
    assert d.findings and d.findings[0].effect.name in EQUIVALENT[effect], d.rejected
    assert 1.0 - d.after["free_run"]["mae"] / d.before["free_run"]["mae"] >= 0.30
    lag = abs(np.datetime64(d.findings[0].start.rstrip("Z")) - np.datetime64(t0))
    assert lag / np.timedelta64(1, "h") <= 3.0


@pytest.mark.slow
@pytest.mark.parametrize("plant", ["almeria", "prototype"])
def test_no_effect_never_makes_heldout_worse(tmp_path, plant):
    series, gh, model, _ = _data(tmp_path, plant, None)
    d = diagnose(series, gh, model)
    assert d.after["free_run"]["mae"] <= d.before["free_run"]["mae"] + 1e-12
    assert d.after["one_step"]["mae"] <= 1.2 * d.before["one_step"]["mae"]
    out = to_json(d)
    assert set(out) >= {"findings", "before", "after", "unexplained"}
    assert set(out["before"]["free_run"]) == {"mae", "rmse", "maxae", "r2", "ef"}


def _misting(r) -> None:
    """An effect not in the library: misting bursts at 11:00 and 15:00 UTC from day 3.6, each
    cooling the air by 2.5 K and relaxing with a 20-minute time constant (both readings)."""
    t = r.time.astype("datetime64[m]").astype(np.int64)
    minute = t % 1440
    start = t[0] + int(3.6 * 1440)
    pulse = np.zeros(len(t))
    for clock in (11 * 60, 15 * 60):
        since = (minute - clock) % 1440
        pulse += np.where((since < 120) & (t >= start), -2.5 * np.exp(-since / 20.0), 0.0)
    r.columns["t_in"] = np.round(r.columns["t_in"] + pulse, 1)


@pytest.mark.slow
def test_effect_outside_library_is_reported_unexplained(tmp_path):
    series, gh, model, _ = _data(tmp_path, "almeria", None, post=_misting)
    d = diagnose(series, gh, model)
    assert d.unexplained, d.signature
    assert "time-of-day" in d.signature


@pytest.mark.usefixtures("piece_judge")
def test_a_round_through_the_public_entry_is_the_diagnosis_first(whitened_prototype):
    """``search.prepare`` and ``search.search_round`` (the entry tests/generality/headroom.py
    replays the search through) on the 6-day prototype record whitened at day 3.6: the round
    tries what the diagnosis's first round tried, with the same verdicts, and picks its first
    finding, which ``search.keep`` reports as the diagnosis does. With ``every`` a candidate the
    search would not try (ranking ΔBIC ≥ 0) comes back too, never passed; ``try_effect`` with
    ``at`` holds the start there."""
    from gateway.diagnose import search

    series, gh, model, _, d = whitened_prototype
    st = search.prepare(series, gh, model).state
    r = search.search_round(st, LIBRARY)
    assert [(t.effect.name, t.verdict.ok, t.verdict.delta_bic) for t in r.tried] == [
        (t["effect"], t["ok"], t["delta_bic"]) for t in d.trials if t["round"] == 1]
    assert r.best is not None and r.best.effect is d.findings[0].effect
    worst, worst_dbic = r.ranked[-1]
    assert worst_dbic >= 0
    assert not search.search_round(st, [worst.effect]).tried
    (late,) = search.search_round(st, [worst.effect], tries=None, every=True).tried
    assert late.rank_dbic == worst_dbic and not late.passed and late.pred["free_run"].shape
    at = r.best.starts[0] + 3600.0
    assert search.try_effect(st, r.best.effect, r.reference, at=at).starts == [at, at]
    kept = search.keep(st, r.best, series)
    assert kept.to_json() == d.findings[0].to_json()
    assert st.effects == [r.best.effect] and st.current_pred is r.best.pred


@pytest.mark.usefixtures("piece_judge")  # in process: the 6-day record needs the piece judge
def test_cli_json_and_report(tmp_path, capsys):
    import json

    from gateway.cli import main

    series, gh, model, _ = _data(tmp_path, "prototype", "cover_transmission")
    rc = main(["diagnose", "--data", str(tmp_path / "prototype.csv"), "--greenhouse",
               "biskra-prototype", "--model", "prototype", "--step", "300", "--json",
               "--report", str(tmp_path / "rep")])
    assert rc == 0
    out = json.loads(capsys.readouterr().out)
    from gateway.cli.diagnose import live_model_hint

    # the JSON's hint is the one the reported base structure gives (a string or null)
    assert out["hint"] == live_model_hint("prototype", out["base_structure"])
    assert out["findings"][0]["effect"] == "solar_gain_change"
    assert out["findings"][0]["params"]["d_solar"] < -0.3
    assert out["after"]["free_run"]["mae"] < out["before"]["free_run"]["mae"]
    for name in ("report.md", "residual.png", "hour_of_day.png", "effects.png"):
        assert (tmp_path / "rep" / name).stat().st_size > 0
    assert "solar gain fell" in (tmp_path / "rep" / "report.md").read_text(encoding="utf-8")


def test_a_kept_vent_controller_points_the_live_estimator_to_the_vented_model():
    from gateway.cli.diagnose import live_model_hint

    log = [{"structure": "base", "kept": True}, {"structure": "vent controller", "kept": True}]
    hint = live_model_hint("prototype", log)
    assert hint is not None and "--model prototype+vent_control" in hint
    assert live_model_hint("prototype+vent_control", log) is None  # already carries it
    log[1]["kept"] = False
    assert live_model_hint("prototype", log) is None


def test_cli_bad_split(tmp_path, capsys):
    from gateway.cli import main

    _data(tmp_path, "prototype", None)
    rc = main(["diagnose", "--data", str(tmp_path / "prototype.csv"), "--greenhouse",
               "biskra-prototype", "--model", "prototype", "--split", "0.99"])
    assert rc == 2
    assert "--split" in capsys.readouterr().err
