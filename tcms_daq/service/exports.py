"""Sample exports of a stored run: canonical CSV, JSON, Parquet and ASAM MDF4 (DESIGN §7, §9).

Every format carries the canonical columns ``time_s, torque_nm, angle_arcsec`` (compensated angle) plus the raw
``encoder_arcsec`` when the run recorded it. Each exporter takes the run's samples as an iterable of column
chunks (``RunStore.iter_columns``) and yields the file's bytes piece by piece, so a long run is never held
whole as text: CSV and JSON stream chunk by chunk, Parquet writes one row group per chunk to a temporary file
that is then streamed. MDF4 is the exception: asammdf writes one channel group from whole arrays, so its
export holds the run's binary columns (8 bytes per sample and channel) once.
"""

from __future__ import annotations

import json
import tempfile
from collections.abc import Callable, Iterable, Iterator, Mapping
from enum import StrEnum
from pathlib import Path

import numpy as np

from tcms_daq.samples import CANONICAL_COLUMNS, csv_bytes

UNITS: dict[str, str] = {
    "time_s": "s",
    "torque_nm": "N·m",
    "angle_arcsec": "arcsec",
    "encoder_arcsec": "arcsec",
    "reference_arcsec": "arcsec",
    "temperature_c": "°C",
}
FILE_BLOCK_BYTES = 1 << 20

Chunks = Iterable[Mapping[str, np.ndarray]]


def ordered_names(channels: Iterable[str]) -> list[str]:
    """Canonical columns first, then the others in recorded order."""
    names = list(channels)
    return [c for c in CANONICAL_COLUMNS if c in names] + [c for c in names if c not in CANONICAL_COLUMNS]


def _ordered(columns: Mapping[str, np.ndarray], names: list[str]) -> dict[str, np.ndarray]:
    return {n: np.asarray(columns[n], dtype=float) for n in names}


def to_csv(chunks: Chunks, channels: list[str], run_id: str) -> Iterator[bytes]:
    """Canonical CSV (:func:`tcms_daq.samples.csv_bytes`), canonical columns first."""
    names = ordered_names(channels)
    yield (",".join(names) + "\n").encode()
    for chunk in chunks:
        yield csv_bytes(_ordered(chunk, names), header=False)


def to_json(chunks: Chunks, channels: list[str], run_id: str) -> Iterator[bytes]:
    """``{"id", "columns", "units", "data": {column: [values]}}``; a non-finite value is ``null`` (JSON has
    no NaN). The data are column-major, so ``chunks`` must be re-iterable (:class:`ChunkSource`): it is read
    once per column, one chunk held at a time."""
    names = ordered_names(channels)
    head = {"id": run_id, "columns": names, "units": {n: UNITS.get(n, "") for n in names}}
    yield json.dumps(head)[:-1].encode() + b', "data": {'
    for i, name in enumerate(names):
        yield (", " if i else "").encode() + json.dumps(name).encode() + b": ["
        first = True
        for chunk in chunks:
            values = np.asarray(chunk[name], dtype=float)
            if not len(values):
                continue
            listed: list[float | None] = values.tolist()
            if not np.isfinite(values).all():
                listed = [v if np.isfinite(v) else None for v in listed]  # type: ignore[arg-type]
            yield (b"" if first else b", ") + json.dumps(listed, allow_nan=False)[1:-1].encode()
            first = False
        yield b"]"
    yield b"}}"


def _stream_file(path: Path) -> Iterator[bytes]:
    with path.open("rb") as f:
        while block := f.read(FILE_BLOCK_BYTES):
            yield block


def to_parquet(chunks: Chunks, channels: list[str], run_id: str) -> Iterator[bytes]:
    import pyarrow as pa
    import pyarrow.parquet as pq

    names = ordered_names(channels)
    schema = pa.schema(
        [pa.field(n, pa.float64(), metadata={"unit": UNITS.get(n, "")}) for n in names],
        metadata={"run_id": run_id},
    )
    with tempfile.TemporaryDirectory(prefix="tcms-parquet-") as tmp:
        path = Path(tmp) / f"{run_id}.parquet"
        with pq.ParquetWriter(path, schema) as writer:
            for chunk in chunks:
                writer.write_table(pa.table({n: pa.array(v) for n, v in _ordered(chunk, names).items()},
                                            schema=schema))
        yield from _stream_file(path)


def to_mdf4(chunks: Chunks, channels: list[str], run_id: str) -> Iterator[bytes]:
    """ASAM MDF 4.10: one channel group, master channel ``time_s``, one float64 channel per column."""
    from asammdf import MDF, Signal

    names = ordered_names(channels)
    parts = [_ordered(c, names) for c in chunks]
    cols = {n: np.concatenate([p[n] for p in parts]) if parts else np.empty(0) for n in names}
    del parts
    time_s = cols.pop("time_s")
    mdf = MDF(version="4.10")
    signals = [
        Signal(samples=v, timestamps=time_s, name=n, unit=UNITS.get(n, ""), comment=f"TCMS run {run_id}")
        for n, v in cols.items()
    ]
    mdf.append(signals, comment=f"TCMS-DAQ run {run_id}")
    del signals, cols, time_s
    with tempfile.TemporaryDirectory(prefix="tcms-mdf-") as tmp:
        path = Path(tmp) / f"{run_id}.mf4"
        mdf.save(path, overwrite=True)
        mdf.close()
        yield from _stream_file(path)


class ChunkSource:
    """A re-iterable view of a stored run's chunks: every ``iter()`` reads the run again from the store."""

    def __init__(self, read: Callable[[], Iterator[Mapping[str, np.ndarray]]]):
        self._read = read

    def __iter__(self) -> Iterator[Mapping[str, np.ndarray]]:
        return self._read()


class ExportFormat(StrEnum):
    """The export formats of ``GET /api/tests/{id}/samples?format=``."""

    CSV = "csv"
    JSON = "json"
    PARQUET = "parquet"
    MDF4 = "mdf4"


Exporter = Callable[[Chunks, list[str], str], Iterator[bytes]]
# format -> (exporter, media type, file extension)
EXPORTERS: dict[ExportFormat, tuple[Exporter, str, str]] = {
    ExportFormat.CSV: (to_csv, "text/csv; charset=utf-8", "csv"),
    ExportFormat.JSON: (to_json, "application/json", "json"),
    ExportFormat.PARQUET: (to_parquet, "application/vnd.apache.parquet", "parquet"),
    ExportFormat.MDF4: (to_mdf4, "application/octet-stream", "mf4"),
}
