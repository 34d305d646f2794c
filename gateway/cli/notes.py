"""What calibrate, replay, diagnose and vsensor say beside their figures about unusual but valid
data (docs/data-format.md, "Notes"): holes, a missing site, a site or clock off by hours, an
optional column the model reads but the data lacks, a record too short to judge.

One place builds the notes of a run: :func:`input_notes` when the data is loaded,
:func:`short_heldout_note` after a diagnosis, :func:`params_notes` for ``replay --params``,
:func:`vsensor_notes` for what ``vsensor`` says of its run. The
commands render that one list: on stderr as each note is made (before a long computation),
in their JSON (``"notes": [{"code", "level", "message"}]``, empty when there is nothing to say),
after their text report and in diagnose's ``report.md``. A note's ``code`` is stable; its
message is for people.
"""

from __future__ import annotations

import sys
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np

from gateway.cli.column_notes import column_notes
from gateway.greenhouse import Greenhouse
from gateway.kitcsv import LOOKS_FAHRENHEIT
from gateway.model.model import Model
from gateway.model.params_file import OutOfBox
from gateway.model.sky import DEFAULT_CLOUD
from gateway.series import Series


@dataclass(frozen=True)
class Note:
    """One thing a run says about its data: ``code`` (stable, for programs), ``message`` (one
    paragraph naming the file or column), ``level`` ``note`` or ``warning`` (the figures are
    likely wrong). ``echo`` False: already on stderr (the CSV reader logs its own notices)."""

    code: str
    message: str
    level: str = "note"
    echo: bool = True

    def to_json(self) -> dict[str, str]:
        return {"code": self.code, "level": self.level, "message": self.message}

    def line(self) -> str:
        return f"{self.level}: {self.message}"


def echo(notes: Iterable[Note]) -> None:
    """Print the notes on stderr as they are made (the CSV reader's are there already)."""
    for note in notes:
        if note.echo:
            print(note.line(), file=sys.stderr)


def as_json(notes: Iterable[Note]) -> list[dict[str, str]]:
    """The ``notes`` list of a command's JSON result."""
    return [n.to_json() for n in notes]


def text_block(notes: Sequence[Note]) -> str:
    """The lines closing a text report (so that stdout saved to a file keeps them)."""
    return "".join(f"{n.line()} [{n.code}]\n" for n in notes)


def input_notes(series: Series, gh: Greenhouse, model: Model, data: str, greenhouse: str,
                command: str | None = None, needs: Sequence[str] = ()) -> list[Note]:
    """Every note the loaded data gives rise to, in the order they are printed: the CSV
    reader's notices, holes in the columns the model needs (and ``needs``, the columns the run
    reads besides: vsensor's inputs), no site, daylight in the site's night, optional columns
    the run reads but the data lacks (column_notes.py). ``command``: ``calibrate``,
    ``replay``, ``diagnose`` or ``vsensor`` (what reads which column)."""
    notes = [Note("csv_reader", text, "warning" if LOOKS_FAHRENHEIT in text else "note",
                  echo=False) for text in series.notices]
    extra = [c for c in needs if c not in model.requires]
    gap = gap_note(series, [*model.requires, *extra],
                   "the model or the sensor" if extra else "the model")
    if gap:
        notes.append(Note("data_gaps", f"{data}: {gap}"))
    if gh.site is None:
        notes.append(Note("no_site", site_note_text(greenhouse)))
    night = night_radiation_note(series, gh)
    if night:
        notes.append(Note("site_time_mismatch", f"{data}: {night}", "warning"))
    for code, message in column_notes(series, gh, model, data, command):
        notes.append(Note(code, message))
    return notes


VSENSOR_WARNINGS = ("other_greenhouse",)
"""vsensor notes whose figures are likely wrong: a sensor trained on another house flags every
minute (docs/vsensor.md)."""


def vsensor_notes(made: Iterable[tuple[str, str]]) -> list[Note]:
    """The notes of a vsensor run from its (code, message) pairs (gateway/vsensor/batch.py
    ``BatchResult.notes``): ``not_scored`` (no reference flow for the CSV) a note,
    ``other_greenhouse`` a warning."""
    return [Note(code, message, "warning" if code in VSENSOR_WARNINGS else "note")
            for code, message in made]


def site_note_text(greenhouse: str) -> str:
    """Without a site at all, what the sky temperature then rests on."""
    return (f"{greenhouse} gives no [site] and no --site was given: the cloudiness cannot be "
            f"read from the radiation, so the sky temperature takes a cloud fraction of "
            f"{DEFAULT_CLOUD:g} and the outside humidity only")


