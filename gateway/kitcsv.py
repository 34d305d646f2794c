"""The kit CSV: the one measured-data format every tool reads and writes.

Spec: docs/data-format.md. Reading is strict: a bad
cell is an error naming the file, the line and the column, never a silent guess.
"""

from __future__ import annotations

import csv
import difflib
import logging
import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import TextIO

import numpy as np

log = logging.getLogger(__name__)
NOTICE = {"notice": "note"}
"""``extra`` of the reader's notices: the command line prints them as its other notes, ``note: …``
(gateway/cli/__init__.py); other programs' logging shows them as warnings."""
WARNING = {"notice": "warning"}
"""``extra`` of a notice whose figures are likely wrong (°F temperatures): ``warning: …``."""
LOOKS_FAHRENHEIT = "looks like °F"
"""The words of the °F notice (gateway/cli/notes.py makes it a warning)."""
FAHRENHEIT_MEDIAN = 45.0
"""Median [°C] of t_in or t_out over a day or more above which the column is read as °F. Measured
(2026-11-29, every 3-day window): no window of the hottest simulated houses in °C (the prototype
and almeria in Biskra's and Sevilla's July: t_in median at most 34.9, t_out 33.1) is flagged;
of Bleiswijk's autumn in °F, 27 of 48 windows are flagged, 14 refused by the range check (its
error says °F) and 7 pass unsaid (inside and outside medians below 45 °F, 7 °C)."""


@dataclass(frozen=True)
class Column:
    """One kit CSV column: name, unit and the physically possible range."""

    name: str
    unit: str
    lower: float
    upper: float
    meaning: str


COLUMNS: dict[str, Column] = {
    c.name: c
    for c in (
        Column("t_in", "°C", -40.0, 70.0, "inside air temperature"),
        Column("rh_in", "%", 0.0, 100.0, "inside relative humidity"),
        Column("t_out", "°C", -50.0, 60.0, "outside air temperature"),
        Column("rh_out", "%", 0.0, 100.0, "outside relative humidity"),
        Column("i_glob", "W m-2", -10.0, 1500.0, "outside global solar radiation"),
        Column("wind", "m s-1", 0.0, 75.0, "outside wind speed"),
        Column("i_in", "W m-2", -10.0, 1500.0, "global radiation under the cover"),
        Column("t_soil", "°C", -30.0, 80.0, "soil surface temperature"),
        Column("vent_roof", "%", 0.0, 100.0, "roof vent opening"),
        Column("vent_side", "%", 0.0, 100.0, "side vent opening"),
        Column("lai", "m2 m-2", 0.0, 15.0, "leaf area index"),
        Column("co2_in", "ppm", 0.0, 10000.0, "inside CO2 concentration"),
        Column("co2_out", "ppm", 0.0, 10000.0, "outside CO2 concentration"),
        Column("rain", "0/1", 0.0, 1.0, "rain detector"),
    )
}
TEMPERATURE_COLUMNS = ("t_in", "t_out", "t_soil")


class KitCsvError(ValueError):
    """A kit CSV file that cannot be read; the message names file, line and column."""


@dataclass
class KitData:
    """Samples of a kit CSV as read: irregular times allowed, NaN where a cell was empty.

    ``time`` holds UTC instants as numpy datetime64[s]; ``columns`` maps a kit column name to a
    float array of the same length.
    """

    time: np.ndarray
    columns: dict[str, np.ndarray]
    source: str = "<memory>"
    notices: list[str] = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.time)

    def seconds(self) -> np.ndarray:
        """Sample times as float seconds since the Unix epoch."""
        return self.time.astype("datetime64[s]").astype(np.int64).astype(float)


def parse_time(text: str) -> np.datetime64:
    """ISO 8601 with an explicit UTC offset or ``Z`` → datetime64[s] in UTC."""
    stamp = datetime.fromisoformat(text.strip())
    if stamp.tzinfo is None:
        raise ValueError("no UTC offset (write e.g. 2020-03-27T00:01:00Z)")
    stamp = stamp.astimezone(UTC).replace(tzinfo=None)
    return np.datetime64(stamp, "s")


