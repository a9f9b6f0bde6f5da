"""Sample exports of a stored run: canonical CSV, JSON, Parquet and ASAM MDF4 (DESIGN §7, §9).

Every format carries the canonical columns ``time_s, torque_nm, angle_arcsec`` (compensated angle) plus the raw
``encoder_arcsec`` when the run recorded it — and a turning test's two-axis record (docs/transmission.md, the results
contract: ``torque_nm`` the output torque, ``angle_arcsec`` the output angle, ``input_angle_arcsec``,
``input_torque_nm``), each channel with its unit and what it is (:func:`channel_description`) —, and the test's
identity (:class:`ExportMeta`: reducer, serial
number, bench, operator, parameters, compensation version, results ± U, verdict, start time): the MDF4 header
(author = operator, department = bench, project, subject = reducer and serial number, comment with every line of
the identity, the whole identity as common properties; start time = the test's start) and channel comments;
Parquet schema metadata; JSON's head. The canonical CSV stays plain numbers (every CSV reader of the project
reads it) and has its identity in a sidecar JSON (``GET /api/tests/{id}/metadata``, :func:`sidecar`).
``time_s`` is the bench clock everywhere; MDF4's master channel counts from the first sample (its header's start
time), and the others state ``time_s_at_start`` (the first sample's ``time_s``). Each exporter takes the run's samples as an iterable of column
chunks (``RunStore.iter_columns``) and yields the file's bytes piece by piece, so a long run is never held
whole as text: CSV and JSON stream chunk by chunk, Parquet writes one row group per chunk to a temporary file
that is then streamed. MDF4 is the exception: asammdf writes one channel group from whole arrays, so its
export holds the run's binary columns (8 bytes per sample and channel) once.
"""

from __future__ import annotations

import itertools
import json
import tempfile
from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import dataclass, field
from datetime import UTC, datetime
from enum import StrEnum
from pathlib import Path
from typing import Any
from xml.sax.saxutils import escape

import numpy as np

from tcms_daq.identity import TURNING_METHODS, identity_lines
from tcms_daq.samples import CANONICAL_COLUMNS, csv_bytes
from tcms_daq.store import StoredRun

UNITS: dict[str, str] = {
    "time_s": "s",
    "torque_nm": "N·m",
    "angle_arcsec": "arcsec",
    "encoder_arcsec": "arcsec",
    "reference_arcsec": "arcsec",
    "temperature_c": "°C",
    "input_angle_arcsec": "arcsec",
    "input_torque_nm": "N·m",
}
FILE_BLOCK_BYTES = 1 << 20

Chunks = Iterable[Mapping[str, np.ndarray]]
PROJECT = "TCMS-DAQ torsional characteristic test"
PROJECT_TURNING = "TCMS-DAQ reducer station test (GB/T 35089-2018 §7–8)"


@dataclass(frozen=True)
class ExportMeta:
    """What an export says about its run: its identity (:meth:`StoredRun.identity`), its full results and
    when the test started (UNIX s, UTC; the creation time for a run that never started)."""

    run_id: str
    identity: dict[str, Any] = field(default_factory=dict)
    results: dict[str, Any] | None = None
    start_unix_s: float | None = None

    @classmethod
    def of(cls, record: StoredRun) -> ExportMeta:
        return cls(record.id, record.identity(), record.results,
                   record.started_at if record.started_at is not None else record.created_at)

    @property
    def start_iso(self) -> str | None:
        return None if self.start_unix_s is None else datetime.fromtimestamp(self.start_unix_s, UTC).isoformat(
            timespec="milliseconds")

    @property
    def turning(self) -> bool:
        """A turning test's record (two axes), not a stiffness test's."""
        return (self.identity.get("method") or {}).get("kind") in TURNING_METHODS

    def document(self, time_s_at_start: float | None, channels: Iterable[str] = ()) -> dict[str, Any]:
        """The JSON metadata (Parquet's, the sidecar's): identity, units, start, full results, and what each of
        ``channels`` is."""
        return {"run_id": self.run_id, "start_time": self.start_iso, "time_s_at_start": time_s_at_start,
                "time_note": "time_s is the bench clock; the test started at start_time, when time_s was "
                             "time_s_at_start (the first sample)",
                "identity": self.identity, "results": self.results, "units": UNITS,
                "channels": {n: {"unit": UNITS.get(n, ""), "description": channel_description(n, self.turning)}
                             for n in ordered_names(channels)}}

    def lines(self) -> list[str]:
        return identity_lines(self.identity) if self.identity else [f"run {self.run_id}"]