def params_notes(outside: Iterable[OutOfBox], path: str, uses: str) -> list[Note]:
    """``--params`` values outside the model's hard box: the value the run starts from
    instead (gateway/model/params_file.py)."""
    return [Note("params_outside_box", o.describe(path, uses)) for o in outside]


NIGHT_RADIATION = 50.0
"""Measured global radiation [W m-2] that is daylight, not a pyranometer's night offset."""
NIGHT_SHARE = 0.25
"""Share of that radiation measured with the sun below the horizon above which the site or
the times are wrong by hours [-]. On correctly timed data it is 0-3 % (the Bleiswijk file's
hourly means lag the sun by ~30 min); with the longitude or UTC offset off by 8-10 h, 96-99 %."""


def night_radiation_note(series: Series, gh: Greenhouse) -> str | None:
    """When most daylight radiation in the data falls while the sun is down at the
    greenhouse's ``[site]`` (NOAA sun, gateway/model/solar.py), what is wrong; else None.
    A longitude of the wrong sign or local times written with ``Z`` shift the clear sky by
    hours against the data: the clear-sky index then sits at 0 by day, the sky reads overcast
    and the outlook forecasts darkness, with no error anywhere."""
    from gateway.model.solar import solar_position

    if gh.site is None or "i_glob" not in series:
        return None
    i = series["i_glob"]
    day = np.isfinite(i) & (i > NIGHT_RADIATION)
    if np.count_nonzero(day) * series.step < 3600.0:
        return None
    sun = solar_position(series.time[day], gh.site.latitude, gh.site.longitude).cos_zenith
    share = float(np.mean(sun <= 0.0))
    if share <= NIGHT_SHARE:
        return None
    return (f"{100 * share:.0f} % of the radiation above {NIGHT_RADIATION:g} W m-2 is measured "
            f"while the sun is below the horizon at latitude {gh.site.latitude:g}, longitude "
            f"{gh.site.longitude:g} (east positive): the site or the times' UTC offset is wrong by "
            "hours (local times written with Z?), and the clear-sky index, the cloudiness and "
            "the outlook are read against the wrong sun (docs/data-format.md)")


def gap_note(series: Series, names: tuple[str, ...] | list[str], who: str = "the model"
             ) -> str | None:
    """What the data lacks on the grid, said once: rows without a value of a column ``who``
    needs (``names``; gaps longer than the interpolation limit, empty cells), as holes, with
    the longest one's length and start; None when nothing is missing. Nothing is filled in
    beyond the interpolation of docs/data-format.md."""
    cols = [series[c] for c in names if c in series.columns]
    if not cols or len(series) == 0:
        return None
    missing = ~np.all(np.isfinite(np.vstack(cols)), axis=0)
    if not missing.any():
        return None
    edge = np.diff(np.concatenate(([0], missing.astype(np.int8), [0])))
    starts, ends = np.flatnonzero(edge == 1), np.flatnonzero(edge == -1)
    k = int(np.argmax(ends - starts))
    minutes = (ends[k] - starts[k]) * series.step / 60.0
    length = f"{minutes / 60.0:.1f} h" if minutes >= 120 else f"{minutes:g} min"
    return (f"{int(missing.sum())} of {len(series)} rows on the {series.step:g} s grid lack a "
            f"value {who} needs, in {len(starts)} hole(s), the longest {length} from "
            f"{series.time[starts[k]]}Z; no value is made up for them (docs/data-format.md)")


def short_heldout_note(time: np.ndarray, split_index: int) -> str | None:
    """What to say when the held-out part (rows ``split_index``.. of ``time``, UTC) is shorter
    than the ``significance.MIN_DAYS`` days the day test needs after a change: no finding can
    come out, and "no library effect improved the held-out error" would read as a clean bill of
    health. None when it is long enough, or without the day test (``judge.DAY_TEST``)."""
    from gateway.diagnose import judge, significance

    if not judge.DAY_TEST or len(time) < 2 or split_index >= len(time):
        return None
    step = float((time[1] - time[0]) / np.timedelta64(1, "s"))
    held = float((time[-1] - time[split_index]) / np.timedelta64(1, "s")) + step
    if held >= significance.MIN_DAYS * 86400.0:
        return None
    return (f"only {held / 86400.0:.1f} days are held out, and a change is judged once "
            f"{significance.MIN_DAYS} held-out days follow its start: no finding can be reported "
            f"from this record (give at least {2 * significance.MIN_DAYS} days with the default --split 0.5; "
            "docs/effects.md, \"Known limits\")")
