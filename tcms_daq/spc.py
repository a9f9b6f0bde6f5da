"""Statistical process control of test results across a fleet of benches (pure numpy; no I/O).

* :func:`individuals_chart` — an individuals / moving-range (I-MR) chart of one result (rigidity, lost motion,
  backlash) in test order, its limits from a baseline period: centre x̄ of the baseline, σ̂ = MR̄/d₂ (d₂ = 1.128
  for moving ranges of two), individuals limits x̄ ± 3σ̂, moving-range upper limit D₄·MR̄ (D₄ = 3.267). Points are
  flagged by the Western Electric rules 1 (beyond 3σ̂) and 2 (8 in a row on one side of the centre).
* :func:`bench_bias` — each bench's bias from reference units tested on several benches (same serial number):
  the additive model value = unit + bench + noise, solved by least squares with the reference bench's bias 0
  (or the benches' mean 0), standard uncertainties from the residual scatter and (XᵀX)⁻¹, expanded with Student's t
  at 95 % on the residual degrees of freedom.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

D2_MR2 = 1.128  # mean moving range of two / σ (normal data)
D4_MR2 = 3.267  # upper control limit factor of the moving-range chart
RUN_LENGTH = 8  # Western Electric rule 2
MIN_BASELINE = 2  # the fewest runs a moving range, hence limits, can be computed from
RECOMMENDED_BASELINE = 20  # limits from fewer runs are provisional (σ̂ from MR̄ scatters by about 1/√(n−1)·0.8)


@dataclass(frozen=True)
class ImrChart:
    """An I-MR chart. ``flags[i]`` names the rules point i breaks (``beyond_3_sigma``, ``run_of_8``)."""

    values: NDArray[np.float64]
    moving_range: NDArray[np.float64]  # |x_i − x_{i−1}|, NaN at i = 0
    baseline_n: int
    center: float
    sigma: float
    ucl: float
    lcl: float
    mr_center: float
    mr_ucl: float
    flags: list[list[str]] = field(default_factory=list)

    @property
    def out_of_control(self) -> list[int]:
        return [i for i, f in enumerate(self.flags) if f]

    def to_dict(self) -> dict[str, object]:
        def listed(a: NDArray[np.float64]) -> list[float | None]:
            out: list[float | None] = a.tolist()
            for i in np.flatnonzero(~np.isfinite(a)).tolist():
                out[i] = None
            return out

        return {"values": listed(self.values), "moving_range": listed(self.moving_range),
                "baseline_n": self.baseline_n, "center": self.center, "sigma": self.sigma, "ucl": self.ucl,
                "lcl": self.lcl, "mr_center": self.mr_center, "mr_ucl": self.mr_ucl, "flags": self.flags,
                "out_of_control": self.out_of_control}


def individuals_chart(values: ArrayLike, baseline_n: int) -> ImrChart:
    """I-MR chart of ``values`` (test order) with limits from the first ``baseline_n`` values (at least 2).
    ValueError when the baseline is too short or holds a non-finite value."""
    x = np.asarray(values, dtype=float)
    if x.ndim != 1:
        raise ValueError("values must be one-dimensional")
    if not 2 <= baseline_n <= len(x):
        raise ValueError(f"the baseline needs 2 … {len(x)} values, got {baseline_n}")
    base = x[:baseline_n]
    if not np.isfinite(base).all():
        raise ValueError("the baseline holds a value that is not a finite number")
    mr = np.full(len(x), np.nan)
    mr[1:] = np.abs(np.diff(x))
    center = float(base.mean())
    mr_center = float(mr[1:baseline_n].mean())
    sigma = mr_center / D2_MR2
    ucl, lcl = center + 3 * sigma, center - 3 * sigma
    flags: list[list[str]] = [[] for _ in x]
    side = np.sign(x - center)
    run = 0
    for i, v in enumerate(x):
        if math.isfinite(v) and (v > ucl or v < lcl):
            flags[i].append("beyond_3_sigma")
        run = run + 1 if i and side[i] != 0 and side[i] == side[i - 1] else (1 if side[i] != 0 else 0)
        if run >= RUN_LENGTH:
            flags[i].append("run_of_8")
    return ImrChart(x, mr, baseline_n, center, sigma, ucl, lcl, mr_center, D4_MR2 * mr_center, flags)


@dataclass(frozen=True)
class BenchBias:
    """One bench's bias (its results minus the reference's, in the result's unit) with its uncertainty."""

    bench: str
    bias: float
    u: float  # standard uncertainty
    U: float  # expanded, k·u
    k: float
    runs: int
    units: int


