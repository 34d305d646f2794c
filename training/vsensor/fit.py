"""Fitting: standardisation, PCA, the NARX networks (scikit-learn) and the linear ARX.

Training follows §IV.3.2.2: 75 % of the data to train, 25 % to validate (the last quarter of
every file, so validation is later in time than what was fitted), input delays 0–5 and output
delays 1–5, tanh hidden layers 30-50-20. The network is fitted series-parallel (past outputs =
the target's), then refined in a few rounds on its own closed-loop feedback (the rows' past
outputs are what the network itself produced, the targets stay the explicit flow), because the
deployed sensor only ever sees its own past; the round with the best closed-loop validation
error is kept. Everything is seeded and single-threaded, so the same data give the same bytes.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from gateway.vsensor.features import OUTPUT_DELAYS
from gateway.vsensor.loop import Bounds, closed_loop, fill_missing
from training.vsensor.dataset import Segment
from training.vsensor.narx import MIXED, TARGETS, Driver, Layer, MixedNarx, Narx, lag_rows, to_target

TRAIN_SHARE = 0.75
MIN_VARIANCE = 0.90
HIDDEN = (30, 50, 20)
FEEDBACKS = ("member", "ensemble")
"""Closed-loop rounds of an ensemble: each member on its own feedback, or on the ensemble's."""
Progress = Callable[..., None]


@dataclass
class Split:
    """Segments with their upper flow limits, and the index where validation starts."""

    segments: list[Segment]
    upper: list[np.ndarray]  # (T,) per segment
    cut: list[int]

    def part(self, name: str) -> list[tuple[np.ndarray, np.ndarray]]:
        """(inputs, flow) per segment for ``train`` or ``validation``."""
        out = []
        for s, c in zip(self.segments, self.cut, strict=True):
            sl = slice(0, c) if name == "train" else slice(c, None)
            out.append((s.inputs[sl], s.flow[sl]))
        return out


def make_split(segments: list[Segment], upper: list[np.ndarray]) -> Split:
    return Split(segments, upper, [int(round(TRAIN_SHARE * len(s.flow))) for s in segments])


def scaler(split: Split) -> tuple[np.ndarray, np.ndarray]:
    """Mean and standard deviation of every input over the training rows (centring, reduction)."""
    u = np.concatenate([i for i, _ in split.part("train")])
    u = u[np.all(np.isfinite(u), axis=1)]
    std = u.std(axis=0)
    return u.mean(axis=0), np.where(std > 1e-12, std, 1.0)


def pca(z: np.ndarray, seed: int, min_share: float = MIN_VARIANCE) -> tuple[np.ndarray, np.ndarray]:
    """Loadings (F, m) of the fewest components keeping ``min_share`` of the variance of the
    standardised inputs ``z`` (IV.56–IV.60), and every component's share (F,)."""
    from sklearn.decomposition import PCA

    p = PCA(svd_solver="full", random_state=seed).fit(z[np.all(np.isfinite(z), axis=1)])
    share = p.explained_variance_ratio_
    m = int(np.searchsorted(np.cumsum(share), min_share - 1e-12) + 1)
    return p.components_[:m].T.copy(), share


def rows(net: Narx, data: list[tuple[np.ndarray, np.ndarray]], lags: list[np.ndarray] | None = None):
    """Stacked series-parallel rows (H, target) of ``data`` for ``net``'s pre-processing (the
    ``opening`` target: the driver rides along as a last column, so its rows are the same)."""
    hs, ts = [], []
    opening = net.target == "opening"
    for i, (u, y) in enumerate(data):
        z = net.reduce(u)
        if opening:
            z = np.concatenate([z, net.driver.of(u)[:, None]], axis=1)
        z, yp, t = lag_rows(z, y, None if lags is None else lags[i])
        d = z[:, :, -1] if opening else None  # (N, 6): the driver at k, k-1 … k-5
        if opening:
            z = z[:, :, :-1]
        hs.append(net.head(z, yp, None if d is None else d[:, 1:]))
        ts.append((to_target(t, net.target, None if d is None else d[:, 0]) - net.y_mean) / net.y_std)
    return np.concatenate(hs), np.concatenate(ts)