def _peek(chunks: Chunks) -> tuple[float | None, Iterator[Mapping[str, np.ndarray]]]:
    """The first sample's time_s and the chunks, none lost."""
    it = iter(chunks)
    for chunk in it:
        t = np.asarray(chunk.get("time_s", ()), dtype=float)
        if len(t):
            return float(t[0]), itertools.chain([chunk], it)
    return None, iter(())


def sidecar(meta: ExportMeta, chunks: Chunks, channels: Iterable[str] = ()) -> dict[str, Any]:
    """The CSV's sidecar JSON (``tcms-<id>.json``): :meth:`ExportMeta.document` with the CSV's columns."""
    first, _ = _peek(chunks)
    return meta.document(first, channels)


def ordered_names(channels: Iterable[str]) -> list[str]:
    """Canonical columns first, then the others in recorded order."""
    names = list(channels)
    return [c for c in CANONICAL_COLUMNS if c in names] + [c for c in names if c not in CANONICAL_COLUMNS]


def _ordered(columns: Mapping[str, np.ndarray], names: list[str]) -> dict[str, np.ndarray]:
    return {n: np.asarray(columns[n], dtype=float) for n in names}


def to_csv(chunks: Chunks, channels: list[str], meta: ExportMeta) -> Iterator[bytes]:
    """Canonical CSV (:func:`tcms_daq.samples.csv_bytes`), canonical columns first; the identity is in the
    sidecar (:func:`sidecar`)."""
    names = ordered_names(channels)
    yield (",".join(names) + "\n").encode()
    for chunk in chunks:
        yield csv_bytes(_ordered(chunk, names), header=False)


def to_json(chunks: Chunks, channels: list[str], meta: ExportMeta) -> Iterator[bytes]:
    """``{"id", "columns", "units", "metadata", "data": {column: [values]}}``; a non-finite value is ``null``
    (JSON has no NaN). The data are column-major, so ``chunks`` must be re-iterable (:class:`ChunkSource`): it
    is read once per column, one chunk held at a time."""
    names = ordered_names(channels)
    first, _ = _peek(chunks)
    head = {"id": meta.run_id, "columns": names, "units": {n: UNITS.get(n, "") for n in names},
            "metadata": meta.document(first, names)}
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


#: the identity's scalars that Parquet's schema metadata and MDF4's common properties carry as keys of their own
IDENTITY_KEYS = ("reducer", "serial_number", "customer", "order_number", "operator", "user", "plan", "bench_id",
                 "bench_name", "status", "verdict", "compensation_version", "compensation_sha256",
                 "bench_model_version")


def parquet_metadata(meta: ExportMeta, time_s_at_start: float | None, channels: Iterable[str] = ()
                     ) -> dict[str, str]:
    """Parquet schema metadata: ``tcms`` (the whole document as JSON) and the identity's scalars as keys."""
    ident = meta.identity
    flat = {"run_id": meta.run_id, "start_time": meta.start_iso or "",
            "time_s_at_start": "" if time_s_at_start is None else repr(time_s_at_start)}
    for key in IDENTITY_KEYS:
        value = ident.get(key)
        flat[key] = "" if value is None else str(value)
    flat["method"] = str((ident.get("method") or {}).get("series") or "")
    flat["parameters"] = json.dumps(ident.get("parameters") or {})
    flat["results"] = json.dumps(ident.get("results") or {})
    flat["tcms"] = json.dumps(meta.document(time_s_at_start, channels), allow_nan=False, default=str)
    return flat


def to_parquet(chunks: Chunks, channels: list[str], meta: ExportMeta) -> Iterator[bytes]:
    import pyarrow as pa
    import pyarrow.parquet as pq

    names = ordered_names(channels)
    first, pieces = _peek(chunks)
    schema = pa.schema(
        [pa.field(n, pa.float64(), metadata={"unit": UNITS.get(n, ""),
                                             "description": channel_description(n, meta.turning)}) for n in names],
        metadata=parquet_metadata(meta, first, names),
    )
    with tempfile.TemporaryDirectory(prefix="tcms-parquet-") as tmp:
        path = Path(tmp) / f"{meta.run_id}.parquet"
        with pq.ParquetWriter(path, schema) as writer:
            for chunk in pieces:
                writer.write_table(pa.table({n: pa.array(v) for n, v in _ordered(chunk, names).items()},
                                            schema=schema))
        yield from _stream_file(path)


