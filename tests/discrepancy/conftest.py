"""Fixtures of the discrepancy tests: hidden-effect runs on the simulated bench (cached per session)."""

from __future__ import annotations

import pytest
from tcms_daq.sim.trials import CASES, make_pair


@pytest.fixture(scope="session")
def pair_cache():
    cache: dict = {}

    def get(case: str, seed: int):
        key = (case, seed)
        if key not in cache:
            cache[key] = make_pair(CASES[case], seed)
        return cache[key]

    return get
