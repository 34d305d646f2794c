"""Online parameter estimator: RSBA on "virtual models" of the last n samples (thesis §IV.2.1.2).

Every sample the estimator

1. checks the sample (non-finite, outside the kit column's possible range, or a stuck inside
   temperature → that value is dropped and counted);
2. for each estimation group due at this step (``Model.online``, e.g. air temperature every
   step with n = 3 and the radiation sub-model every 20 steps with n = 60), re-simulates the
   window [t - n, t] from the measured state at t - n for the whole bat population at once and
   lets RSBA minimise the mean square error (RMSE in the thesis: same minimiser);
3. searches parameter j only while its process is active (``Parameter.active``: radiation
   > 5 W m-2, vents open, LAI > 0.1), inside the adaptive box ``C_j (1 ± R_j)`` (IV.53–IV.54,
   table 12) clipped to the hard limits (table 13); otherwise the value is held;
4. applies the best set at t and predicts T_in[t + 1] with one exact exponential step.

Nothing after t is ever read, so replaying recorded data gives exactly what the live gateway
would have predicted. Parameters never leave their hard box and no NaN is ever returned: a
prediction that cannot be made is ``None``.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Mapping, Sequence
from dataclasses import replace

import numpy as np

from gateway.estimate.online_output import Counters, Prediction
from gateway.estimate.sample_check import STUCK_SAMPLES, StuckRun, check_sample
from gateway.estimate.settings import DEFAULT_ITERATIONS, GroupSettings, online_settings  # noqa: F401 (re-exported)
from gateway.estimate.swarm import ALMERIA_OFFLINE, SearchResult, bat
from gateway.greenhouse import Greenhouse
from gateway.model.drivers import prepare_drivers, site_of
from gateway.model.model import Model
from gateway.model.sky import CloudTracker
from gateway.model.step import Stepper
from gateway.series import Series

MIN_RADIATION_PAIRS = 10
"""The radiation sub-model is only re-estimated with at least this many sunlit samples."""


class OnlineEstimator:
    """Sample-by-sample adaptation of a model's parameters, usable live or in replay.

    ``theta0``: starting parameters (offline calibration); None starts from the middle of the
    hard box (the thesis's estimator works without offline calibration). ``dt`` is the model
    step [s]; samples are expected every ``dt`` (the ingest layer resamples).
    """

    def __init__(
        self,
        model: Model,
        gh: Greenhouse,
        theta0: np.ndarray | None = None,
        settings: Sequence[GroupSettings] | None = None,
        dt: float = 60.0,
        seed: int | None = 0,
        search: Callable[..., SearchResult] = bat,
        stuck_samples: int = STUCK_SAMPLES,
    ) -> None:
        self.model, self.gh, self.dt = model, gh, float(dt)
        # identical readings in a row that make a stuck sensor (sample_check.stuck_limit)
        self.stuck_samples = int(stuck_samples)
        self.search = search  # swarm.bat (vectorised RSBA); the bench swaps in a per-bat loop
        self.lower, self.upper = model.bounds(gh)
        self.variation = model.variations(gh)
        if theta0 is None:
            theta0 = 0.5 * (self.lower + self.upper)
        theta0 = np.asarray(theta0, dtype=float)
        if theta0.shape != self.lower.shape or not np.all(np.isfinite(theta0)):
            raise ValueError(f"{model.name}: theta0 must be {len(self.lower)} finite values {model.names}")
        self.theta0 = np.clip(theta0, self.lower, self.upper)
        self.theta = self.theta0.copy()
        self.settings = tuple(settings) if settings is not None else online_settings(model, gh)
        self.rng = np.random.default_rng(seed)
        self.capacity_c = model.capacity(gh)  # C [J m-2 K-1] (III.24) or rho V / S_f (III.14)
        self._idx = {g.output: np.array([model.index(n) for n in g.parameters]) for g in self.settings}
        self._conditions = [p.active for p in model.parameters]
        self._names = list(enumerate(model.names))
        self._bat = {
            g.output: replace(ALMERIA_OFFLINE, bats=g.bats, iterations=g.iterations) for g in self.settings
        }
        # Columns whose absence stops the temperature step (derived ones follow from these).
        self._needed = [c for c in model.requires if c != "t_in"]
        if "rh_in" in model.requires:
            self._needed.append("p_w_in")  # transpiration's VPD (III.29)
        self.history = max(g.window for g in self.settings) + 1
        self._cap = max(4 * self.history, 512)
        self._buf: dict[str, np.ndarray] = {}
        self._n = 0  # rows stored in the buffer
        self._stuck = StuckRun(limit=self.stuck_samples)
        # Parameters at the start of each of the last stuck_samples updates, to undo what a
        # stuck run taught the estimator before it was recognised.
        self._theta_before: deque[np.ndarray] = deque(maxlen=self.stuck_samples)
        self._last_prediction: float | None = None
        self._sky = CloudTracker(site_of(gh), self.dt)  # cloudiness carried sample to sample
        self.counters = Counters()
        self.last_row: dict[str, float] = {}
        """The checked and derived drivers of the last sample (what replay records)."""

    # -- public API ----------------------------------------------------------------------
    def update(self, sample: Mapping[str, float], time: np.datetime64 | None = None) -> Prediction:
        """Take the measured sample at t (kit column name → value), adapt, predict t + 1.

        ``time`` (UTC) lets the sky temperature follow the cloudiness read from the radiation
        (gateway/model/sky.py); without it the cloud fraction stays at its prior."""
        self.counters.samples += 1
        step = self.counters.samples - 1  # index of this sample since start
        self._theta_before.append(self.theta.copy())
        values, faults = check_sample(sample, self.model.requires, self._stuck,
                                      self.counters.faults)
        if self._stuck.length == self.stuck_samples:
            self._strike_stuck_run()
        if faults:
            self.counters.faulty_samples += 1
        if not np.isfinite(values.get("t_in", np.nan)) and self._last_prediction is not None:
            # T_in missing: the inside vapour pressure (III.4) is derived from the bridged state
            row = self._derive({**values, "t_in": self._last_prediction}, time)
            row["t_in"] = np.nan
        else:
            row = self._derive(values, time)
        self._append(row)
        self.last_row = row
        estimated = []
        for g in self.settings:
            if step % g.every:
                continue
            ran = self._estimate_rad(g) if g.output == "i_in" else self._estimate_air(g)
            if ran is None:
                continue  # nothing active or nothing measured for this group: hold, no fault
            if ran:
                estimated.append(g.output)
                self.counters.estimated[g.output] = self.counters.estimated.get(g.output, 0) + 1
            else:
                self.counters.skipped[g.output] = self.counters.skipped.get(g.output, 0) + 1
        t_next, dead = self._predict(row)
        if t_next is None:
            self.counters.no_prediction += 1
        self._last_prediction = t_next
        return Prediction(t_next, self.theta.copy(), tuple(estimated), tuple(faults), dead)

    def restart_window(self) -> None:
        """Forget the window (after a gap in the data, e.g. the kit was off for hours): the next
        estimations wait for a full window of new samples. The parameters are kept."""
        self._buf, self._n = {}, 0
        self._stuck = StuckRun(limit=self.stuck_samples)
        self._theta_before.clear()
        self._last_prediction = None

    def snapshot(self) -> dict:
        """Everything ``update`` depends on, as JSON-ready values (NaN stays NaN), so a restarted
        gateway resumes exactly where it stopped (``restore``)."""
        keep = min(self._n, self.history)
        a = self._n - keep
        return {
            "model": self.model.name, "names": self.model.names,
            "theta": self.theta.tolist(), "theta0": self.theta0.tolist(),
            "rng": self.rng.bit_generator.state,
            "window": {k: v[a : self._n].tolist() for k, v in self._buf.items()},
            "stuck": [self._stuck.value, self._stuck.length],
            "theta_before": [t.tolist() for t in self._theta_before],
            "last_prediction": self._last_prediction,
            "sky": self._sky.state(),
            "counters": {"samples": self.counters.samples,
                         "faulty_samples": self.counters.faulty_samples,
                         "faults": self.counters.faults, "estimated": self.counters.estimated,
                         "skipped": self.counters.skipped,
                         "no_prediction": self.counters.no_prediction},
        }

    def restore(self, snap: Mapping) -> None:
        """Continue from a ``snapshot`` of the same model (ValueError if not: state_migration.py)."""
        if snap.get("model") != self.model.name or list(snap.get("names", [])) != self.model.names:
            raise ValueError(f"saved estimator state is for model {snap.get('model')!r} "
                             f"{snap.get('names')}, not {self.model.name!r} {self.model.names}")
        theta = np.clip(np.asarray(snap["theta"], dtype=float), self.lower, self.upper)
        if theta.shape != self.theta.shape or not np.all(np.isfinite(theta)):
            raise ValueError("saved estimator state: bad parameter vector")
        self.theta = theta
        self.rng.bit_generator.state = snap["rng"]
        self.restart_window()
        rows = {k: np.asarray(v, dtype=float) for k, v in snap["window"].items()}
        self._n = min((len(v) for v in rows.values()), default=0)
        for k, v in rows.items():
            self._buf[k] = np.full(self._cap, np.nan)
            self._buf[k][: self._n] = v[len(v) - self._n :]
        self._stuck = StuckRun(float(snap["stuck"][0]), int(snap["stuck"][1]), self.stuck_samples)
        self._theta_before.extend(np.asarray(t, dtype=float) for t in snap["theta_before"])
        self._last_prediction = snap["last_prediction"]
        if "sky" in snap:  # states saved before the cloud tracker existed start it afresh
            self._sky.restore(snap["sky"])
        c = snap["counters"]
        self.counters = Counters(c["samples"], c["faulty_samples"], dict(c["faults"]),
                                 dict(c["estimated"]), dict(c["skipped"]), c["no_prediction"])

    # -- checks and buffer ----------------------------------------------------------------
    def _strike_stuck_run(self) -> None:
        """A stuck run was just recognised: its repeats 2 … stuck_samples − 1 were accepted as
        measurements. Strike them from the buffer (no later window uses them) and restore the
        parameters held before the first repeat, so the flat readings do not steer the model
        while it dead-reckons through the fault (the first reading of the run was a real one)."""
        repeats = self.stuck_samples - 2
        air = self._idx.get("t_in")  # the groups fitted on other outputs learnt nothing from it
        if air is not None and len(self._theta_before) >= repeats + 1:
            self.theta[air] = self._theta_before[-(repeats + 1)][air]
        if "t_in" in self._buf:
            self._buf["t_in"][max(self._n - repeats, 0) : self._n] = np.nan
        key = "t_in:stuck_struck_out"  # counted apart: these samples were accepted on arrival
        self.counters.faults[key] = self.counters.faults.get(key, 0) + repeats

    def _derive(self, values: dict[str, float], time: np.datetime64 | None) -> dict[str, float]:
        """The same derived drivers as a whole-series replay (``prepare_drivers``), for one row;
        the cloud fraction from the tracker (the same as over a whole series)."""
        cols = {k: np.array([v]) for k, v in values.items()}
        cloud = np.array([self._sky.update(time, values.get("i_glob", np.nan))])
        stamp = np.array([np.datetime64(0, "s") if time is None else
                          np.datetime64(time, "s")])  # type: ignore[call-overload]  # numpy stub gap
        x = prepare_drivers(Series(stamp, self.dt, cols), self.gh, cloud=cloud)
        return {k: float(v[0]) for k, v in x.items()}

    def _append(self, row: Mapping[str, float]) -> None:
        for k in row:
            if k not in self._buf:  # a column first seen now (a sensor added live): NaN before
                self._buf[k] = np.full(self._cap, np.nan)
        if self._n == self._cap:  # keep the last `history` rows; amortised O(1) per sample
            keep = self.history
            for arr in self._buf.values():
                arr[:keep] = arr[self._cap - keep :]
                arr[keep:] = np.nan
            self._n = keep
        for k, arr in self._buf.items():
            arr[self._n] = row.get(k, np.nan)
        self._n += 1

    def _window(self, rows: int) -> dict[str, np.ndarray] | None:
        """Views of the last ``rows`` rows of every driver, or None before enough samples."""
        if self._n < rows:
            return None
        a = self._n - rows
        return {k: v[a : self._n] for k, v in self._buf.items()}

    # -- estimation -------------------------------------------------------------------------
    def _free(self, g: GroupSettings, now: Mapping[str, np.ndarray]) -> np.ndarray:
        """Indices of the group's parameters whose process is active at t."""
        idx = self._idx[g.output]
        active = [bool(self._conditions[j](now)[0]) for j in idx]
        return idx[np.array(active, dtype=bool)]

    def _box(self, free: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Adaptive search box C_j (1 ± R_j) (IV.53–IV.54) inside the hard box (table 13)."""
        lo, hi = self.lower[free], self.upper[free]
        c, r = self.theta[free], self.variation[free]
        # A value at 0 would give a box of width 0 forever: the half-width never drops below
        # R_j times 1 % of the hard range.
        half = r * np.maximum(np.abs(c), 0.01 * (hi - lo))
        whole = ~np.isfinite(r)
        b_lo = np.where(whole, lo, np.maximum(lo, c - half))
        b_hi = np.where(whole, hi, np.minimum(hi, c + half))
        return b_lo, b_hi

    def _penalty(self, g: GroupSettings, free: np.ndarray, cand: np.ndarray) -> np.ndarray | float:
        if g.prior <= 0:
            return 0.0
        z = (cand - self.theta0[free]) / (self.upper[free] - self.lower[free])
        return g.prior * np.mean(z * z, axis=1)

    def _candidate_columns(self, free: np.ndarray, t_start: float,
                           x: Mapping[str, np.ndarray]) -> Callable[[np.ndarray], tuple]:
        """``columns(cand) -> (p, start, step)``: the parameter columns (P, 1) of candidates
        (P, free), the others held (``Model.columns`` without checks), the start state (P, 1)
        and the model's stepper over the window ``x`` for those columns. One buffer and one
        stepper per population size, rewritten (reset) at every call (a cost call is done with
        them; a new stepper per call was ~5 % of a replay under cProfile)."""
        base, names, held = self.theta, self._names, {}

        def columns(cand: np.ndarray) -> tuple[dict[str, np.ndarray], np.ndarray, Stepper]:
            if cand.shape[0] not in held:
                rows = np.repeat(base[:, None], cand.shape[0], axis=1)  # (k, P): a row a parameter
                p = {name: rows[j, :, None] for j, name in names}
                held[cand.shape[0]] = (rows, p, np.full((cand.shape[0], 1), t_start),
                                       self.model.stepper(p, x, self.capacity_c, self.dt))
            rows, p, start, step = held[cand.shape[0]]
            rows[free] = cand.T
            step.reset()
            return p, start, step

        return columns

    def _estimate_air(self, g: GroupSettings) -> bool | None:
        """Virtual model of the temperature: free run over [t - n, t] for all bats at once."""
        n = g.window
        x: Mapping[str, np.ndarray] | None = self._window(n + 1)
        if x is None:
            return False
        now = {k: v[-1:] for k, v in x.items()}
        free = self._free(g, now)
        if free.size == 0:
            return None
        measured = x["t_in"]
        if not np.all(np.isfinite(measured)) or not all(
            np.all(np.isfinite(x[c][:-1])) for c in self._needed
        ):
            return False
        model = self.model
        x = model.prepare(x)  # the terms' driver-only columns, once for every candidate
        target = measured[1:]
        columns = self._candidate_columns(free, measured[0], x)

        def cost(cand: np.ndarray) -> np.ndarray:
            p, start, step = columns(cand)
            # observation terms: simulate the true state behind the reading, compare readings
            state = model.true_state(p, x, start, 0)
            states = np.empty((cand.shape[0], n))
            for s in range(n):  # III.23 integrated step by step from the measured T_in[t - n]
                state = step(state, s)
                states[:, s] = state[:, 0]
            err = model.reading(p, x, states, slice(1, n + 1)) - target
            mse = np.add.reduce(err * err, axis=1) / n
            return mse + self._penalty(g, free, cand) if g.prior > 0 else mse

        lo, hi = self._box(free)
        res = self.search(cost, lo, hi, self._bat[g.output], "rsba", self.rng, x0=self.theta[free])
        if np.all(np.isfinite(res.best)) and np.isfinite(res.cost):
            self.theta[free] = np.clip(res.best, self.lower[free], self.upper[free])
        return True

    def _estimate_rad(self, g: GroupSettings) -> bool | None:
        """Radiation sub-model i_in = c_tsw i_glob (III.35) on the sunlit samples of the window."""
        radiation = self.model.radiation
        if radiation is None:
            return None
        x = self._window(g.window)
        if x is None:
            return False
        if "i_in" not in x or not np.any(np.isfinite(x["i_in"])):
            return None  # not measured (yet): c_tsw keeps its value
        now = {k: v[-1:] for k, v in x.items()}
        free = self._free(g, now)
        if free.size == 0:
            return None
        j = self.model.index(radiation.parameter.name)
        if free.size != 1 or free[0] != j:  # the radiation sub-model has a single parameter
            raise ValueError(f"online.i_in: only {radiation.parameter.name} can be fitted on i_in")
        lo, hi = self._box(free)
        prior = None
        if g.prior > 0:
            prior = (g.prior, float(self.theta0[j]), float(self.upper[j] - self.lower[j]))
        fit = radiation.fit(x, bounds=(float(lo[0]), float(hi[0])), min_pairs=MIN_RADIATION_PAIRS,
                            prior=prior)
        if fit is None:
            return False
        self.theta[j] = float(np.clip(fit.value, self.lower[j], self.upper[j]))
        return True

    # -- prediction ---------------------------------------------------------------------------
    def _predict(self, row: Mapping[str, float]) -> tuple[float | None, bool]:
        """T_in[t + 1] from T_in[t] (or the previous prediction when T_in[t] is missing)."""
        state = row.get("t_in", np.nan)
        dead = False
        if not np.isfinite(state):
            if self._last_prediction is None:
                return None, False
            state, dead = self._last_prediction, True
        if not all(np.isfinite(row.get(c, np.nan)) for c in self._needed):
            return None, dead
        x = self._window(1)
        assert x is not None
        p = self.model.columns(self.theta[None, :])
        # Observation terms: step the true state behind the reading; the offset at t stands for
        # the one at t + 1 (its drivers are not known yet; sensor errors move slowly). The
        # drivers at t + 1 are not known either: the step holds those at t (step.py).
        model = self.model
        true = model.true_state(p, x, np.array([[state]]), 0)
        t_next = model.reading(p, x, model.step(p, x, true, 0, self.capacity_c, self.dt), 0)
        value = float(np.asarray(t_next).reshape(-1)[0])
        if not np.isfinite(value):
            return None, dead
        return value, dead