CHANNEL_DESCRIPTIONS = {
    "time_s": "bench clock",
    "torque_nm": "measured torque",
    "angle_arcsec": "compensated twist angle",
    "encoder_arcsec": "raw encoder angle (before compensation)",
    "reference_arcsec": "reference angle (autocollimator)",
    "temperature_c": "temperature",
}
#: … of a turning test's two-axis record (one row per latched angle pair)
TURNING_CHANNEL_DESCRIPTIONS = {
    **CHANNEL_DESCRIPTIONS,
    "time_s": "bench clock (one row per latched pair of the input and output angles)",
    "torque_nm": "output torque (the loader's; a braking load on a forward rotation reads negative)",
    "angle_arcsec": "output angle, compensated",
    "encoder_arcsec": "output encoder angle, raw (before compensation)",
    "input_angle_arcsec": "input angle (input encoder, arcsec of the input shaft)",
    "input_torque_nm": "input torque (turning the input forward is positive)",
}


def channel_description(name: str, turning: bool = False) -> str:
    """What a recorded channel is (a turning test's record: its two axes)."""
    return (TURNING_CHANNEL_DESCRIPTIONS if turning else CHANNEL_DESCRIPTIONS).get(name, name)


def mdf_header_comment(meta: ExportMeta, time_s_at_start: float | None) -> str:
    """The MDF4 HDcomment XML: the identity's lines as text, author/department/project/subject and the whole
    identity as common properties (ASAM MDF 4 common_properties; a ``tree`` named ``tcms``)."""
    ident = meta.identity

    def element(name: str, value: Any) -> str:
        return f'<e name="{escape(name)}">{escape("" if value is None else str(value))}</e>'

    subject = f"{ident.get('reducer') or 'reducer'} serial number {ident.get('serial_number') or '—'}"
    common = [element("author", ident.get("operator") or ""), element("department", ident.get("bench_name") or ""),
              element("project", PROJECT_TURNING if meta.turning else PROJECT), element("subject", subject)]
    tree = {k: v for k, v in parquet_metadata(meta, time_s_at_start).items() if k != "tcms"}
    common.append('<tree name="tcms">' + "".join(element(k, v) for k, v in tree.items()) + "</tree>")
    text = "\n".join(meta.lines())
    return f"<HDcomment><TX>{escape(text)}</TX><common_properties>{''.join(common)}</common_properties></HDcomment>"


def to_mdf4(chunks: Chunks, channels: list[str], meta: ExportMeta) -> Iterator[bytes]:
    """ASAM MDF 4.10: one channel group, master channel ``time_s`` from the first sample (the header's start time
    is the test's start), one float64 channel per column with the test's identity in its comment."""
    from asammdf import MDF, Signal

    names = ordered_names(channels)
    parts = [_ordered(c, names) for c in chunks]
    cols = {n: np.concatenate([p[n] for p in parts]) if parts else np.empty(0) for n in names}
    del parts
    time_s = cols.pop("time_s")
    first = float(time_s[0]) if len(time_s) else None
    if first is not None:
        time_s = time_s - first
    mdf = MDF(version="4.10")
    mdf.header.comment = mdf_header_comment(meta, first)
    if meta.start_unix_s is not None:
        mdf.header.start_time = datetime.fromtimestamp(meta.start_unix_s, UTC)
    summary = "; ".join(meta.lines())
    signals = [
        Signal(samples=v, timestamps=time_s, name=n, unit=UNITS.get(n, ""),
               comment=f"{channel_description(n, meta.turning)} — {summary}")
        for n, v in cols.items()
    ]
    mdf.append(signals, comment=f"TCMS-DAQ run {meta.run_id}: time from the first sample (bench clock time_s "
                                f"{first if first is not None else 0.0:.6f} s)")
    del signals, cols, time_s
    with tempfile.TemporaryDirectory(prefix="tcms-mdf-") as tmp:
        path = Path(tmp) / f"{meta.run_id}.mf4"
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


Exporter = Callable[[Chunks, list[str], ExportMeta], Iterator[bytes]]
# format -> (exporter, media type, file extension)
EXPORTERS: dict[ExportFormat, tuple[Exporter, str, str]] = {
    ExportFormat.CSV: (to_csv, "text/csv; charset=utf-8", "csv"),
    ExportFormat.JSON: (to_json, "application/json", "json"),
    ExportFormat.PARQUET: (to_parquet, "application/vnd.apache.parquet", "parquet"),
    ExportFormat.MDF4: (to_mdf4, "application/octet-stream", "mf4"),
}
