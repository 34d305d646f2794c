"""calibrate_base's optional ``resample`` of its shooting windows (issue 10, bg): off by default
and then exactly main's calibration; a repeated window start weighs as two."""

from __future__ import annotations

import numpy as np

from gateway.diagnose import base
from gateway.diagnose.fit import Shooting, drivers, window_starts
from tests.diagnose_data import prototype_bases, sine_series

H = 72  # 6 h of 5-minute rows
S = 2016  # 7 days of calibration part
S1 = int(round(base.INNER_SPLIT * S))


def kit_data() -> dict[str, np.ndarray]:
    """7 days of sine weather; T_in the prototype's free run plus a slow wave it cannot fit."""
    gh, _, m = prototype_bases()
    x = drivers(sine_series(n=S, step=300), gh)
    x["t_in"] = m.free_run(m.defaults(gh)[None], x, gh, 300.0)[0] + 0.3 * np.sin(
        np.arange(S) / 50.0)
    return x


def calibrate(x, monkeypatch, resample=None) -> tuple[np.ndarray, list, list[np.ndarray]]:
    """calibrate_base on ``x``, recording the starts of every Shooting it builds."""
    gh, _, m = prototype_bases()
    seen: list[np.ndarray] = []

    class Spy(Shooting):
        def __post_init__(self) -> None:
            super().__post_init__()
            seen.append(np.array(self.starts))

    monkeypatch.setattr(base, "Shooting", Spy)
    kwargs = {} if resample is None else {"resample": resample}
    _, theta, log = base.calibrate_base(m, gh, x, 300.0, S, H, 0, lambda msg: None, **kwargs)
    return theta, log, seen


def plain_windows() -> list[np.ndarray]:
    """The three sets of windows main's calibration fits and judges on: C1, C2, C."""
    return [window_starts([(0, S1)], H, skip=H), window_starts([(S1, S)], H),
            window_starts([(0, S)], H, skip=H)]


def test_a_repeated_start_counts_twice_in_the_shooting_cost():
    gh, _, m = prototype_bases()
    x = kit_data()
    th = m.defaults(gh)[None]
    a, b = 72, 360
    one = [Shooting(m, x, gh, 300.0, np.array([s]), H).sse(th) for s in (a, b)]
    both, n = Shooting(m, x, gh, 300.0, np.array([a, b, b]), H).sse(th)
    assert one[1][0][0] > 0
    np.testing.assert_allclose(both, one[0][0] + 2 * one[1][0], rtol=1e-12)
    assert n == one[0][1] + 2 * one[1][1]


def test_default_is_mains_calibration_bit_for_bit(monkeypatch):
    """Without ``resample`` every Shooting gets main's plain windows, and an identity hook gives
    the very same parameters and structure log (the hook adds nothing else)."""
    x = kit_data()
    theta, log, seen = calibrate(x, monkeypatch)
    plain = plain_windows()
    assert seen and all(any(np.array_equal(s, p) for p in plain) for s in seen)
    assert all(any(np.array_equal(s, p) for s in seen) for p in plain)
    theta_id, log_id, _ = calibrate(x, monkeypatch, lambda starts: starts)
    np.testing.assert_array_equal(theta, theta_id)
    assert log == log_id


def test_resample_reaches_every_shooting_of_the_calibration(monkeypatch):
    """A hook dropping the first window and doubling the rest: every Shooting of the
    calibration (fits, validation, refit) fits the hook's starts, none main's."""
    x = kit_data()

    def hook(starts: np.ndarray) -> np.ndarray:
        return np.repeat(starts[1:], 2)

    _, _, seen = calibrate(x, monkeypatch, hook)
    want = [hook(p) for p in plain_windows()]
    assert seen and all(any(np.array_equal(s, w) for w in want) for s in seen)
    assert all(any(np.array_equal(s, w) for s in seen) for w in want)