@dataclass(frozen=True)
class BiasEstimate:
    benches: list[BenchBias]
    reference: str | None  # the bench whose bias is 0 (None: the benches' mean is 0)
    dof: int  # residual degrees of freedom
    residual_sd: float  # repeatability of one test (pooled)
    units: list[str]
    excluded_runs: int  # runs of units tested on one bench only (they say nothing of the benches)

    def to_dict(self) -> dict[str, object]:
        return {"reference": self.reference, "dof": self.dof, "residual_sd": self.residual_sd, "units": self.units,
                "excluded_runs": self.excluded_runs,
                "benches": [{"bench": b.bench, "bias": b.bias, "u": b.u, "U": b.U, "k": b.k, "runs": b.runs,
                             "units": b.units} for b in self.benches]}


def bench_bias(units: Sequence[str], benches: Sequence[str], values: ArrayLike,
               reference: str | None = None) -> BiasEstimate:
    """Bench biases from repeated tests of reference units on several benches.

    ``units[i]`` (serial number), ``benches[i]`` and ``values[i]`` describe test i. Only units tested on at least
    two benches count. ``reference``: the bench whose bias is 0 (default: the benches' mean bias is 0).
    ValueError when the design cannot separate the benches or leaves no degree of freedom for the scatter."""
    from scipy import stats

    y_all = np.asarray(values, dtype=float)
    if not (len(units) == len(benches) == len(y_all)):
        raise ValueError("units, benches and values differ in length")
    keep = np.isfinite(y_all)
    benches_of: dict[str, set[str]] = {}
    for unit, bench, ok in zip(units, benches, keep, strict=True):
        if ok:
            benches_of.setdefault(unit, set()).add(bench)
    shared = {u for u, b in benches_of.items() if len(b) >= 2}
    rows = [i for i in range(len(y_all)) if keep[i] and units[i] in shared]
    unit_names = sorted(shared)
    bench_names = sorted({benches[i] for i in rows})
    if len(bench_names) < 2:
        raise ValueError("no reference unit was tested on two benches or more")
    if reference is not None and reference not in bench_names:
        raise ValueError(f"reference bench {reference!r} tested none of the shared units "
                         f"(benches: {', '.join(bench_names)})")
    y = y_all[rows]
    n, n_units, n_benches = len(rows), len(unit_names), len(bench_names)
    # columns: one per unit, then bench effects under the constraint
    design = np.zeros((n, n_units + n_benches - 1))
    u_index = {u: j for j, u in enumerate(unit_names)}
    free = [b for b in bench_names if b != reference] if reference is not None else bench_names[:-1]
    b_index = {b: n_units + j for j, b in enumerate(free)}
    for r, i in enumerate(rows):
        design[r, u_index[units[i]]] = 1.0
        bench = benches[i]
        if bench in b_index:
            design[r, b_index[bench]] = 1.0
        elif reference is None:  # the last bench: minus the sum of the others (mean bias 0)
            design[r, n_units:] = -1.0
    rank = np.linalg.matrix_rank(design)
    if rank < design.shape[1]:
        raise ValueError("the benches are not connected through shared units: their biases cannot be separated")
    dof = n - design.shape[1]
    if dof < 1:
        raise ValueError("no repeated tests: nothing is left to estimate the scatter (test the units again)")
    coef, *_ = np.linalg.lstsq(design, y, rcond=None)
    residual = y - design @ coef
    s2 = float(residual @ residual) / dof
    cov = s2 * np.linalg.inv(design.T @ design)
    k = float(stats.t.ppf(0.975, dof))
    effects: dict[str, tuple[float, float]] = {}
    weights = np.zeros(design.shape[1])
    for bench in bench_names:
        weights[:] = 0.0
        if bench in b_index:
            weights[b_index[bench]] = 1.0
        elif reference is None:
            weights[n_units:] = -1.0
        bias = float(weights @ coef)
        u = math.sqrt(max(float(weights @ cov @ weights), 0.0))
        effects[bench] = (bias, u)
    out = []
    for bench in bench_names:
        bias, u = effects[bench]
        mask = [benches[i] == bench for i in rows]
        out.append(BenchBias(bench, bias, u, k * u, k, int(sum(mask)),
                             len({units[i] for i, m in zip(rows, mask, strict=True) if m})))
    return BiasEstimate(out, reference, dof, math.sqrt(s2), unit_names, int(keep.sum()) - n)