def read_kit_csv(path: str | Path, required: Iterable[str] = ()) -> KitData:
    """Read and validate a kit CSV.

    Raises KitCsvError naming ``file:line`` and the column for: a missing required column, an
    unparsable time or number, a time not after the previous one, a value outside the column's
    physical range (with a hint when a temperature looks like kelvin or RH like a fraction).
    Unknown columns are ignored with a notice (logged and kept in ``KitData.notices``).
    """
    path = Path(path)
    try:
        # utf-8-sig: spreadsheets write UTF-8 with a byte-order mark, which is still UTF-8.
        handle = path.open(newline="", encoding="utf-8-sig")
    except OSError as exc:
        raise KitCsvError(f"{path}: cannot open: {exc.strerror}") from exc
    notices: list[str] = []
    with handle:
        reader = csv.reader(handle)
        try:
            header = _read_header(path, reader, required, notices)
            known = [(i, h) for i, h in enumerate(header) if h in COLUMNS]
            times, values = _read_rows(path, reader, len(header), known, notices)
        except UnicodeDecodeError as exc:  # decoded a block at a time: find the line
            raise KitCsvError(_not_utf8(path, exc)) from None
    _refuse_rh_fractions(path, values)
    _note_fahrenheit(path, times, values, notices)
    return KitData(
        time=np.array(times, dtype="datetime64[s]"),
        columns={k: np.array(v, dtype=float) for k, v in values.items()},
        source=str(path),
        notices=notices,
    )


def _read_header(path: Path, reader, required: Iterable[str], notices: list[str]) -> list[str]:
    """The header row, checked (``time`` first, no duplicate, the required columns present);
    unknown columns are noted in ``notices``."""
    try:
        header = [h.strip() for h in next(reader)]
    except StopIteration:
        raise KitCsvError(f"{path}: empty file, expected a header row") from None
    if not header or header[0] != "time":
        first = header[0] if header else ""
        sep = next((c for c in ";\t|" if c in first), None)
        hint = (f" (the separator must be a comma, not {sep!r})" if sep
                else " (column names are lower case: time, t_in, ...)" if first.lower() == "time"
                else "")
        raise KitCsvError(
            f"{path}:1: the first column must be 'time', found "
            f"{repr(first) if header else 'an empty line'}{hint}"
        )
    if len(set(header)) != len(header):
        dup = sorted({h for h in header if header.count(h) > 1})
        raise KitCsvError(f"{path}:1: duplicate column(s) {', '.join(dup)}")
    extra = [h for h in header[1:] if h not in COLUMNS]
    missing = [c for c in required if c not in header]
    if missing:
        raise KitCsvError(f"{path}:1: missing required column(s) {', '.join(missing)}"
                          + _unknown_hint(extra))
    if extra:
        notices.append(f"{path}: ignoring unknown column(s) {', '.join(extra)}")
        log.warning(notices[-1], extra=NOTICE)
    return header


def _unknown_hint(extra: list[str]) -> str:
    """What the header has instead: its unknown columns, each with the kit name it is close to
    (a typo such as ``tin`` or ``T_in``)."""
    if not extra:
        return ""
    names = []
    for h in extra:
        close = difflib.get_close_matches(h.lower(), COLUMNS, n=1, cutoff=0.6)
        names.append(f"{h!r} (did you mean {close[0]!r}?)" if close else repr(h))
    return (f"; the header has unknown column(s) {', '.join(names)} (kit column names: "
            f"docs/data-format.md)")


def _not_utf8(path: Path, exc: UnicodeDecodeError) -> str:
    """``file:line: not UTF-8 text`` with the line of the first byte that is not UTF-8 (the
    reader decodes block by block, so the exception's offset is within a block)."""
    data = path.read_bytes()
    if data[:2] in (b"\xff\xfe", b"\xfe\xff"):
        return f"{path}: UTF-16 text (a spreadsheet's 'Unicode text'); save the file as UTF-8 CSV"
    try:
        data.decode("utf-8")
    except UnicodeDecodeError as whole:
        line = data[: whole.start].count(b"\n") + 1
        return (f"{path}:{line}: not UTF-8 text ({whole.reason} at byte {whole.start}; save the "
                f"file as UTF-8)")
    return f"{path}: not UTF-8 text ({exc.reason})"


