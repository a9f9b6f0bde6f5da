"""Exports stream a stored run chunk by chunk (issue 10 item 6) and read back to the stored samples."""

from __future__ import annotations

import io
import json

import numpy as np
import pyarrow.csv as pa_csv
import pyarrow.parquet as pq
import pytest

from tcms_daq.service import exports
from tcms_daq.store import RunStore

CHANNELS = ("time_s", "torque_nm", "angle_arcsec", "encoder_arcsec")


@pytest.fixture
def stored(tmp_path):
    """A run of 5 000 samples in 50 stored batches, with a NaN angle where a reading was lost."""
    rng = np.random.default_rng(3)
    t = np.arange(5000) / 500.0
    torque = 100.0 * np.sin(t)
    angle = torque / 5.0 + rng.normal(0.0, 0.2, t.size)
    angle[1234] = np.nan
    cols = {"time_s": t, "torque_nm": torque, "angle_arcsec": angle, "encoder_arcsec": angle * 1.0001}
    store = RunStore(tmp_path / "runs.sqlite3")
    store.create_run("r1", {"reducer": "RV-110E"}, CHANNELS)
    store.append_samples("r1", [{k: v[i:i + 100] for k, v in cols.items()} for i in range(0, t.size, 100)])
    yield store, cols
    store.close()


def _body(fmt: exports.ExportFormat, store: RunStore, chunk_samples: int) -> tuple[bytes, int]:
    exporter = exports.EXPORTERS[fmt][0]
    source = exports.ChunkSource(lambda: store.iter_columns("r1", chunk_samples=chunk_samples))
    pieces = list(exporter(source, list(CHANNELS), exports.ExportMeta("r1")))
    return b"".join(pieces), len(pieces)


def test_store_chunks_cover_the_run_in_order(stored):
    store, cols = stored
    chunks = list(store.iter_columns("r1", chunk_samples=700))
    assert len(chunks) == 8  # 7 batches of 100 per chunk: 7 full chunks and the rest
    np.testing.assert_array_equal(np.concatenate([c["time_s"] for c in chunks]), cols["time_s"])
    np.testing.assert_array_equal(store.read_columns("r1")["angle_arcsec"], cols["angle_arcsec"])


def test_csv_streams_in_pieces_and_reads_back_exactly(stored):
    store, cols = stored
    body, pieces = _body(exports.ExportFormat.CSV, store, 700)
    assert pieces == 9  # the header, then one piece per chunk
    assert body.startswith(b"time_s,torque_nm,angle_arcsec,encoder_arcsec\n")
    table = pa_csv.read_csv(io.BytesIO(body))  # the project's reader refuses the NaN, on purpose
    np.testing.assert_array_equal(table.column("torque_nm").to_numpy(), cols["torque_nm"])
    np.testing.assert_array_equal(table.column("angle_arcsec").to_numpy(), cols["angle_arcsec"])


def test_json_streams_and_writes_null_for_a_lost_reading(stored):
    store, cols = stored
    body, pieces = _body(exports.ExportFormat.JSON, store, 700)
    assert pieces > 8
    doc = json.loads(body)
    assert doc["columns"] == list(CHANNELS) and doc["units"]["torque_nm"] == "N·m"
    assert doc["data"]["angle_arcsec"][1234] is None
    assert len(doc["data"]["time_s"]) == 5000
    np.testing.assert_array_equal(doc["data"]["torque_nm"], cols["torque_nm"])


def test_parquet_has_a_row_group_per_chunk(stored):
    store, cols = stored
    body, _ = _body(exports.ExportFormat.PARQUET, store, 700)
    pf = pq.ParquetFile(io.BytesIO(body))
    assert pf.metadata.num_row_groups == 8
    np.testing.assert_array_equal(pf.read().column("time_s").to_numpy(), cols["time_s"])
