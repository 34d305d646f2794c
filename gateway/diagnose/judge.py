"""The judge: held-out predictions and the decision whether an effect is kept (docs/effects.md,
"How the diagnosis decides").

The held-out part H (after the calibration part C) is cut into blocks dealt alternately into
two folds. Each fold's blocks are predicted by a model fitted on C plus the *other* fold only
(blocked two-fold cross-fitting): every held-out figure comes from data its fit never saw,
wherever an effect starts.
"""

from __future__ import annotations

import numpy as np

from gateway.diagnose.bic import EFFECTIVE_S
from gateway.metrics import metrics
from gateway.model.model import Model

BLOCK_S = 12 * 3600.0
"""Length of the held-out blocks dealt into the two folds [s] (``heldout_blocks``)."""
JUDGE_PIECE_S = 6 * 3600.0
"""Length of the held-out pieces whose paired MSE differences the t statistic is taken over."""
MIN_GAIN = 0.05
"""Smallest relative cut of held-out free-run MAE that can count as an improvement."""
MIN_T = 1.0
"""Block-paired t statistic of the MSE cut required (unless the cut is ≥ STRONG_GAIN)."""
STRONG_GAIN = 0.25

Blocks = list[tuple[int, int]]


def heldout_blocks(split: int, n: int, dt: float) -> Blocks:
    """The held-out part cut into blocks of ``BLOCK_S`` (a quarter of it when shorter).

    Half a day: long enough for a free run to forget its measured start (the air and fast
    mass relax within an hour or two), short enough that each fold's fit set samples the whole
    held-out part densely, so an effect growing in time (a drift) is pinned down on both sides
    of every judged block."""
    length = n - split
    want = int(round(BLOCK_S / dt))
    block = want if length >= 4 * want else max(length // 4, 2)
    edges = list(range(split, n, block))
    blocks = [(a, min(a + block, n)) for a in edges]
    if len(blocks) > 1 and blocks[-1][1] - blocks[-1][0] < block // 2:
        a, _ = blocks.pop()
        blocks[-1] = (blocks[-1][0], n)
    return blocks


def folds_of(blocks: Blocks) -> list[Blocks]:
    """Blocks dealt alternately into two folds."""
    return [[b for i, b in enumerate(blocks) if i % 2 == j] for j in (0, 1)]


def heldout(model: Model, thetas, x, gh, dt, folds, s, n) -> dict[str, np.ndarray]:
    """Cross-fitted held-out predictions: free runs restarted at each block start, one-step."""
    free = np.full(n - s, np.nan)
    one = np.full(n - s, np.nan)
    for j in (0, 1):
        th = thetas[j][None, :]
        if not folds[j]:
            continue
        o = model.one_step(th, x, gh, dt)[0]
        for a, b in folds[j]:
            free[a - s : b - s] = model.free_run(th, x, gh, dt, start=a, stop=b)[0]
            one[a - s : b - s] = o[a:b]
    return {"free_run": free, "one_step": one}


def persistence(meas, blocks, s, n) -> dict[str, np.ndarray]:
    """Naive baselines: the previous reading (one-step), the block's first reading (free run)."""
    free = np.full(n - s, np.nan)
    for a, b in blocks:
        free[a - s : b - s] = meas[a]
    one = np.concatenate([[np.nan], meas[s:-1]])
    return {"free_run": free, "one_step": one}


def metrics_of(meas, pred, s) -> dict:
    m = meas[s:]
    return {k: metrics(m, v) for k, v in pred.items()}


def judge(before, after, meas, blocks, s, dt) -> dict:
    """Is the held-out free-run error significantly lower after? The paired t statistic is
    over pieces of ``JUDGE_PIECE_S`` of the blocks (free-run residuals decorrelate within
    hours; whole blocks would leave only a handful of pairs)."""
    eb = (before["free_run"] - meas[s:]) ** 2
    ea = (after["free_run"] - meas[s:]) ** 2
    ok = np.isfinite(eb) & np.isfinite(ea)
    piece = max(int(round(JUDGE_PIECE_S / dt)), 1)
    d = []
    for a0, b0 in blocks:
        for a in range(a0, b0, piece):
            b = min(a + piece, b0)
            k = ok[a - s : b - s]
            if k.any():
                d.append(np.mean(eb[a - s : b - s][k]) - np.mean(ea[a - s : b - s][k]))
    d = np.array(d)
    mae_b = float(np.mean(np.sqrt(eb[ok])))
    mae_a = float(np.mean(np.sqrt(ea[ok])))
    mse_b, mse_a = float(np.mean(eb[ok])), float(np.mean(ea[ok]))
    gain = 1.0 - mae_a / mae_b if mae_b > 0 else 0.0
    mse_gain = 1.0 - mse_a / mse_b if mse_b > 0 else 0.0
    sd = float(np.std(d, ddof=1)) if len(d) > 1 else float("inf")
    t = float(np.mean(d) / (sd / np.sqrt(len(d)))) if sd > 0 else (np.inf if np.mean(d) > 0 else 0.0)
    good = gain >= MIN_GAIN and (t >= MIN_T or mse_gain >= STRONG_GAIN)
    why = (f"held-out free-run MAE {mae_b:.3f} → {mae_a:.3f} °C ({-100 * gain:+.0f} %), "
           f"paired t = {t:.2f} over {len(d)} pieces of {JUDGE_PIECE_S / 3600:g} h")
    return {"ok": bool(good), "why": why, "gain": gain, "t": t, "mae_before": mae_b,
            "mae_after": mae_a, "mse_after": mse_a}


def scores(passed: list[dict], meas, s, dt) -> list[float]:
    """One score per passing candidate's verdict (lowest: most evidence): ΔBIC of its fits (both
    folds' fit sets, its second output's included) plus its held-out log-likelihood ratio
    against the best held-out MSE (all one effective sample per ``EFFECTIVE_S``). A rival the
    held-out part barely separates is decided by the fits, and the other way round."""
    best_mse = min(v["mse_after"] for v in passed)
    n_h = np.isfinite(meas[s:]).sum() * dt / EFFECTIVE_S
    return [float(sum(v["delta_bic"]) + n_h * np.log(v["mse_after"] / best_mse))
            for v in passed]


def calibration_free_run(model, theta, x, gh, dt, s) -> np.ndarray:
    """In-sample free-run residual on the calibration part (blocks of one day), for comparison."""
    day = int(round(86400.0 / dt))
    block = min(day, max(s // 2, 2))
    errs = []
    for a in range(0, s - 1, block):
        b = min(a + block, s)
        if b - a < 2:
            continue
        pred = model.free_run(theta[None, :], x, gh, dt, start=a, stop=b)[0]
        errs.append(x["t_in"][a:b] - pred)
    return np.concatenate(errs)
