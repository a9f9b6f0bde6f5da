"""``GET /metrics``: Prometheus text exposition, collected from the live objects at scrape time."""

from __future__ import annotations

from collections.abc import Callable, Iterator

from prometheus_client import CollectorRegistry, generate_latest
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily, Metric
from prometheus_client.registry import Collector

from tcms_daq.service.events import EventHub
from tcms_daq.service.live import LiveHub
from tcms_daq.store import Store


class ServiceCollector(Collector):
    def __init__(self, live: LiveHub, events: EventHub, store: Store, active_run: Callable[[], str | None]):
        self.live = live
        self.events = events
        self.store = store
        self.active_run = active_run

    def collect(self) -> Iterator[Metric]:
        yield GaugeMetricFamily(
            "tcms_acquisition_rate_samples_per_second",
            "Samples per second published by the acquisition loop (recent window)",
            value=self.live.acquisition_rate_hz(),
        )
        yield CounterMetricFamily(
            "tcms_acquisition_samples", "Samples published by the acquisition loop", value=self.live.samples_total
        )
        yield CounterMetricFamily("tcms_live_frames", "Live frames encoded", value=self.live.frames_total)
        yield CounterMetricFamily(
            "tcms_live_dropped_frames", "Live frames dropped from client queues", value=self.live.dropped_total()
        )
        yield CounterMetricFamily(
            "tcms_live_samples_decimated", "Samples left out of live frames by min/max decimation (all recorded)",
            value=self.live.samples_decimated_total,
        )
        yield CounterMetricFamily(
            "tcms_live_evicted_clients", "Live clients evicted for stalling", value=self.live.evicted_total
        )
        yield GaugeMetricFamily("tcms_live_clients", "Connected live clients", value=len(self.live.clients))
        yield GaugeMetricFamily("tcms_event_clients", "Connected event clients", value=len(self.events.clients))
        yield CounterMetricFamily("tcms_events", "Test events published", value=self.events.sequence)
        tests = GaugeMetricFamily("tcms_tests", "Stored tests by status", labels=["status"])
        for status, n in self.store.count_by_status().items():
            tests.add_metric([status], n)
        yield tests
        yield GaugeMetricFamily(
            "tcms_test_active", "1 while a test is queued or running", value=1 if self.active_run() else 0
        )


def make_registry(collector: ServiceCollector) -> CollectorRegistry:
    registry = CollectorRegistry(auto_describe=False)
    registry.register(collector)
    return registry


def render(registry: CollectorRegistry) -> bytes:
    return generate_latest(registry)
