"""Canonical sample arrays and the canonical CSV format (DESIGN §9).

Columns: ``time_s, torque_nm, angle_arcsec``; optional ``encoder_arcsec`` (raw encoder, before compensation),
``reference_arcsec`` (autocollimator), ``temperature_c``, ``run_id``. Extra columns are kept in ``extra`` and
otherwise ignored. ``angle_arcsec`` is the (compensated) output twist angle, positive in the direction of
positive torque.
"""

from __future__ import annotations

import csv
import io
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from tcms_daq.errors import DataFormatError

CANONICAL_COLUMNS: tuple[str, ...] = ("time_s", "torque_nm", "angle_arcsec")
#: the turning tests' columns beside the canonical ones (docs/transmission.md, the results contract): the input
#: angle (arcsec of the input shaft) an angle pair source latches with the output angle, and the input torque (N·m)
INPUT_ANGLE_COLUMN = "input_angle_arcsec"
INPUT_TORQUE_COLUMN = "input_torque_nm"
OPTIONAL_COLUMNS: tuple[str, ...] = ("encoder_arcsec", "reference_arcsec", "temperature_c", "run_id")


@dataclass
class Samples:
    """A run (or a batch) of time-stamped samples as column arrays of equal length.

    time_s: monotonic time stamp in s; torque_nm: measured torque in N·m; angle_arcsec: twist angle in arcsec.
    ``extra`` holds optional columns by their canonical name (same length).
    """

    time_s: np.ndarray
    torque_nm: np.ndarray
    angle_arcsec: np.ndarray
    extra: dict[str, np.ndarray] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.time_s = np.asarray(self.time_s, dtype=float)
        self.torque_nm = np.asarray(self.torque_nm, dtype=float)
        self.angle_arcsec = np.asarray(self.angle_arcsec, dtype=float)
        n = len(self.time_s)
        if len(self.torque_nm) != n or len(self.angle_arcsec) != n:
            raise DataFormatError(
                f"column lengths differ: time_s {n}, torque_nm {len(self.torque_nm)}, "
                f"angle_arcsec {len(self.angle_arcsec)}"
            )
        for name, col in list(self.extra.items()):
            col = np.asarray(col, dtype=float)
            if len(col) != n:
                raise DataFormatError(f"column {name!r} has {len(col)} values, expected {n}")
            self.extra[name] = col

    def __len__(self) -> int:
        return len(self.time_s)

    def columns(self) -> dict[str, np.ndarray]:
        """All columns, canonical first, by name."""
        return {"time_s": self.time_s, "torque_nm": self.torque_nm, "angle_arcsec": self.angle_arcsec, **self.extra}

    def select(self, mask_or_slice: slice | np.ndarray) -> Samples:
        return Samples(
            self.time_s[mask_or_slice],
            self.torque_nm[mask_or_slice],
            self.angle_arcsec[mask_or_slice],
            {k: v[mask_or_slice] for k, v in self.extra.items()},
        )

    @staticmethod
    def concat(parts: Iterable[Samples]) -> Samples:
        parts = [p for p in parts]
        if not parts:
            return Samples(np.empty(0), np.empty(0), np.empty(0))
        keys = set(parts[0].extra)
        for p in parts[1:]:
            keys &= set(p.extra)
        return Samples(
            np.concatenate([p.time_s for p in parts]),
            np.concatenate([p.torque_nm for p in parts]),
            np.concatenate([p.angle_arcsec for p in parts]),
            {k: np.concatenate([p.extra[k] for p in parts]) for k in sorted(keys)},
        )


def _parse_column(name: str, raw: list[str], first_data_line: int) -> np.ndarray:
    try:
        return np.array(raw, dtype=float)
    except ValueError:
        for i, text in enumerate(raw):
            try:
                float(text)
            except ValueError:
                raise DataFormatError(
                    f"non-numeric value {text!r} in column {name!r} at line {first_data_line + i}"
                ) from None
        raise


def parse_csv_text(text: str, required: Iterable[str] = CANONICAL_COLUMNS, source: str = "<csv>") -> dict[str, np.ndarray]:
    """Parse CSV text with a header row into float columns; every column in ``required`` must be present.

    Raises DataFormatError (one line, naming ``source``) for a missing header/column, a short row, or a
    non-numeric or non-finite value.
    """
    required = tuple(required)
    reader = csv.reader(io.StringIO(text))
    rows = [row for row in reader if row and any(cell.strip() for cell in row)]
    if not rows:
        raise DataFormatError(f"{source}: empty file (expected a header row with {', '.join(required)})")
    header = [h.strip() for h in rows[0]]
    missing = [c for c in required if c not in header]
    if missing:
        raise DataFormatError(f"{source}: missing column {missing[0]!r} (header has: {', '.join(header)})")
    body = rows[1:]
    for i, row in enumerate(body):
        if len(row) < len(header):
            raise DataFormatError(f"{source}: line {i + 2} has {len(row)} fields, header has {len(header)}")
    out: dict[str, np.ndarray] = {}
    for j, name in enumerate(header):
        if not name or name in out:
            continue
        raw = [row[j].strip() for row in body]
        if name in required or name in CANONICAL_COLUMNS or name in OPTIONAL_COLUMNS:
            col = _parse_column(name, raw, 2)
            bad = np.flatnonzero(~np.isfinite(col))
            if bad.size:
                raise DataFormatError(f"{source}: non-finite value in column {name!r} at line {bad[0] + 2}")
            out[name] = col
        else:
            try:
                out[name] = np.array(raw, dtype=float)
            except ValueError:
                continue  # extra non-numeric columns are ignored
    return out