def train_targets(data: list[tuple[np.ndarray, np.ndarray]], opts: RowOptions) -> np.ndarray:
    """Every training minute's target in the network's space (for its median and spread)."""
    return np.concatenate([to_target(y, opts.target, None if opts.driver is None else opts.driver.of(u))
                           for u, y in data])


def simulate(net: Narx | MixedNarx, split: Split, bounds: Bounds | None = None) -> list[np.ndarray]:
    """Closed-loop flows of every whole segment (all at once, padded to the longest);
    ``bounds``: inputs clamped to them (``loop.closed_loop``, ``VentSensor(clamp_inputs=True)``)."""
    n_max = max(len(s.flow) for s in split.segments)
    n_f = split.segments[0].inputs.shape[1]
    u = np.empty((len(split.segments), n_max, n_f))
    up = np.zeros((len(split.segments), n_max))
    for i, s in enumerate(split.segments):
        filled, _ = fill_missing(s.inputs, net.mean)
        u[i, : len(filled)] = filled
        u[i, len(filled):] = filled[-1]
        up[i, : len(filled)] = split.upper[i]
    y = closed_loop(net.predict, u, up, net.y0, net.histories, bounds)
    return [y[i, : len(s.flow)] for i, s in enumerate(split.segments)]


def simulate_own_feedback(net: Narx | MixedNarx, split: Split, bounds: Bounds | None = None
                          ) -> list[np.ndarray]:
    """Closed-loop flows of an ensemble whose members each hear **their own** past outputs
    (K histories, each member's output clipped to the physical range, then averaged): what the
    graph and runtime of an ``own_feedback`` model do. A single network: ``simulate``."""
    return simulate(dataclasses.replace(net, own_feedback=True), split, bounds)


def validation_mae(net: Narx | MixedNarx, split: Split) -> float:
    sims = simulate(net, split)
    err = [np.abs(y[c:] - s.flow[c:]) for y, s, c in zip(sims, split.segments, split.cut, strict=True)]
    e = np.concatenate(err)
    return float(np.nanmean(e))


def _layers(mlp) -> list[Layer]:
    n = len(mlp.coefs_)
    return [Layer(w.copy(), b.copy(), "tanh" if i < n - 1 else "identity")
            for i, (w, b) in enumerate(zip(mlp.coefs_, mlp.intercepts_, strict=True))]


Noise = Callable[[np.ndarray], np.ndarray]
HIGH_FLOW_QUANTILE = 0.90
"""``RowOptions.high_weight`` weighs the rows whose target is above this quantile of the
training targets."""


@dataclass(frozen=True)
class RowOptions:
    """How the training rows are presented to the networks (defaults: as they are)."""

    noise_sigma: float = 0.0  # see feedback_noise
    high_weight: float = 1.0  # loss weight of the rows above HIGH_FLOW_QUANTILE (the peaks)
    target: str = "identity"  # narx.TARGETS: the flow, √G, log(1 + G) or G / D learnt and fed back,
    # or MIXED: an ensemble's members alternating flow and opening by seed (training/vsensor/mixed.py)
    driver: Driver | None = None  # the ``opening`` (or MIXED) target's D (narx.Driver.of_greenhouse)

    def __post_init__(self) -> None:
        if self.target not in (*TARGETS, MIXED):
            raise ValueError(f"target {self.target!r}: one of {(*TARGETS, MIXED)}")
        if (self.target in ("opening", MIXED)) != (self.driver is not None):
            raise ValueError("the opening and mixed targets need the driver, and only they take it")

    def as_settings(self) -> dict[str, float | str]:
        """The non-default options, for the model's training settings."""
        out: dict[str, float | str] = {}
        if self.target != "identity":
            out["target_transform"] = self.target
        if self.noise_sigma:
            out["feedback_noise"] = self.noise_sigma
        if self.high_weight != 1.0:
            out["high_flow_weight"] = self.high_weight
        return out


