"""SPC of a fleet's results: I-MR control charts per reducer model, test method (and bench), bench-to-bench bias
from reference units tested on several benches (:mod:`tcms_daq.spc`; the runs from the shared store).

A series holds results of one test method only (:func:`tcms_daq.identity.test_method`): a test at 4 output
positions reports the worst of 4, a different quantity from one position's value, so ``single``, ``positions-4``
and ``rates-3`` are separate charts and separate bias estimates."""

from __future__ import annotations

from datetime import datetime
from typing import Annotated, Any, Literal

from fastapi import APIRouter, Query
from fastapi.responses import JSONResponse

from tcms_daq.identity import HEADLINES
from tcms_daq.service.deps import Store, errors
from tcms_daq.service.routes.tests import unix_seconds
from tcms_daq.service.runner import RequestRejected
from tcms_daq.service.schemas import BenchBiasView, SpcChartView
from tcms_daq.spc import MIN_BASELINE, RECOMMENDED_BASELINE, bench_bias, individuals_chart
from tcms_daq.store import RunQuery
from tcms_daq.store.base import HeadlinePoint, iso_many

router = APIRouter(prefix="/api/spc", tags=["spc"])

Quantity = Literal["rigidity_nm_per_arcmin", "lost_motion_arcsec", "backlash_arcsec"]
UNITS = {h.key: h.unit for h in HEADLINES}
MAX_RUNS = 10_000
_Name = Annotated[str, Query(min_length=1, max_length=200)]


_Method = Annotated[str, Query(pattern=r"^(single|positions-[0-9]{1,2}|rates-[0-9]{1,2})$", description=(
    "the test method of the series: 'single' (one position), 'positions-N' (worst of N output positions) or "
    "'rates-N' (worst of N loading rates)"))]


def _completed(store: Store, reducer: str, bench: str | None, quantity: str) -> list[HeadlinePoint]:
    """Completed runs of ``reducer`` (on ``bench``) with a finite ``quantity``, oldest first, each with the series
    of its test method (of the newest MAX_RUNS runs)."""
    return store.headline_points(quantity, RunQuery(reducer=reducer, bench=bench, status="completed"), MAX_RUNS)


def _methods(points: list[HeadlinePoint]) -> dict[str, int]:
    counts: dict[str, int] = {}
    for p in points:
        counts[p.series] = counts.get(p.series, 0) + 1
    return dict(sorted(counts.items()))


@router.get("/chart", response_model=SpcChartView, responses=errors(422))
def control_chart(store: Store, reducer: _Name, quantity: Quantity = "rigidity_nm_per_arcmin",
                  method: _Method = "single",
                  bench: Annotated[str | None, Query(min_length=1, max_length=200)] = None,
                  baseline_runs: Annotated[int | None, Query(ge=2, le=MAX_RUNS)] = None,
                  baseline_until: Annotated[datetime | None, Query(
                      description="the baseline is every run created up to this time (ISO 8601)")] = None,
                  ) -> JSONResponse:
    """Individuals / moving-range chart of one result of the completed runs of a reducer model tested by one
    method (on one bench, or the fleet), in test order; limits from the baseline: the first ``baseline_runs``
    runs (default 20, or all when fewer) or the runs up to ``baseline_until``. ``methods`` counts the runs of
    every method; ``limits`` says whether the baseline sets limits at all (``none``: fewer than 2 runs, no chart),
    ``provisional`` (fewer than 20) or ``established``, and ``note`` says it in words."""
    if baseline_runs is not None and baseline_until is not None:
        raise RequestRejected("give baseline_runs or baseline_until, not both")
    everything = _completed(store, reducer, bench, quantity)
    points = [p for p in everything if p.series == method]
    if baseline_until is not None:
        until = unix_seconds(baseline_until)
        n = sum(1 for p in points if until is not None and p.created_at <= until + 0.001)
    else:
        n = min(baseline_runs or RECOMMENDED_BASELINE, len(points))
    where = f" on bench {bench}" if bench else ""
    runs = [{"id": p.id, "created_at": at, "bench_id": p.bench_id, "serial_number": p.serial_number, "value": p.value}
            for p, at in zip(points, iso_many([p.created_at for p in points]), strict=True)]
    view: dict[str, Any] = {"quantity": quantity, "unit": UNITS[quantity], "reducer": reducer, "bench": bench,
                            "method": method, "methods": _methods(everything), "runs": runs, "baseline_n": n}
    if len(points) < MIN_BASELINE or n < MIN_BASELINE:
        others = ", ".join(f"{k} ({c})" for k, c in view["methods"].items() if k != method)
        view.update(chart=None, limits="none", note=(
            f"too few runs: {len(points)} completed {method} runs of {reducer}{where} with {quantity}, {n} of them "
            f"in the baseline; control limits need at least {MIN_BASELINE}"
            + (f" (other methods: {others})" if others else "")))
        return _answered(view)
    chart = individuals_chart([p.value for p in points], n)
    provisional = n < RECOMMENDED_BASELINE
    view.update(chart=chart.to_dict(), limits="provisional" if provisional else "established", note=(
        f"baseline of {n} runs" + (f": limits provisional until {RECOMMENDED_BASELINE} runs" if provisional else "")))
    return _answered(view)


def _answered(view: dict[str, Any]) -> JSONResponse:
    """The chart as JSON without FastAPI's validation against SpcChartView: for 10 000 runs that took several
    times the query (tests/service/test_service_spc.py validates the view against the model instead)."""
    return JSONResponse(view)


@router.get("/bias", response_model=BenchBiasView, responses=errors(422))
def bias(store: Store, reducer: _Name, quantity: Quantity = "rigidity_nm_per_arcmin", method: _Method = "single",
         reference: Annotated[str | None, Query(min_length=1, max_length=200,
                                                description="bench id whose bias is 0 (default: mean 0)")] = None,
         ) -> dict[str, Any]:
    """Each bench's bias on one result, from the reference units (same serial number) of a reducer model tested
    by one method on several benches, with its standard and expanded uncertainty (Student's t, 95 %)."""
    points = [p for p in _completed(store, reducer, None, quantity)
              if p.series == method and p.bench_id and p.serial_number is not None]
    try:
        est = bench_bias([str(p.serial_number) for p in points], [str(p.bench_id) for p in points],
                         [p.value for p in points], reference=reference)
    except ValueError as exc:
        raise RequestRejected(f"{reducer}, {quantity}, {method} tests: {exc}") from None
    return {"quantity": quantity, "unit": UNITS[quantity], "reducer": reducer, "method": method, **est.to_dict()}
