"""The opt-in bagged judge (issue 10, rule bq; gateway/diagnose/bagging.py): off (``bags=0``) it
is main's diagnosis; with bags, every held-out prediction the judge and the report see is the
mean over the bags, each bag's state follows the search, and the run is deterministic.

The record is 8 days of sine weather on the prototype box (5-minute rows): its own model's free
run plus a slow wave it cannot fit and a 25 W m-2 heater from day 5 (inside the held-out half),
read at the DHT22's 0.1 K. Iterations are cut (``cheap``) to keep the tests short; the piece
judge is used (``judge.DAY_TEST`` off), as the 6-day diagnosis tests do (tests/test_diagnose.py),
so that the short held-out part can keep the heater.
"""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from gateway.diagnose import bagging, effect_fit, search, to_json
from gateway.diagnose import base as base_mod
from gateway.diagnose import judge as jd
from gateway.diagnose.effects import EFFECTS, compose
from gateway.diagnose.fit import drivers
from tests.diagnose_data import prototype_bases, sine_series

DAYS = 8
STEP = 300
HEATER_AT_S = 5 * 86400.0
LIBRARY = (EFFECTS["heat_source"], EFFECTS["sensor_drift"])
BAGS = 2


def record():
    """(series, greenhouse, base model) of the module docstring."""
    gh, base, m = prototype_bases()
    series = sine_series(n=DAYS * 86400 // STEP, step=STEP)
    x = drivers(series, gh)
    e = EFFECTS["heat_source"]
    truth = compose(m, [e], gh, float(x["_index"][-1]))
    theta = truth.defaults(gh)
    theta[truth.index(e.amp_name)], theta[truth.index(e.tau_name)] = 25.0, HEATER_AT_S
    t_in = truth.free_run(theta[None], x, gh, float(STEP))[0]
    t_in = np.round(t_in + 0.3 * np.sin(np.arange(len(t_in)) / 50.0), 1)
    return replace(series, columns={**series.columns, "t_in": t_in}), gh, base


def cheap(mp: pytest.MonkeyPatch) -> None:
    """Fewer iterations and one round (the tests check the plumbing, not the fits)."""
    mp.setattr(jd, "DAY_TEST", False)
    mp.setattr(base_mod, "BASE_ITERATIONS", 10)
    mp.setattr(base_mod, "OPTION_ITERATIONS", 5)
    mp.setattr(base_mod, "LM_ITERATIONS", 8)
    mp.setattr(effect_fit, "REFIT_LM_ITERATIONS", 6)
    mp.setattr(search, "MAX_EFFECTS", 1)


def plain(d) -> dict:
    """A diagnosis's JSON without its run time, with its trials and held-out predictions."""
    out = to_json(d)
    out.pop("seconds")
    out["trials"] = d.trials
    for name in ("pred_before", "pred_after"):
        out[name] = {k: v.tolist() for k, v in getattr(d, name).items()}
    return json.loads(json.dumps(out, default=str))


@pytest.fixture(scope="module")
def runs():
    """The record diagnosed as main (no ``bags``), with ``bags=0``, twice with ``bags=2``, and
    the bagged search replayed through the public steps (prepare, search_round, keep)."""
    series, gh, base = record()
    with pytest.MonkeyPatch.context() as mp:
        cheap(mp)
        main = search.diagnose(series, gh, base, library=LIBRARY)
        calls: list[int] = []
        inner = bagging.bases
        mp.setattr(bagging, "bases", lambda *a: calls.append(a[-2]) or inner(*a))
        off = search.diagnose(series, gh, base, library=LIBRARY, bags=0)
        off_calls = list(calls)
        bagged = [search.diagnose(series, gh, base, library=LIBRARY, bags=BAGS) for _ in (0, 1)]
        st = search.prepare(series, gh, base, bags=BAGS).state
        first = {k: v.copy() for k, v in st.current_pred.items()}
        bases = [b.current_pred for b in st.bags]
        rnd = search.search_round(st, LIBRARY)
        refs = [search.reference(b) for b in st.bags]
        if rnd.best is not None:
            search.keep(st, rnd.best, series)
    return {"main": main, "off": off, "off_calls": off_calls, "bagged": bagged, "state": st,
            "first": first, "bases": bases, "round": rnd, "refs": refs, "series": series}


def test_bags_off_is_mains_diagnosis(runs):
    """``bags=0`` never calibrates a bag and gives main's diagnosis to the last digit."""
    assert runs["off_calls"] == []
    assert plain(runs["off"]) == plain(runs["main"])


def test_bags_are_deterministic(runs):
    a, b = runs["bagged"]
    assert plain(a) == plain(b)


def test_the_report_is_the_mean_of_the_bags(runs):
    """The report's "before" is the mean of the bags' bases' free runs (on 5-minute data the
    report's grid is the fit grid), its "after" the mean of the bags' final models'; the bags'
    bases differ from each other and from main's."""
    d, st = runs["bagged"][0], runs["state"]
    bases = [p["free_run"] for p in runs["bases"]]
    assert len(st.bags) == BAGS and not np.allclose(bases[0], bases[1], equal_nan=True)
    main_base = runs["main"].pred_before["free_run"]
    assert not np.allclose(main_base, np.mean(bases, axis=0), equal_nan=True)
    np.testing.assert_allclose(d.pred_before["free_run"], np.mean(bases, axis=0), rtol=1e-12)
    np.testing.assert_array_equal(runs["first"]["free_run"], np.mean(bases, axis=0))
    finals = [b.current_pred["free_run"] for b in st.bags]
    np.testing.assert_allclose(d.pred_after["free_run"], np.mean(finals, axis=0), rtol=1e-12)
    assert [f.to_json() for f in d.findings] == [f.to_json() for f in st.findings]


def test_the_judge_sees_the_bags_mean_and_main_stays_the_spine(runs, monkeypatch):
    """Every candidate's prediction and the reference are the bags' means; its starts and ΔBIC
    are main's fits'; a kept candidate is kept in every bag (its bag fit the bag's model)."""
    monkeypatch.setattr(jd, "DAY_TEST", False)  # as the round was judged (``cheap``)
    rnd, st = runs["round"], runs["state"]
    assert rnd.tried, "the round tried nothing"
    ctx, meas = st.ctx, st.ctx.x["t_in"]
    for k in ("free_run", "one_step"):
        np.testing.assert_array_equal(rnd.reference[k],
                                      np.mean([r[k] for r in runs["refs"]], axis=0))
    for t in rnd.tried:
        assert len(t.bagged) == BAGS
        for k in ("free_run", "one_step"):
            np.testing.assert_array_equal(t.pred[k], np.mean([b.pred[k] for b in t.bagged], axis=0))
        assert t.verdict.delta_bic == [float(f.delta_bic) for f in t.fits]
        again = jd.judge(runs["first"], rnd.reference, t.pred, meas, st.held.blocks, ctx.split,
                         ctx.dt, t.starts, ctx.last)
        assert (again.why, again.mae_before, again.mae_after) == (
            t.verdict.why, t.verdict.mae_before, t.verdict.mae_after)
    assert rnd.best is not None, [t.verdict.why for t in rnd.tried]
    e = rnd.best.effect
    assert st.effects == [e] and all(b.effects == [e] for b in st.bags)
    for b, bt in zip(st.bags, rnd.best.bagged, strict=True):
        assert b.model is bt.model and b.current_pred is bt.pred
    assert st.current_pred is rnd.best.pred


def test_the_cli_and_the_suite_pass_bags_on(monkeypatch, capsys):
    """``diagnose --bags K`` and a suite case's ``bags`` reach ``diagnose(..., bags=K)``; a
    negative K is refused before any data is read."""
    import gateway.diagnose
    from gateway.cli import diagnose as cli_diagnose
    from gateway.cli import main
    from tests.generality import cases

    seen: list[int] = []

    def fake(series, gh, model, **kwargs):
        seen.append(kwargs["bags"])
        raise ValueError("stopped by the test")

    monkeypatch.setattr(gateway.diagnose, "diagnose", fake)
    monkeypatch.setattr(cli_diagnose, "load_inputs", lambda args: (None, None, None))
    args = ["diagnose", "--data", "kit.csv", "--greenhouse", "biskra-prototype", "--model",
            "prototype"]
    assert main([*args, "--bags", "3"]) == 2 and seen == [3]
    assert main([*args, "--bags", "-1"]) == 2 and seen == [3]
    assert "--bags" in capsys.readouterr().err
    with pytest.raises(ValueError, match="stopped by the test"):
        cases._diagnose(cases.Case("diagnose", "refsim", "autumn"), None, None, None, None, 4)
    assert seen == [3, 4]