def row_options(noise_sigma: float, high_weight: float, target: str, gh) -> RowOptions:
    """The command line's :class:`RowOptions`; the ``opening`` target's driver from the
    greenhouse ``gh`` (narx.Driver.of_greenhouse)."""
    return RowOptions(noise_sigma, high_weight, target,
                      Driver.of_greenhouse(gh) if target in ("opening", MIXED) else None)


def row_weights(t: np.ndarray, threshold: float, high_weight: float) -> np.ndarray | None:
    """Loss weights of rows with (scaled) targets ``t``: ``high_weight`` above ``threshold``,
    1 elsewhere, normalised to a mean of 1 (the step size stays comparable); None for 1."""
    if high_weight == 1.0:
        return None
    w = np.where(t > threshold, high_weight, 1.0)
    return w / w.mean()


def feedback_noise(sigma: float, floor: float, rng: np.random.Generator) -> Noise | None:
    """Rows with a common random offset on their five past outputs (robustness of the loop).

    Closed loop, the past outputs the network hears are its own, off by a slowly varying error;
    here every row's past outputs (scaled: units of the target's standard deviation) get one
    offset drawn from N(0, ``sigma``), redrawn at every epoch, never below ``floor`` (the scaled
    zero flow: the deployed outputs are clipped at 0). ``sigma`` 0: no noise (None)."""
    if sigma <= 0:
        return None
    n_out = len(OUTPUT_DELAYS)

    def noisy(h: np.ndarray) -> np.ndarray:
        out = h.copy()
        off = sigma * rng.standard_normal(len(h))
        out[:, -n_out:] = np.maximum(out[:, -n_out:] + off[:, None], floor)
        return out

    return noisy


def _epochs(mlp, h, t, hv, tv, epochs: int, patience: int, progress: Progress, label: str,
            noise: Noise | None = None, weights: np.ndarray | None = None):
    """partial_fit one pass at a time, keep the weights of the best validation loss
    (``noise``: applied afresh to the training rows at every pass; ``weights``: the rows' loss
    weights; validation stays clean and unweighted)."""
    best, best_w, stale = np.inf, None, 0
    for e in range(epochs):
        mlp.partial_fit(h if noise is None else noise(h), t, sample_weight=weights)
        loss = float(np.mean((mlp.predict(hv) - tv) ** 2))
        if loss < best - 1e-7:
            best, stale = loss, 0
            best_w = ([w.copy() for w in mlp.coefs_], [b.copy() for b in mlp.intercepts_])
        else:
            stale += 1
        progress(advance=1, info=f"{label} epoch {e + 1} val {loss:.4f}")
        if stale >= patience:
            progress(advance=epochs - e - 1)
            break
    if best_w is not None:
        mlp.coefs_, mlp.intercepts_ = best_w


@dataclass
class Member:
    """One network being fitted: its numpy form, its scikit-learn form and its rows."""

    net: Narx
    mlp: object  # MLPRegressor
    rows: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]  # h, t, h_val, t_val
    noise: Noise | None
    weigh: Callable[[np.ndarray], np.ndarray | None]  # scaled targets → loss weights
    log: dict


