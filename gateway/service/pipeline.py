"""One greenhouse's live estimator: every final minute → online estimator → causal forecasts,
fluxes, (virtual ventilation sensor) → estimate rows, saved with the estimator's state.

Forecasts are causal: over the horizon the outside drivers come from the greenhouse's weather
outlook (gateway/estimate/outlook.py, the config's; ``default_outlook`` unless it names another), which
sees only what was measured up to now; each forecast row names the outlook. The forecast is
replay's ``corrected`` by default (gateway/service/forecaster.py: the model from its disturbance
filter's state, combined with the RLS ARX by recent skill, then corrected by a regression on its
own matured errors); ``forecast="combined"``, ``"adaptive_kf"`` or ``"adaptive"`` chooses
another. A hole in the data
longer than ``gap_s`` restarts the estimator's window and keeps its parameters; shorter holes
are stepped as missing minutes (the estimator dead-reckons through them, as in ``replay``).
Each batch of minutes is one transaction: its rows and the cursor after it, so a restart resumes
exactly where the last commit left off. The estimator's snapshot (~176 KB) is rewritten only once
``snapshot_every_min`` minutes have been stepped since the last one; the batches in between
commit a journal of the minutes stepped since (their values, a few hundred bytes a minute), and a
restart steps the journal's minutes again from the snapshot without making their rows again
(they are committed): the same values in the same order, so the same state (the estimator is
deterministic, its random state is in the snapshot). Stepping them again from the store would
not do: a lagging kit's late records change a minute after it was stepped. A snapshot of another
model (the greenhouse's ``model =`` changed, e.g. ``prototype`` → ``prototype+vent_control``) is
migrated (gateway/estimate/state_migration.py: the matching parameters keep their values, the
start's log line names what was kept, added and dropped); one that cannot be used starts anew,
saying why.
A virtual ventilation sensor reads the fluxes of its own model kind: the forecasting estimator's
when the kinds agree, else those of a second estimator of its kind stepped on the same minutes
(gateway/service/ventilation.py; its state is saved beside the forecasting one).
Minutes with an outside temperature and no rh_out (the sky temperature then from T_out alone)
are said in the log once per outage, not per minute (gateway/service/humidity_watch.py).
"""

from __future__ import annotations

import logging
import math
import sqlite3
import time
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from gateway.estimate.horizon import live_block
from gateway.estimate.online import OnlineEstimator, online_settings
from gateway.estimate.outlook import Outlook, make_outlook
from gateway.estimate.state_migration import migrate_state
from gateway.greenhouse import Greenhouse
from gateway.model.model import Model
from gateway.service.forecaster import LiveForecaster
from gateway.service.humidity_watch import HumidityWatch
from gateway.service.minutes import KIT_COLUMNS, Minute, final_before, first_minute, read_minutes
from gateway.service.settings import EstimatorSettings, GreenhouseSettings
from gateway.service.ventilation import HISTORY_KEY, STATE_KEY, SensorFeed, VentilationSensor
from gateway.store.db import transaction
from gateway.store.live import (
    EstimateRow,
    Journal,
    add_estimates,
    load_journal,
    load_state,
    save_journal,
    save_state,
)

log = logging.getLogger("serra.gateway")
DT = 60.0
BATCH = 30  # minutes per transaction while catching up
COMMIT_S = 0.5  # [wall s] a batch is committed early when it takes longer than this
HUMIDITY_BACK_MIN = 60
"""Minutes rh_out must be back in a row before the log says so (humidity_watch.py)."""


@dataclass
class StepReport:
    stepped: int = 0
    restarts: int = 0
    last_minute: int | None = None
    rows: int = 0
    more: bool = False  # stopped after max_batches with final minutes still to step
    notes: list[str] = field(default_factory=list)