def _read_rows(path: Path, reader, width: int, known: list[tuple[int, str]],
               notices: list[str]) -> tuple[list[np.datetime64], dict[str, list[float]]]:
    """The data rows: times strictly increasing (an exact repeat of the row before is skipped
    with a notice), every known column's cells parsed and range-checked."""
    times: list[np.datetime64] = []
    values: dict[str, list[float]] = {h: [] for _, h in known}
    previous = None
    previous_cells: list[str] = []
    repeats: list[int] = []  # lines of exact repeats of the row before (logger re-sends)
    bad = _BadCells()
    for row in reader:
        line = reader.line_num
        if not row or (len(row) == 1 and not row[0].strip()):
            continue
        if len(row) != width:
            bad.raise_first()
            raise KitCsvError(f"{path}:{line}: {len(row)} cells, the header has {width}")
        try:
            stamp = parse_time(row[0])
        except ValueError as exc:
            bad.raise_first()  # an earlier bad cell is the first error
            why = ("not an ISO 8601 time with its UTC offset (write e.g. 2020-03-27T00:01:00Z; "
                   "day/month/year and Unix seconds are not read)"
                   if str(exc).startswith("Invalid isoformat") else str(exc))
            raise KitCsvError(f"{path}:{line}: column time: bad time {row[0]!r}: {why}") from None
        cells = [row[i].strip() for i, _ in known]
        if stamp == previous and cells == previous_cells:
            repeats.append(line)  # the same sample twice: keeping one loses nothing
            continue
        if stamp == previous:
            bad.raise_first()  # an earlier bad cell is the first error
            raise KitCsvError(
                f"{path}:{line}: column time: {row[0]} repeats the previous row's time with "
                f"other values; which one is the measurement?"
            )
        if previous is not None and stamp < previous:
            bad.raise_first()  # an earlier bad cell is the first error
            raise KitCsvError(
                f"{path}:{line}: column time: {row[0]} is not after the previous row "
                f"({previous}Z); rows must be in time order"
            )
        previous, previous_cells = stamp, cells
        times.append(stamp)
        for i, name in known:
            values[name].append(bad.parse(path, line, name, row[i]))
    bad.raise_first()
    if not times:
        raise KitCsvError(f"{path}: no data rows")
    if repeats:
        notices.append(
            f"{path}: skipped {len(repeats)} exact repeat(s) of the row before "
            f"(line(s) {', '.join(map(str, repeats[:5]))}{' …' if len(repeats) > 5 else ''})"
        )
        log.warning(notices[-1], extra=NOTICE)
    return times, values


def _note_fahrenheit(path: Path, times: list[np.datetime64], values: dict[str, list[float]],
                     notices: list[str]) -> None:
    """Say so when t_in or t_out looks like °F (the kit CSV is °C; such a file passes the range
    checks when it is cool, and every figure from it is wrong): over a day or more of rows (a
    few midday hours of a hot house can be above it in °C), a median above
    :data:`FAHRENHEIT_MEDIAN`."""
    if len(times) < 2 or times[-1] - times[0] < np.timedelta64(1, "D"):
        return
    for name in ("t_in", "t_out"):
        cells = np.array(values.get(name, []), dtype=float)
        cells = cells[np.isfinite(cells)]
        if len(cells) and np.median(cells) > FAHRENHEIT_MEDIAN:
            notices.append(
                f"{path}: column {name}: median {np.median(cells):.1f} over "
                f"{(times[-1] - times[0]) / np.timedelta64(1, 'D'):.1f} days, above "
                f"{FAHRENHEIT_MEDIAN:g} °C, which no greenhouse or climate holds for days: it "
                f"{LOOKS_FAHRENHEIT} (the kit CSV wants °C: (°F - 32) / 1.8); the figures "
                "computed from it are wrong")
            log.warning(notices[-1], extra=WARNING)


def _refuse_rh_fractions(path: Path, values: dict[str, list[float]]) -> None:
    for name in ("rh_in", "rh_out"):
        rh = np.array(values.get(name, []), dtype=float)
        rh = rh[np.isfinite(rh)]
        # Each value is possible alone; ten or more, all within 0-1 %, are a fraction, not %.
        if len(rh) >= 10 and rh.max() <= 1.0 and rh.max() > 0.0:
            raise KitCsvError(
                f"{path}: column {name}: every value is between 0 and 1 (max {rh.max():g}): "
                f"looks like a fraction, the kit CSV wants % (0-100)"
            )


