"""SPC against generators with known truth: I-MR limits from a baseline, the rules, and bench biases from
reference units tested on several benches (their U covers the true bias about 95 % of the time)."""

from __future__ import annotations

import numpy as np
import pytest

from tcms_daq.spc import bench_bias, individuals_chart


def test_imr_limits_estimate_the_process_and_flag_a_shift_after_the_baseline():
    rng = np.random.default_rng(7)
    sigma, mean = 2.0, 294.0
    x = np.concatenate([rng.normal(mean, sigma, 400), rng.normal(mean + 4 * sigma, sigma, 12)])
    chart = individuals_chart(x, baseline_n=400)
    assert chart.center == pytest.approx(mean, abs=3 * sigma / 20)  # x̄ of 400: σ/20
    assert chart.sigma == pytest.approx(sigma, rel=0.1)  # MR̄/d₂ of normal data
    assert chart.ucl == pytest.approx(chart.center + 3 * chart.sigma)
    assert chart.mr_ucl == pytest.approx(3.267 * chart.mr_center)
    in_baseline = [i for i in chart.out_of_control if i < 400]
    assert len(in_baseline) <= 4  # 0.27 % beyond 3σ, and rare runs of 8
    shifted = [i for i in chart.out_of_control if i >= 400]
    assert len(shifted) >= 8  # a 4σ shift: most points beyond 3σ, then a run of 8
    assert "run_of_8" in chart.flags[407]
    assert np.isnan(chart.moving_range[0]) and chart.moving_range[1] == pytest.approx(abs(x[1] - x[0]))
    doc = chart.to_dict()
    assert doc["moving_range"][0] is None and len(doc["values"]) == 412


def test_imr_refuses_a_bad_baseline():
    with pytest.raises(ValueError, match="baseline needs 2"):
        individuals_chart([1.0, 2.0, 3.0], baseline_n=1)
    with pytest.raises(ValueError, match="baseline needs"):
        individuals_chart([1.0, 2.0], baseline_n=3)
    with pytest.raises(ValueError, match="not a finite"):
        individuals_chart([1.0, np.nan, 3.0], baseline_n=3)


def _fleet(rng, biases: dict[str, float], n_units: int = 6, repeats: int = 2, sd: float = 0.8,
           one_bench_units: int = 2) -> tuple[list[str], list[str], np.ndarray]:
    """Reference units of true rigidity ~ N(294, 5) tested ``repeats`` times on every bench (value = unit +
    bench bias + noise), plus units tested on one bench only (they must not count)."""
    units, benches, values = [], [], []
    for u in range(n_units):
        truth = rng.normal(294.0, 5.0)
        for bench, bias in biases.items():
            for _ in range(repeats):
                units.append(f"REF-{u}")
                benches.append(bench)
                values.append(truth + bias + rng.normal(0.0, sd))
    for u in range(one_bench_units):
        units.append(f"ONCE-{u}")
        benches.append("b")
        values.append(1e6)  # would wreck the estimate if it counted
    return units, benches, np.array(values)


def test_bench_bias_recovers_known_biases_and_its_u_covers_them():
    biases = {"a": 0.0, "b": 1.5, "c": -0.7}
    rng = np.random.default_rng(11)
    covered, trials = {b: 0 for b in biases}, 300
    for _ in range(trials):
        est = bench_bias(*_fleet(rng, biases), reference="a")
        for row in est.benches:
            if abs(row.bias - biases[row.bench]) <= row.U:
                covered[row.bench] += 1
    assert covered["a"] == trials  # the reference: 0 by definition
    for bench in ("b", "c"):
        assert 0.91 * trials <= covered[bench] <= 0.99 * trials, covered
    est = bench_bias(*_fleet(np.random.default_rng(1), biases), reference="a")
    assert est.excluded_runs == 2 and est.units == [f"REF-{u}" for u in range(6)]
    assert est.residual_sd == pytest.approx(0.8, rel=0.35)
    by = {b.bench: b for b in est.benches}
    assert by["b"].runs == 12 and by["b"].units == 6 and by["a"].u == 0.0
    assert by["b"].k == pytest.approx(2.03, abs=0.02)  # t(0.975, 36 − 8 = 28)


def test_bench_bias_with_mean_zero_and_refusals():
    biases = {"a": 1.0, "b": 3.0, "c": -1.0}  # mean 1: relative to the mean they are 0, 2, −2
    est = bench_bias(*_fleet(np.random.default_rng(3), biases, repeats=3, sd=0.3))
    assert est.reference is None
    for row, truth in zip(est.benches, (0.0, 2.0, -2.0), strict=True):
        assert row.bias == pytest.approx(truth, abs=4 * row.u + 1e-9)
    assert sum(r.bias for r in est.benches) == pytest.approx(0.0, abs=1e-9)
    with pytest.raises(ValueError, match="two benches"):
        bench_bias(["u1", "u2"], ["a", "a"], [1.0, 2.0])
    with pytest.raises(ValueError, match="no repeated tests"):
        bench_bias(["u1", "u1"], ["a", "b"], [1.0, 2.0])
    with pytest.raises(ValueError, match="reference bench 'z'"):
        bench_bias(["u1", "u1", "u1"], ["a", "b", "b"], [1.0, 2.0, 2.1], reference="z")
    with pytest.raises(ValueError, match="not connected"):  # u1 links a–b, u2 links c–d: no path between
        bench_bias(["u1", "u1", "u1", "u2", "u2", "u2"], ["a", "b", "b", "c", "d", "d"],
                   [1.0, 2.0, 2.1, 1.0, 2.0, 2.1])
