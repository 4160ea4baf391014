"""Reading the tables of a recorded dataset (docs/replay.md): CSV, or Parquet where pyarrow is installed.

Each table has a fixed set of columns (SCHEMAS): required ones must be present with a value in
every row, optional ones may be missing from the header or empty in a row (read as NaN). Every
number must parse, be finite and at most MAX_MAGNITUDE in size; an unknown column is a mistake. A mistake is one ConfigError
(exit 2) naming the file, the row (1 = first data row, and its line in a CSV file) and the column.
"""
from __future__ import annotations

import csv
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from testbed.errors import ConfigError

#: the value columns of a camera row: the focal-plane coordinates of the seen point (units of the
#: focal length) and its unit line of sight in the camera frame (testbed.sensors.camera)
CAMERA_COLUMNS = ("alpha", "beta", "bx", "by", "bz")
#: the phase table's columns of the src antenna's position (m) and velocity (m/s), world, from its
#: master's own navigation solution (testbed.sensors.phase: phase/master_pos, phase/master_vel)
PHASE_MASTER_COLUMNS = ("master_x", "master_y", "master_z", "master_vx", "master_vy", "master_vz")
#: (column, is a number, required) per table
SCHEMAS: dict[str, tuple[tuple[str, bool, bool], ...]] = {
    "links": (("time", True, True), ("src", False, True), ("dst", False, True), ("kind", False, True),
              ("value", True, True), ("sigma", True, False), ("arrival", True, False), ("nlos", True, False)),
    "poses": (("time", True, True), ("body", False, True), ("kind", False, True),
              *((c, True, True) for c in ("x", "y", "z")), *((c, True, False) for c in ("qw", "qx", "qy", "qz")),
              *((c, True, False) for c in ("sigma_x", "sigma_y", "sigma_z")), ("arrival", True, False)),
    "imu": (("time", True, True), ("site", False, True), *((c, True, True) for c in ("ax", "ay", "az", "gx", "gy", "gz")),
            ("sigma_accel", True, False), ("sigma_gyro", True, False), ("arrival", True, False)),
    "height": (("time", True, True), ("site", False, True), ("value", True, True), ("sigma", True, False),
               ("arrival", True, False)),
    "phase": (("time", True, True), ("src", False, True), ("dst", False, True), ("phase", True, True),
              ("range", True, True), ("rate", True, False), *((c, True, True) for c in PHASE_MASTER_COLUMNS),
              ("rate_periods", True, True), ("wavelength", True, True), ("slip", True, True),
              *((f"sigma_{c}", True, False) for c in ("phase", "range", "rate")), ("arrival", True, False)),
    "camera": (("time", True, True), ("src", False, True), ("dst", False, True),
               *((c, True, True) for c in CAMERA_COLUMNS), ("arrival", True, False)),
    "truth": (("time", True, True), ("body", False, True), *((c, True, True) for c in ("x", "y", "z", "qw", "qx", "qy", "qz")),
              *((c, True, False) for c in ("vx", "vy", "vz", "wx", "wy", "wz"))),
}
REQUIRED_TABLES = ("links",)
#: the calibration table (testbed.replay.calibration): not a stream, no time column; read by
#: read_table(path, "calibration", CALIBRATION_SCHEMA)
CALIBRATION_SCHEMA = (("src", False, True), ("dst", False, False), ("bias", True, False), ("scale", True, False),
                      ("sigma_bias", True, False), ("sigma_scale", True, False), ("time_offset", True, False),
                      ("sigma_time_offset", True, False), ("scale_from", True, False), ("scale_to", True, False))
#: the largest magnitude of any number in a table (s, m, m/s, ...): Unix times until the year 2286,
#: any coordinate on Earth; squares and sums of squares of such numbers stay far from overflow
MAX_MAGNITUDE = 1e10