def start_member(name: str, split: Split, mean, std, projection, seed: int, hidden=HIDDEN,
                 epochs: int = 150, progress: Progress | None = None,
                 round_lr: float | None = None, opts: RowOptions = RowOptions()) -> Member:
    """A network fitted series-parallel (past outputs = the target's), not yet refined."""
    from sklearn.neural_network import MLPRegressor

    progress = progress or (lambda **k: None)
    y_train = train_targets(split.part("train"), opts)
    flows = np.concatenate([y for _, y in split.part("train")])
    net = Narx(name, mean, std, projection, float(np.nanmedian(y_train)),
               float(np.nanstd(y_train)) or 1.0, target=opts.target, driver=opts.driver,
               flow_median=float(np.nanmedian(flows)) if opts.driver is not None else float("nan"))
    h, t = rows(net, split.part("train"))
    hv, tv = rows(net, split.part("validation"))
    noise = feedback_noise(opts.noise_sigma, -net.y_mean / net.y_std, np.random.default_rng(seed))
    threshold = float(np.quantile(t, HIGH_FLOW_QUANTILE))

    def weigh(targets: np.ndarray) -> np.ndarray | None:
        return row_weights(targets, threshold, opts.high_weight)

    mlp = MLPRegressor(hidden_layer_sizes=hidden, activation="tanh", solver="adam", alpha=1e-4,
                       batch_size=256, learning_rate_init=1e-3, random_state=seed, shuffle=True)
    _epochs(mlp, h, t, hv, tv, epochs, 20, progress, name, noise, weigh(t))
    net.layers = _layers(mlp)
    log = {"series_parallel_val_mse": float(np.mean((mlp.predict(hv) - tv) ** 2)),
           "closed_loop_val_mae": [validation_mae(net, split)]}
    if round_lr is not None and hasattr(mlp, "_optimizer"):
        mlp._optimizer.learning_rate_init = round_lr  # Adam keeps its moments; only the step
    return Member(net, mlp, (h, t, hv, tv), noise, weigh, log)


def refine(m: Member, split: Split, sims: list[np.ndarray], round_epochs: int,
           progress: Progress, label: str) -> None:
    """One closed-loop round: the training rows again, plus rows whose past outputs are
    ``sims`` (closed-loop flows of whole segments) and whose targets stay the explicit flow."""
    h, t, hv, tv = m.rows
    train_sims = [y[:c] for y, c in zip(sims, split.cut, strict=True)]
    hc, tc = rows(m.net, split.part("train"), train_sims)
    tt = np.concatenate([t, tc])
    _epochs(m.mlp, np.concatenate([h, hc]), tt, hv, tv, round_epochs, round_epochs, progress,
            label, m.noise, m.weigh(tt))
    m.net.layers = _layers(m.mlp)


def fit_narx(name: str, split: Split, mean, std, projection, seed: int, hidden=HIDDEN,
             epochs: int = 150, rounds: int = 3, round_epochs: int = 30,
             progress: Progress | None = None, round_lr: float | None = None,
             opts: RowOptions = RowOptions()) -> tuple[Narx, dict]:
    """Train one network (series-parallel, then closed-loop rounds). Returns it and a log.

    ``round_lr``: Adam's step size during the closed-loop rounds (default: the series-parallel
    one, 1e-3); a smaller step fine-tunes instead of jumping between rounds. ``opts``: noise
    on the past outputs and loss weights of the rows (:class:`RowOptions`)."""
    progress = progress or (lambda **k: None)
    m = start_member(name, split, mean, std, projection, seed, hidden, epochs, progress,
                     round_lr, opts)
    log = m.log
    best = (log["closed_loop_val_mae"][0], m.net.layers)
    for r in range(rounds):
        refine(m, split, simulate(m.net, split), round_epochs, progress,
               f"{name} closed-loop round {r + 1}")
        mae = validation_mae(m.net, split)
        log["closed_loop_val_mae"].append(mae)
        if mae < best[0]:
            best = (mae, m.net.layers)
    m.net.layers = best[1]
    log["kept_round"] = int(np.argmin(log["closed_loop_val_mae"]))
    return m.net, log


