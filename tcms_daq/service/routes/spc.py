"""SPC of a fleet's results: I-MR control charts per reducer model (and bench), bench-to-bench bias from
reference units tested on several benches (:mod:`tcms_daq.spc`; the runs from the shared store)."""

from __future__ import annotations

from datetime import datetime
from typing import Annotated, Any, Literal

from fastapi import APIRouter, Query

from tcms_daq.identity import HEADLINES
from tcms_daq.service.deps import Store, errors
from tcms_daq.service.routes.tests import unix_seconds
from tcms_daq.service.runner import RequestRejected
from tcms_daq.service.schemas import BenchBiasView, SpcChartView
from tcms_daq.spc import bench_bias, individuals_chart
from tcms_daq.store import RunQuery, StoredRun

router = APIRouter(prefix="/api/spc", tags=["spc"])

Quantity = Literal["rigidity_nm_per_arcmin", "lost_motion_arcsec", "backlash_arcsec"]
UNITS = {h.key: h.unit for h in HEADLINES}
MAX_RUNS = 10_000
_Name = Annotated[str, Query(min_length=1, max_length=200)]


def _completed(store: Store, reducer: str, bench: str | None, quantity: str) -> list[tuple[StoredRun, float]]:
    """Completed runs of ``reducer`` (on ``bench``) with a finite ``quantity``, oldest first."""
    runs = store.list_runs(MAX_RUNS, 0, RunQuery(reducer=reducer, bench=bench, status="completed"))
    out = []
    for run in reversed(runs):
        value = (run.results or {}).get(quantity)
        if isinstance(value, int | float) and not isinstance(value, bool) and value == value and abs(value) != float("inf"):
            out.append((run, float(value)))
    return out


@router.get("/chart", response_model=SpcChartView, responses=errors(422))
def control_chart(store: Store, reducer: _Name, quantity: Quantity = "rigidity_nm_per_arcmin",
                  bench: Annotated[str | None, Query(min_length=1, max_length=200)] = None,
                  baseline_runs: Annotated[int | None, Query(ge=2, le=MAX_RUNS)] = None,
                  baseline_until: Annotated[datetime | None, Query(
                      description="the baseline is every run created up to this time (ISO 8601)")] = None,
                  ) -> dict[str, Any]:
    """Individuals / moving-range chart of one result of the completed runs of a reducer model (on one bench, or
    the fleet), in test order; limits from the baseline: the first ``baseline_runs`` runs (default 20, or all
    when fewer) or the runs up to ``baseline_until``."""
    if baseline_runs is not None and baseline_until is not None:
        raise RequestRejected("give baseline_runs or baseline_until, not both")
    points = _completed(store, reducer, bench, quantity)
    if baseline_until is not None:
        until = unix_seconds(baseline_until)
        n = sum(1 for run, _ in points if until is not None and run.created_at <= until + 0.001)
    else:
        n = min(baseline_runs or 20, len(points))
    if len(points) < 2 or n < 2:
        where = f" on bench {bench}" if bench else ""
        raise RequestRejected(f"{len(points)} completed runs of {reducer}{where} with {quantity} ({n} in the "
                              "baseline): a control chart needs at least 2 in its baseline")
    chart = individuals_chart([v for _, v in points], n)
    return {"quantity": quantity, "unit": UNITS[quantity], "reducer": reducer, "bench": bench,
            "runs": [{"id": r.id, "created_at": r.summary()["created_at"], "bench_id": r.bench_id,
                      "serial_number": r.request.get("serial_number"), "value": v} for r, v in points],
            "chart": chart.to_dict()}


@router.get("/bias", response_model=BenchBiasView, responses=errors(422))
def bias(store: Store, reducer: _Name, quantity: Quantity = "rigidity_nm_per_arcmin",
         reference: Annotated[str | None, Query(min_length=1, max_length=200,
                                                description="bench id whose bias is 0 (default: mean 0)")] = None,
         ) -> dict[str, Any]:
    """Each bench's bias on one result, from the reference units (same serial number) of a reducer model tested
    on several benches, with its standard and expanded uncertainty (Student's t, 95 %)."""
    points = [(r, v) for r, v in _completed(store, reducer, None, quantity)
              if r.bench_id and isinstance(r.request.get("serial_number"), str)]
    try:
        est = bench_bias([r.request["serial_number"] for r, _ in points], [str(r.bench_id) for r, _ in points],
                         [v for _, v in points], reference=reference)
    except ValueError as exc:
        raise RequestRejected(f"{reducer}, {quantity}: {exc}") from None
    return {"quantity": quantity, "unit": UNITS[quantity], "reducer": reducer, **est.to_dict()}