@dataclass(frozen=True, slots=True)
class Table:
    """One table: file (as named in messages), columns {name: (n,) float (NaN: empty) or str},
    lines (n,) the line of each row in a CSV file (None for Parquet)."""

    file: str
    columns: dict[str, np.ndarray]
    lines: np.ndarray | None

    def __len__(self) -> int:
        return int(self.columns["time"].size)

    def __getitem__(self, name: str) -> np.ndarray:
        return self.columns[name]

    def has(self, name: str) -> bool:
        """Is the optional column present with a value in every row?"""
        col = self.columns[name]
        return col.size > 0 and bool(np.all(np.isfinite(col)))

    def where(self, row: int) -> str:
        line = f" (line {int(self.lines[row])})" if self.lines is not None else ""
        return f"{self.file}: row {row + 1}{line}"

    def error(self, row: int, column: str, reason: str) -> ConfigError:
        """The one-line error of a bad cell: file, row, column, reason."""
        return ConfigError(f"{self.where(row)}, column {column}: {reason}")

    def select(self, keep: np.ndarray) -> "Table":
        """The rows where keep (n,) bool, in order."""
        return Table(self.file, {k: v[keep] for k, v in self.columns.items()},
                     None if self.lines is None else self.lines[keep])


def find(directory: Path, name: str) -> Path | None:
    """NAME.csv or NAME.parquet in directory (ConfigError if both), None if neither."""
    found = [directory / f"{name}.{ext}" for ext in ("csv", "parquet") if (directory / f"{name}.{ext}").is_file()]
    if len(found) > 1:
        raise ConfigError(f"{directory}: both {name}.csv and {name}.parquet; keep one")
    return found[0] if found else None


def _rows(reader) -> Iterator[tuple[list[str], int]]:
    """(cells, line) of each data row of a CSV reader past its header; blank lines skipped."""
    for cells in reader:  # cells are stripped per column by the caller
        if not cells or (len(cells) == 1 and not cells[0].strip()):
            continue
        yield cells, reader.line_num


def _oversized(path: Path, header: list[str]) -> str:
    """Where the first cell longer than csv's field limit is ("row R (line L), column C"): the file
    read again with the limit lifted for the search only."""
    limit = csv.field_size_limit()
    csv.field_size_limit(sys.maxsize)
    try:
        with open(path, newline="", encoding="utf-8") as fh:
            reader = csv.reader(fh)
            next(reader)
            for r, (cells, line) in enumerate(_rows(reader), start=1):
                for j, cell in enumerate(cells):
                    if len(cell) > limit:
                        name = header[j] if j < len(header) else f"{j + 1} (beyond the header)"
                        return f"row {r} (line {line}), column {name}: a cell of {len(cell)} characters"
    finally:
        csv.field_size_limit(limit)
    return "the header"


def _read_csv(path: Path) -> tuple[list[str], list[list[str]], list[int]]:
    header: list[str] = []
    try:
        with open(path, newline="", encoding="utf-8") as fh:
            reader = csv.reader(fh)
            header = next(reader, None)
            if header is None:
                raise ConfigError(f"{path}: empty file (expected a header row)")
            header = [h.strip() for h in header]
            rows, lines = [], []
            n = len(header)
            for cells, line in _rows(reader):
                if len(cells) != n:
                    raise ConfigError(f"{path}: row {len(rows) + 1} (line {line}): {len(cells)} cells, the header has {n}")
                rows.append(cells)
                lines.append(line)
    except UnicodeDecodeError:
        raise ConfigError(f"{path}: not a UTF-8 text file") from None
    except csv.Error as e:
        if "field limit" in str(e):
            raise ConfigError(f"{path}: {_oversized(path, header)}, over the CSV field limit of "
                              f"{csv.field_size_limit()} characters") from None
        raise ConfigError(f"{path}: not valid CSV: {e}") from None
    return header, rows, lines