def _joint(name: str, split: Split, mean, std, projection, seeds: list[int], hidden, epochs: int,
           rounds: int, round_epochs: int, progress: Progress, round_lr: float | None,
           opts: RowOptions) -> tuple[Narx, dict]:
    """Members fitted series-parallel apart, then refined together: in every round each member
    learns from rows whose past outputs are **the ensemble's** closed-loop flows (what it hears
    deployed); the round whose ensemble has the best closed-loop validation MAE is kept."""
    ms = [start_member(name, split, mean, std, projection, s, hidden, epochs, progress,
                       round_lr, opts) for s in seeds]
    stacks = [m.net.layers for m in ms]
    ens = dataclasses.replace(ms[0].net, layers=stacks[0], members=list(stacks))
    log = {"seeds": list(seeds), "feedback": "ensemble",
           "members": [m.log for m in ms], "ensemble_round_val_mae": [validation_mae(ens, split)]}
    best = (log["ensemble_round_val_mae"][0], list(stacks))
    for r in range(rounds):
        sims = simulate(ens, split)
        for j, m in enumerate(ms):
            refine(m, split, sims, round_epochs, progress, f"{name} joint round {r + 1} member {j}")
            stacks[j] = m.net.layers
        ens.members = list(stacks)
        mae = validation_mae(ens, split)
        log["ensemble_round_val_mae"].append(mae)
        if mae < best[0]:
            best = (mae, list(stacks))
    log["kept_round"] = int(np.argmin(log["ensemble_round_val_mae"]))
    ens.members = best[1]
    ens.layers = best[1][0]
    log["member_val_mae"], log["ensemble_val_mae_by_size"] = [], []
    for k in range(1, len(seeds) + 1):
        one = dataclasses.replace(ens, layers=best[1][k - 1], members=[])
        log["member_val_mae"].append(validation_mae(one, split))
        ens.members = best[1][:k]
        log["ensemble_val_mae_by_size"].append(validation_mae(ens, split))
    return ens, log


def fit_ensemble(name: str, split: Split, mean, std, projection, seeds: list[int],
                 hidden=HIDDEN, epochs: int = 150, rounds: int = 3, round_epochs: int = 30,
                 progress: Progress | None = None, round_lr: float | None = None,
                 opts: RowOptions = RowOptions(), feedback: str = "member"
                 ) -> tuple[Narx | MixedNarx, dict]:
    """``fit_narx`` once per seed on the same rows; the members' outputs are averaged.

    ``feedback`` "member": each member is fitted (and its closed-loop rounds run) on its own,
    as a single network; "ensemble": the rounds run on the ensemble's feedback (``_joint``).
    The ensemble, deployed, feeds every member its own mean past outputs. One seed: the single
    network, unchanged. The log holds every member's log and the ensemble's closed-loop
    validation MAE with its first k members, k = 1 … K (how much averaging buys)."""
    if feedback not in FEEDBACKS:
        raise ValueError(f"feedback {feedback!r}: one of {FEEDBACKS}")
    progress = progress or (lambda **k: None)
    if opts.target == MIXED:  # members of two targets: averaged as flows (mixed.py)
        from training.vsensor.mixed import fit_mixed

        return fit_mixed(name, split, mean, std, projection, seeds, hidden, epochs, rounds,
                         round_epochs, progress, round_lr, opts, feedback)
    if feedback == "ensemble" and len(seeds) > 1:
        return _joint(name, split, mean, std, projection, seeds, hidden, epochs, rounds,
                      round_epochs, progress, round_lr, opts)
    fitted = [fit_narx(name, split, mean, std, projection, s, hidden, epochs, rounds,
                       round_epochs, progress, round_lr, opts) for s in seeds]
    net = fitted[0][0]
    if len(fitted) == 1:
        return net, fitted[0][1]
    log = {"seeds": list(seeds), "members": [lg for _, lg in fitted],
           "member_val_mae": [min(lg["closed_loop_val_mae"]) for _, lg in fitted],
           "ensemble_val_mae_by_size": []}
    for k in range(1, len(fitted) + 1):
        net.members = [n.layers for n, _ in fitted[:k]]
        log["ensemble_val_mae_by_size"].append(validation_mae(net, split))
    return net, log


def fit_arx(split: Split, mean, std, ridge: float = 1e-3) -> Narx:
    """Linear ARX on the same inputs and delays, least squares (series-parallel), no PCA."""
    y_train = np.concatenate([y for _, y in split.part("train")])
    net = Narx("linear_arx", mean, std, None, float(np.nanmedian(y_train)),
               float(np.nanstd(y_train)) or 1.0)
    h, t = rows(net, split.part("train"))
    a = np.column_stack([h, np.ones(len(h))])
    coef = np.linalg.solve(a.T @ a + ridge * np.eye(a.shape[1]), a.T @ t)
    net.layers = [Layer(coef[:-1, None].copy(), coef[-1:].copy(), "identity")]
    return net
