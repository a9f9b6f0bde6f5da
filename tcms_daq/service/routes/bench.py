"""The bench: its instruments' real states, limits, catalogue and the live acquisition rate."""

from __future__ import annotations

from fastapi import APIRouter

from tcms_daq.service.admin_settings import stored_settings
from tcms_daq.service.deps import Bench, Live, Manager, Store
from tcms_daq.service.schemas import BenchStatus

router = APIRouter(tags=["bench"])


@router.get("/api/bench", response_model=BenchStatus)
def bench_status(bench: Bench, manager: Manager, live: Live, store: Store) -> BenchStatus:
    """The bench as the service last read it (the status poll never stops), the bounds a test request must keep
    (``test_bounds``; the dashboard's form uses them), the reducer catalogue and the active test."""
    return BenchStatus.model_validate({
        **bench.status(),
        "id": store.bench_id,
        "display_name": stored_settings(store).bench_display_name,
        "active_test": manager.active_id,
        "live": {
            "acquisition_rate_samples_per_second": live.acquisition_rate_hz(),
            "frame_rate_hz": live.frame_rate_hz,
            "clients": len(live.clients),
        },
    })