def _read_parquet(path: Path) -> tuple[list[str], dict[str, list]]:
    try:
        import pyarrow.parquet as pq  # lazy: an optional dependency, only for Parquet files
    except ImportError:
        raise ConfigError(f"{path}: reading Parquet needs pyarrow (pip install pyarrow); or write the table as CSV") from None
    try:
        data = pq.read_table(path).to_pydict()
    except Exception as e:  # pyarrow's own errors have no common base class
        raise ConfigError(f"{path}: not a readable Parquet file: {type(e).__name__}: {e}".splitlines()[0]) from None
    return list(data), data


def _numbers(table: str, file: str, name: str, raw: np.ndarray, required: bool, lines) -> np.ndarray:
    """Cells (str) to float; empty -> NaN (optional only); anything unparsable or non-finite refused."""
    where = lambda i: f"{file}: row {i + 1}" + (f" (line {lines[i]})" if lines is not None else "")  # noqa: E731
    empty = raw == ""
    if required and empty.any():
        i = int(np.argmax(empty))
        raise ConfigError(f"{where(i)}, column {name}: empty, but {table} needs a value here")
    try:
        out = np.where(empty, "nan", raw).astype(float)
    except ValueError:
        for i, cell in enumerate(raw):
            try:
                float(cell or "nan")
            except ValueError:
                raise ConfigError(f"{where(i)}, column {name}: expected a number, got {str(cell)!r}") from None
        raise
    bad = ~np.isfinite(out) & ~empty
    if bad.any():
        i = int(np.argmax(bad))
        raise ConfigError(f"{where(i)}, column {name}: must be a finite number, got {str(raw[i])!r}")
    huge = np.abs(out) > MAX_MAGNITUDE
    if huge.any():
        i = int(np.argmax(huge))
        raise ConfigError(f"{where(i)}, column {name}: must be at most {MAX_MAGNITUDE:g} in magnitude, got {str(raw[i])!r}")
    return out


def read_table(path: Path, table: str, schema: tuple | None = None) -> Table:
    """Read and type one table of SCHEMAS[table] (or of `schema`) from a CSV or Parquet file;
    ConfigError on a mistake."""
    path = Path(path)
    schema = SCHEMAS[table] if schema is None else schema
    known = [c for c, _, _ in schema]
    if path.suffix == ".parquet":
        header, data = _read_parquet(path)
        lines = None
        n = len(data[header[0]]) if header else 0
        cells = {h: np.array(["" if v is None else (repr(float(v)) if isinstance(v, (int, float)) and not isinstance(v, bool)
                                                    else str(v)) for v in data[h]], dtype=str).reshape(n) for h in header}
    else:
        header, rows, lines = _read_csv(path)
        n = len(rows)
        columns = list(zip(*rows)) if rows else [()] * len(header)
        cells = {h: np.char.strip(np.array(columns[j], dtype=str).reshape(n)) for j, h in enumerate(header)}
    for h in header:
        if h not in known:
            raise ConfigError(f"{path}: unknown column {h!r} (the {table} table has: {', '.join(known)})")
    twice = [h for j, h in enumerate(header) if h in header[:j]]
    if twice:
        raise ConfigError(f"{path}: the header names column {twice[0]!r} twice")
    missing = [c for c, _, req in schema if req and c not in cells]
    if missing:
        raise ConfigError(f"{path}: missing column{'s' if len(missing) > 1 else ''} {', '.join(missing)} "
                          f"(the {table} table needs {', '.join(c for c, _, r in schema if r)})")
    out = {}
    for c, numeric, required in schema:
        raw = cells.get(c, np.full(n, "", dtype=str))
        if numeric:
            out[c] = _numbers(table, str(path), c, raw, required, lines)
        else:
            if required and (raw == "").any():
                i = int(np.argmax(raw == ""))
                where = f"{path}: row {i + 1}" + (f" (line {lines[i]})" if lines is not None else "")
                raise ConfigError(f"{where}, column {c}: empty, but {table} needs a value here")
            out[c] = raw
    return Table(str(path), out, None if lines is None else np.array(lines, np.int64))