class GreenhousePipeline:
    """The estimator of one greenhouse, resumed from (and saved to) the store."""

    def __init__(self, name: str, gh: Greenhouse, model: Model, inside: int, outside: int,
                 theta0: np.ndarray | None, *,
                 horizons: tuple[int, ...] = EstimatorSettings.horizons_min,
                 outlook: str = GreenhouseSettings.outlook, seed: int = EstimatorSettings.seed,
                 gap_s: float = EstimatorSettings.gap_s,
                 history_min: int = EstimatorSettings.history_min,
                 ventilation: VentilationSensor | None = None,
                 forecast: str = EstimatorSettings.forecast,
                 snapshot_every_min: int = EstimatorSettings.snapshot_every_min) -> None:
        """The keyword defaults are the config's ([estimator] and [[greenhouse]] outlook), read
        from its dataclasses so that they cannot drift apart."""
        self.name, self.gh, self.model = name, gh, model
        self.inside, self.outside = inside, outside
        self.devices = {inside, outside}
        self.horizons = horizons
        self.outlook: Outlook = make_outlook(outlook, gh)
        self.gap_s = gap_s
        self.ventilation = ventilation
        self.vent: SensorFeed | None = None
        self._fresh = (theta0, seed, forecast)  # what a new estimator and forecaster start from
        self._start_fresh()
        self.cursor: int | None = None  # last minute stepped
        self.snapshot_every_s = 60 * snapshot_every_min
        self.saved: int | None = None  # last minute of the saved snapshot (None: none saved)
        self.journal: list[tuple[int, list[float]]] = []  # minutes stepped since it: values
        self.history_min = history_min
        self.hist: dict[str, deque[float]] = {c: deque(maxlen=history_min) for c in KIT_COLUMNS}
        self.hist_minute: int | None = None
        self.humidity = HumidityWatch(name, HUMIDITY_BACK_MIN)
        self.state = "waiting for data"

    def _start_fresh(self) -> None:
        theta0, seed, forecast = self._fresh
        m, gh = self.model, self.gh
        self.est = OnlineEstimator(m, gh, theta0, online_settings(m, gh), dt=DT, seed=seed)
        self.forecaster = LiveForecaster(m, gh, DT, self.horizons, forecast)
        if self.ventilation is not None:
            self.vent = SensorFeed(self.ventilation, m, gh, seed, DT)

    # -- start ------------------------------------------------------------------------------
    def resume(self, conn: sqlite3.Connection) -> str:
        """Load the saved state (or choose where a new estimator starts); returns a log line."""
        saved = load_state(conn, self.name)
        if saved is not None:
            note = ""
            try:
                state = saved.state
                if state.get("model") != self.model.name:  # the config's model changed
                    state, moved = migrate_state(state, self.model, self.gh, self.est.theta0)
                    note = "; " + moved.describe()
                self.est.restore(state)
                # a state saved before the forecaster existed starts it afresh
                self.forecaster.restore(state.get("forecaster"))
                if self.vent is not None:  # the state as saved: it may hold the sensor's kind
                    note += self.vent.restore(saved.state)
                journal = load_journal(conn, self.name)
                if journal is not None and journal.columns != KIT_COLUMNS:
                    raise ValueError(f"journal of columns {journal.columns}")
            except (ValueError, KeyError, TypeError, IndexError) as e:
                msg = f"greenhouse {self.name}: saved estimator state not used ({e}); starting anew"
                saved = None
                self._start_fresh()  # a restore that failed half-way leaves nothing behind
            else:
                self.cursor = self.saved = saved.minute if journal is None else journal.snapshot
                self._load_history(conn)
                if journal is not None:
                    note += self._replay(journal, saved.minute)
                self.state = "running"
                return (f"greenhouse {self.name}: estimator resumed at {_iso(saved.minute)} "
                        f"({self.est.counters.samples} minutes stepped so far){note}")
        else:
            msg = f"greenhouse {self.name}: new estimator ({self.model.name})"
        if self.vent is not None:
            msg += self.vent.describe()
        first = first_minute(conn, self.inside)
        if first is not None:  # a store with history: warm up on its last `history_min` minutes
            last = conn.execute("SELECT max(minute) FROM minute WHERE device_id=?",
                                (self.inside,)).fetchone()[0]
            self.cursor = max(first, last - 60 * self.history_min) - 60
        return msg

    def _replay(self, journal: Journal, cursor: int) -> str:
        """Step the journal's minutes again from the snapshot, their rows and notes dropped
        (committed, said); returns what the start's log line adds."""
        for minute, values in journal.minutes:
            self._advance_to(Minute(minute, dict(zip(KIT_COLUMNS, values, strict=True))),
                             StepReport())
        if self.cursor != cursor:  # written in one transaction with it: cannot happen
            raise RuntimeError(f"greenhouse {self.name}: the journal ends at {self.cursor}, "
                               f"the saved cursor is {cursor}")
        return f"; {len(journal.minutes)} minutes stepped again from the snapshot's journal"

    def _load_history(self, conn: sqlite3.Connection) -> None:
        assert self.cursor is not None
        start = self.cursor - 60 * (self.history_min - 1)
        for m in read_minutes(conn, self.inside, self.outside, start, self.cursor + 60):
            self._remember(m)

    # -- stepping ---------------------------------------------------------------------------
    def step_pending(self, conn: sqlite3.Connection, now: float, settle_s: float,
                     max_wait_s: float, max_batches: int = 1_000_000) -> StepReport:
        """Step the final minutes after the cursor, one transaction per batch of ``BATCH``, at
        most ``max_batches`` batches (``report.more`` says whether some are left)."""
        report = StepReport()
        bound = final_before(conn, self.devices, now, settle_s, max_wait_s)
        start = (self.cursor + 60) if self.cursor is not None else -(2**62)
        for _ in range(max_batches):
            nxt = conn.execute("SELECT min(minute) FROM minute WHERE device_id=? AND minute>=? "
                               "AND minute<?", (self.inside, start, bound)).fetchone()[0]
            if nxt is None:
                return report
            minutes = read_minutes(conn, self.inside, self.outside, nxt, min(bound, nxt + 60 * BATCH))
            rows: list[EstimateRow] = []
            t0 = time.monotonic()
            for m in minutes:
                rows += self._advance_to(m, report)
                if time.monotonic() - t0 > COMMIT_S:
                    break  # a slow machine commits more often: a crash loses less work
            assert self.cursor is not None
            with transaction(conn):
                add_estimates(conn, rows)
                self._save(conn, now)
            report.rows += len(rows)
            report.last_minute = self.cursor
            start = self.cursor + 60
        report.more = True
        return report

    def _save(self, conn: sqlite3.Connection, now: float) -> None:
        """The cursor, with the snapshot once ``snapshot_every_s`` have been stepped since the
        last one, else with the journal of the minutes since it (in the caller's transaction)."""
        assert self.cursor is not None
        if self.saved is None or self.cursor - self.saved >= self.snapshot_every_s:
            save_state(conn, self.name, self.model.name, self.cursor, self._snapshot(), now)
            self.saved, self.journal = self.cursor, []
        else:
            save_journal(conn, self.name, self.cursor,
                         Journal(self.saved, KIT_COLUMNS, self.journal))

    def _snapshot(self) -> dict:
        snap = self.est.snapshot()
        snap["forecaster"] = self.forecaster.snapshot()
        if self.vent is not None:
            for key, part in ((STATE_KEY, self.vent.snapshot()), (HISTORY_KEY, self.vent.history())):
                if part is not None:
                    snap[key] = part
        return snap

    def _advance_to(self, m: Minute, report: StepReport) -> list[EstimateRow]:
        self.journal.append((m.minute, [m.values.get(c, math.nan) for c in KIT_COLUMNS]))
        rows: list[EstimateRow] = []
        if self.cursor is not None and m.minute - self.cursor > self.gap_s:
            gap_h = (m.minute - self.cursor) / 3600
            self.est.restart_window()
            self.forecaster.reset()
            if self.vent is not None:
                self.vent.restart_window()
            report.restarts += 1
            report.notes.append(f"greenhouse {self.name}: window restarted after a {gap_h:.1f} h "
                                f"gap in the data (parameters kept)")
        elif self.cursor is not None:
            for hole in range(self.cursor + 60, m.minute, 60):  # short hole: missing minutes
                rows += self._step(Minute(hole, dict.fromkeys(KIT_COLUMNS, math.nan)))
                report.stepped += 1
        rows += self._step(m)
        report.stepped += 1
        said = self.humidity.see(m.minute, m.values)
        if said:
            report.notes.append(said)
        return rows

    def _remember(self, m: Minute) -> None:
        if self.hist_minute is not None:
            missing = min((m.minute - self.hist_minute) // 60 - 1, self.history_min)
            for _ in range(max(missing, 0)):
                for c in KIT_COLUMNS:
                    self.hist[c].append(math.nan)
        for c in KIT_COLUMNS:
            self.hist[c].append(m.values.get(c, math.nan))
        self.hist_minute = m.minute

    def _step(self, m: Minute) -> list[EstimateRow]:
        self._remember(m)
        when = np.datetime64(int(m.minute), "s")
        pred = self.est.update(m.values, time=when)
        self.forecaster.update(self.est.last_row, pred.theta, when)
        if self.vent is not None:
            self.vent.update(m.values, when)
        self.cursor = m.minute
        self.state = "running"
        t, g = float(m.minute), self.name
        rows = [EstimateRow(g, t, "online", n, float(v), p.unit)
                for n, v, p in zip(self.model.names, pred.theta, self.model.parameters, strict=True)]
        t_in = m.values.get("t_in", math.nan)
        if math.isfinite(t_in):
            rows.append(EstimateRow(g, t, "measured", "t_in", t_in, "degC"))
        if pred.t_in is not None:
            info = "dead_reckoning" if pred.dead_reckoning else ""
            rows.append(EstimateRow(g, t, "online", "t_in_next", pred.t_in, "degC", info))
        if not math.isfinite(t_in):
            return rows
        flux = self.model.fluxes_at(pred.theta, self.est.last_row, t_in)
        rows += [EstimateRow(g, t, "flux", n, v, "W m-2") for n, v in flux.items()]
        rows += [EstimateRow(g, t, "forecast", f"t_in+{h}min", v, "degC", self.outlook.name)
                 for h, v in self._forecasts(pred.theta, t)]
        if self.vent is not None:
            vent = self.vent.estimate(t, t_in, self.est.last_row, flux)
            if vent is not None:
                flag = "out_of_range" if vent.out_of_range else ""
                rows += [EstimateRow(g, t, "vsensor", "ventilation_flow", vent.flow, "m3 s-1", flag),
                         EstimateRow(g, t, "vsensor", "ventilation_heat_loss", vent.heat_loss,
                                     "W m-2", flag)]
        return rows

    def _forecasts(self, theta: np.ndarray, t: float) -> list[tuple[int, float]]:
        """T_in at t + h for each horizon (the forecaster's kind: from the measured T_in at t
        or the filter's state, gateway/service/forecaster.py), with the outlook's drivers over
        (t, t + h]: nothing after t is read."""
        n_hist = len(self.hist["t_in"])
        time = np.datetime64(int(t), "s") + np.arange(-n_hist + 1, 1) * np.timedelta64(60, "s")
        history = {c: np.fromiter(v, float, n_hist) for c, v in self.hist.items()}
        cloud = self.est.last_row.get("cloud", math.nan)  # the estimator's, as replay holds it
        x = live_block(self.outlook, history, time, max(self.horizons), DT, self.gh, cloud)
        got = self.forecaster.forecasts(theta, x, self.horizons)
        return [(h, v) for h, v in got.items() if math.isfinite(v)]


def _iso(t: float) -> str:
    return time.strftime("%Y-%m-%dT%H:%MZ", time.gmtime(t))
