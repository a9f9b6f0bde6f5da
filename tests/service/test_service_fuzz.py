"""Schemathesis against the running service (issue 10, Done when): ≥ 1 000 generated requests over every
operation of the OpenAPI schema, valid and invalid (positive and negative generation), with and without the
token, on the simulated bench — and not one server error.

Tests started by the fuzzer run on the in-process simulated bench; the others get 409 meanwhile.
"""

from __future__ import annotations

from collections import Counter

import pytest
import schemathesis
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from schemathesis import GenerationMode
from svc_helpers import TOKEN, serve

pytestmark = pytest.mark.slow

MIN_REQUESTS = 1000


def test_no_server_error_from_generated_requests(settings_factory, sim_config):
    with serve(settings_factory(config_path=sim_config, sim_speed=50.0)) as srv:
        schema = schemathesis.openapi.from_url(f"{srv.base}/openapi.json")
        operations = [result.ok() for result in schema.get_all_operations()]
        assert len(operations) >= 15
        strategy = st.one_of([op.as_strategy(mode) for op in operations
                              for mode in (GenerationMode.POSITIVE, GenerationMode.NEGATIVE)])
        statuses: Counter[int] = Counter()
        server_errors: list[str] = []

        @settings(max_examples=1100, deadline=None, database=None, derandomize=True,
                  suppress_health_check=list(HealthCheck))
        @given(case=strategy, with_token=st.booleans())
        def fuzz(case, with_token: bool) -> None:
            headers = {"Authorization": f"Bearer {TOKEN}"} if with_token else {}
            response = case.call(base_url=srv.base, headers=headers, timeout=30)
            statuses[response.status_code] += 1
            if response.status_code >= 500:
                server_errors.append(f"{response.status_code} {case.as_curl_command()}\n{response.text[:300]}")

        fuzz()
        total = sum(statuses.values())
        print(f"{total} requests, statuses {dict(sorted(statuses.items()))}")
        assert total >= MIN_REQUESTS, f"only {total} requests were generated: {dict(statuses)}"
        assert not server_errors, f"{len(server_errors)} server errors of {total} requests:\n" + "\n".join(
            server_errors[:5])
