"""Sample exports of a stored run: canonical CSV, JSON, Parquet and ASAM MDF4 (DESIGN §7, §9).

Every format carries the canonical columns ``time_s, torque_nm, angle_arcsec`` (compensated angle) plus the raw
``encoder_arcsec`` when the run recorded it. Each exporter returns the file's bytes.
"""

from __future__ import annotations

import io
import json
import tempfile
from collections.abc import Callable, Mapping
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


def _ordered(columns: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
    names = [c for c in CANONICAL_COLUMNS if c in columns] + [c for c in columns if c not in CANONICAL_COLUMNS]
    return {n: np.asarray(columns[n], dtype=float) for n in names}


def to_csv(columns: Mapping[str, np.ndarray], run_id: str) -> bytes:
    """Canonical CSV (:func:`tcms_daq.samples.csv_bytes`), canonical columns first."""
    return csv_bytes(_ordered(columns))


def to_json(columns: Mapping[str, np.ndarray], run_id: str) -> bytes:
    cols = _ordered(columns)
    body = {
        "id": run_id,
        "columns": list(cols),
        "units": {n: UNITS.get(n, "") for n in cols},
        "data": {n: v.tolist() for n, v in cols.items()},
    }
    return json.dumps(body, allow_nan=False).encode()


def to_parquet(columns: Mapping[str, np.ndarray], run_id: str) -> bytes:
    import pyarrow as pa
    import pyarrow.parquet as pq

    cols = _ordered(columns)
    schema = pa.schema(
        [pa.field(n, pa.float64(), metadata={"unit": UNITS.get(n, "")}) for n in cols],
        metadata={"run_id": run_id},
    )
    table = pa.table({n: pa.array(v) for n, v in cols.items()}, schema=schema)
    buf = io.BytesIO()
    pq.write_table(table, buf)
    return buf.getvalue()


def to_mdf4(columns: Mapping[str, np.ndarray], run_id: str) -> bytes:
    """ASAM MDF 4.10: one channel group, master channel ``time_s``, one float64 channel per column."""
    from asammdf import MDF, Signal

    cols = _ordered(columns)
    time_s = cols.pop("time_s")
    mdf = MDF(version="4.10")
    signals = [
        Signal(samples=v, timestamps=time_s, name=n, unit=UNITS.get(n, ""), comment=f"TCMS run {run_id}")
        for n, v in cols.items()
    ]
    mdf.append(signals, comment=f"TCMS-DAQ run {run_id}")
    with tempfile.TemporaryDirectory(prefix="tcms-mdf-") as tmp:
        path = Path(tmp) / f"{run_id}.mf4"
        mdf.save(path, overwrite=True)
        mdf.close()
        return path.read_bytes()


EXPORTERS: dict[str, tuple[Callable[[Mapping[str, np.ndarray], str], bytes], str, str]] = {
    "csv": (to_csv, "text/csv; charset=utf-8", "csv"),
    "json": (to_json, "application/json", "json"),
    "parquet": (to_parquet, "application/vnd.apache.parquet", "parquet"),
    "mdf4": (to_mdf4, "application/octet-stream", "mf4"),
}