class _BadCells:
    """The first bad cell is the error, and how many more follow is said with it: a logger whose
    humidity reads 100.4 % in fog has hundreds, and one line at a time would hide that."""

    def __init__(self) -> None:
        self.first: KitCsvError | None = None
        self.more = 0
        self.next_line = 0

    def parse(self, path: Path, line: int, name: str, cell: str) -> float:
        try:
            return _parse_cell(path, line, name, cell)
        except KitCsvError as exc:
            if self.first is None:
                self.first = exc
            else:
                self.more += 1
                self.next_line = self.next_line or line
            return math.nan

    def raise_first(self) -> None:
        """Raise the first bad cell's error, with the count of those after it (so far)."""
        if self.first is None:
            return
        more = (f" (and {self.more} more bad cell(s) after it, the next on line {self.next_line})"
                if self.more else "")
        raise KitCsvError(f"{self.first}{more}")


_MISSING_MARKS = {"na", "n/a", "#n/a", "null", "none", "-", "--", "?", "missing"}
"""What spreadsheets, R and loggers write for a missing value; the kit CSV leaves the cell empty."""


def _parse_cell(path: Path, line: int, name: str, cell: str) -> float:
    cell = cell.strip()
    if not cell:
        return math.nan
    try:
        value = float(cell)
    except ValueError:
        hint = " (a missing value is an empty cell)" if cell.lower() in _MISSING_MARKS else ""
        raise KitCsvError(f"{path}:{line}: column {name}: not a number: {cell!r}{hint}") from None
    if not math.isfinite(value):
        raise KitCsvError(f"{path}:{line}: column {name}: {cell!r} (leave the cell empty)")
    col = COLUMNS[name]
    if not col.lower <= value <= col.upper:
        hint = ""
        if name in TEMPERATURE_COLUMNS and 200.0 < value < 400.0:
            hint = " (looks like kelvin: the kit CSV wants °C)"
        elif name in TEMPERATURE_COLUMNS and col.upper < value <= 160.0:
            hint = " (°F? the kit CSV wants °C: (°F - 32) / 1.8)"
        elif name.startswith("rh_") and value > 100.0:
            hint = " (relative humidity cannot exceed 100 %)"
        raise KitCsvError(
            f"{path}:{line}: column {name}: {value:g} {col.unit} outside the physical range "
            f"[{col.lower:g}, {col.upper:g}]{hint}"
        )
    return value


def format_time(t: np.datetime64) -> str:
    """datetime64 (UTC) → ISO 8601 with a ``Z``."""
    # numpy's stubs have no datetime64(datetime64, unit) overload; numpy takes it
    return str(np.datetime64(t, "s")) + "Z"  # type: ignore[call-overload]


def write_kit_csv(
    path: str | Path | TextIO, time: np.ndarray, columns: Mapping[str, np.ndarray], digits: int = 6,
    header: bool = True,
) -> Path:
    """Write a kit CSV; NaN becomes an empty cell. Only kit columns are accepted. ``path`` may be
    an open text stream (``export --out -``: stdout), returned as ``Path("-")``; ``header``
    False: the rows only, to go on a file written in parts (the same columns each time)."""
    unknown = [c for c in columns if c not in COLUMNS]
    if unknown:
        raise ValueError(f"not kit CSV columns: {', '.join(unknown)} (see docs/data-format.md)")
    if not isinstance(path, str | Path):
        _write_rows(path, time, columns, digits, header)
        return Path("-")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="", encoding="utf-8") as handle:
        _write_rows(handle, time, columns, digits, header)
    return path


def _write_rows(handle: TextIO, time: np.ndarray, columns: Mapping[str, np.ndarray],
                digits: int, header: bool = True) -> None:
    names = [c for c in COLUMNS if c in columns]
    data = [np.asarray(columns[c], dtype=float) for c in names]
    out = csv.writer(handle, lineterminator="\n")
    if header:
        out.writerow(["time", *names])
    for i, stamp in enumerate(np.asarray(time, dtype="datetime64[s]")):
        out.writerow(
            [str(stamp) + "Z"]
            + [("" if not math.isfinite(v[i]) else f"{v[i]:.{digits}g}") for v in data]
        )
