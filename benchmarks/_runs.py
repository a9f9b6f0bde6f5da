"""What every benchmark module reports the same way: a figure measured in ``RUNS`` runs, as its min/median/max.

(The harness, ``python -m benchmarks``, adds the machine's load before and after each module and the time it was
measured; a module reports only what it measures.)
"""

from __future__ import annotations

import statistics
from collections.abc import Iterable

RUNS = 3  # runs per figure: the report gives min/median/max, never the best run alone


def spread(name: str, values: Iterable[float]) -> dict[str, float]:
    """``{name}_min``, ``{name}_median`` and ``{name}_max`` of ``values`` (one figure over its runs)."""
    ordered = sorted(float(v) for v in values)
    if not ordered:
        raise ValueError(f"no runs of {name}")
    return {f"{name}_min": ordered[0], f"{name}_median": statistics.median(ordered), f"{name}_max": ordered[-1]}
