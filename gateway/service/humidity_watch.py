"""Whether the live estimator's sky temperature reads the outside humidity, said in the log once
per outage instead of never (or per minute).

Without rh_out the clear-sky emissivity of the sky temperature comes from the outside air
temperature alone (Swinbank 1963) instead of its vapour pressure (Brutsaert 1975;
gateway/model/sky.py ``clear_sky_emissivity``), row by row and with no error: the estimator, its
flux terms and the forecasts' sky all take it. ``calibrate``/``replay``/``diagnose`` say the same
in their ``no_rh_out``/``rh_out_gaps`` notes (gateway/cli/column_notes.py).
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping

from gateway.model.sky import WITHOUT_HUMIDITY


class HumidityWatch:
    """Watches the minutes a greenhouse's estimator steps. A minute with an outside temperature
    and no ``rh_out`` starts an outage: one line naming its first minute. The outage ends, with
    one more line, once ``back_min`` consecutive such minutes have rh_out again, so a channel
    that flickers is not logged per flicker. Minutes without an outside temperature count for
    neither (the sky temperature needs it in both cases)."""

    def __init__(self, greenhouse: str, back_min: int) -> None:
        self.greenhouse, self.back_min = greenhouse, back_min
        self.missing = False  # in an outage (said)
        self._back: float | None = None  # first minute of the current run with rh_out again
        self._run = 0  # minutes in that run

    def see(self, minute: float, values: Mapping[str, float]) -> str | None:
        """Take one stepped minute (start [unix s], kit column values); the line to log, if any."""
        if not math.isfinite(values.get("t_out", math.nan)):
            return None
        has = math.isfinite(values.get("rh_out", math.nan))
        if not self.missing:
            if has:
                return None
            self.missing, self._back, self._run = True, None, 0
            return (f"greenhouse {self.greenhouse}: no outside relative humidity (rh_out) from "
                    f"{_iso(minute)}Z while the outside temperature is measured: "
                    f"{WITHOUT_HUMIDITY} (said once; a line follows when rh_out is back for "
                    f"{self.back_min} min)")
        if not has:
            self._back, self._run = None, 0
            return None
        if self._back is None:
            self._back = minute
        self._run += 1
        if self._run < self.back_min:
            return None
        self.missing = False
        return (f"greenhouse {self.greenhouse}: outside relative humidity (rh_out) back since "
                f"{_iso(self._back)}Z: the sky temperature reads its vapour pressure again")


def _iso(t: float) -> str:
    return time.strftime("%Y-%m-%dT%H:%M", time.gmtime(t))