def read_csv_columns(path: str | Path, required: Iterable[str] = CANONICAL_COLUMNS) -> dict[str, np.ndarray]:
    """Read a CSV file into float columns (see ``parse_csv_text``); DataFormatError (one line, naming the file)
    for a missing or unreadable file, a missing column or a bad value."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise DataFormatError(f"{path}: no such file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise DataFormatError(f"{path}: cannot read ({exc})") from None
    fast = _arrow_columns(text, tuple(required))
    return fast if fast is not None else parse_csv_text(text, required=required, source=str(path))


def _arrow_columns(text: str, required: tuple[str, ...]) -> dict[str, np.ndarray] | None:
    """The columns of a well-formed numeric CSV by Arrow's C++ reader (a million rows in a fraction of a second);
    None for anything else (a missing column, a short row, a non-numeric or non-finite value, a repeated or
    empty header name), which ``parse_csv_text`` then reads and reports with its one-line messages."""
    if len(text) < 1_000_000:  # small files: the Python reader is fast enough and the one that explains errors
        return None
    try:
        import pyarrow as pa
        import pyarrow.csv as pa_csv

        table = pa_csv.read_csv(pa.py_buffer(text.encode()))
    except Exception:  # noqa: BLE001 - any problem: the Python reader says what it is
        return None
    names = [n.strip() for n in table.column_names]
    if len(set(names)) != len(names) or "" in names or any(c not in names for c in required):
        return None
    out: dict[str, np.ndarray] = {}
    for name, column in zip(names, table.columns, strict=True):
        if not pa.types.is_floating(column.type) and not pa.types.is_integer(column.type):
            if name in required or name in CANONICAL_COLUMNS or name in OPTIONAL_COLUMNS:
                return None
            continue  # extra non-numeric columns are ignored
        values = column.to_numpy(zero_copy_only=False).astype(float)
        if not np.all(np.isfinite(values)):
            return None
        out[name] = values
    return out


def read_csv(path: str | Path, required: Iterable[str] = CANONICAL_COLUMNS) -> Samples:
    """Read a canonical sample CSV. Raises DataFormatError with a one-line message naming the problem."""
    return samples_from_columns(read_csv_columns(path, required))


def samples_from_columns(cols: Mapping[str, np.ndarray]) -> Samples:
    extra = {k: v for k, v in cols.items() if k not in CANONICAL_COLUMNS}
    n = len(next(iter(cols.values()))) if cols else 0
    zeros = np.zeros(n)
    return Samples(cols.get("time_s", zeros), cols.get("torque_nm", zeros), cols.get("angle_arcsec", zeros), extra)


def csv_bytes(columns: Mapping[str, np.ndarray], header: bool = True) -> bytes:
    """Canonical CSV of equally long float columns, in the given order: a header row (unless ``header`` is
    False: a later chunk of a streamed file), then the shortest text that reads back to the same float
    (``nan``, ``inf``), so a round trip is exact. The one CSV writer of the project (files, exports); Arrow's
    C++ writer, not a Python loop per row."""
    import pyarrow as pa
    import pyarrow.csv as pa_csv

    cols = {name: np.asarray(values, dtype=float) for name, values in columns.items()}
    buf = io.BytesIO()
    if header:
        buf.write((",".join(cols) + "\n").encode())
    if cols and len(next(iter(cols.values()))):
        pa_csv.write_csv(pa.table(cols), buf, pa_csv.WriteOptions(include_header=False, quoting_style="none"))
    return buf.getvalue()


def to_csv_text(samples: Samples, columns: Iterable[str] | None = None) -> str:
    """Canonical CSV text of ``samples`` (all columns, or the named ones in that order); see :func:`csv_bytes`."""
    cols = samples.columns()
    names = list(columns) if columns is not None else list(cols)
    return csv_bytes({n: cols[n] for n in names}).decode("ascii")


def write_csv(path: str | Path, samples: Samples, columns: Iterable[str] | None = None) -> None:
    Path(path).write_text(to_csv_text(samples, columns), encoding="utf-8")
