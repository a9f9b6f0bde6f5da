"""The compiled fast path of Compensator.apply against the exact (term-by-term) path: accuracy at any span,
periodic tables, block folding, non-finite input, immutability, compilation at construction."""

import pickle

import numpy as np
import pytest

from tcms_daq.compensation import Compensator, Drift, Eccentricity, Offset, Periodic, Scale, Torsion, kernel
from tcms_daq.compensation.compensator import LONG_PERIOD_MIN_ARCSEC
from tcms_daq.compensation.kernel import BLOCK_SAMPLES, MAX_ABS_ANGLE_ARCSEC
from tcms_daq.units import ARCSEC_PER_REV

REVOLUTION = ARCSEC_PER_REV


def full_compensator(**kwargs) -> Compensator:
    return Compensator(
        [
            Scale(-0.19),
            Torsion(0.004),
            Offset(1.5),
            Eccentricity(eccentricity_mm=0.005, radius_mm=30.0, phase_rad=0.7),
            Periodic(72.0, 0.35, -0.12),
            Periodic(36.0, 0.08, 0.05),
            Periodic(REVOLUTION / 3, 2.0, -1.0),  # a third-order error over the revolution
        ],
        **kwargs,
    )


SPANS = {
    "hysteresis ±230″": (-230.0, 230.0),
    "±1 revolution": (-REVOLUTION / 2, REVOLUTION / 2),
    "0 … 1 revolution": (0.0, REVOLUTION),
    "±2 revolutions": (-2 * REVOLUTION, 2 * REVOLUTION),
    "±1000 revolutions": (-1000 * REVOLUTION, 1000 * REVOLUTION),
}


@pytest.mark.parametrize("span", SPANS.values(), ids=SPANS.keys())
def test_random_samples_agree_with_the_exact_path(span):
    comp = full_compensator().with_terms(Drift(0.02))  # one time-dependent term: evaluated directly
    rng = np.random.default_rng(11)
    n = 200_003
    angle = rng.uniform(*span, n)
    torque = rng.uniform(-1500, 1500, n)
    time = rng.uniform(0, 600, n)
    fast = comp.apply(angle, torque, time)
    exact = comp.apply(angle, torque, time, exact=True)
    assert np.max(np.abs(fast - exact)) <= comp.tolerance_arcsec / 2
    assert comp.tolerance_arcsec / 2 <= 1e-3 / 2  # far below the encoder's 0.7″ resolution
    # and the exact path is the sum of the terms evaluated one by one
    by_hand = angle - sum(t.evaluate(angle, torque, time) for t in comp.terms)
    np.testing.assert_allclose(exact, by_hand, rtol=0, atol=1e-6)


@pytest.mark.parametrize("span", SPANS.values(), ids=SPANS.keys())
def test_sweeps_agree_with_the_exact_path(span):
    # slowly moving readings: most blocks lie in one cell of the long-period table and are folded
    comp = full_compensator()
    rng = np.random.default_rng(12)
    n = 300_001
    angle = np.linspace(*span, n) + rng.normal(0, 0.2, n)
    torque = 1000 * np.sin(np.linspace(0, 20, n))
    assert np.max(np.abs(comp.apply(angle, torque) - comp.apply(angle, torque, exact=True))) <= 5e-4


def _blocks_near_grid_points(step_arcsec: float, reach_in_steps: float, rng) -> np.ndarray:
    """Blocks that each start on a grid point of the long-period table and spread ±reach steps around it."""
    blocks = []
    for grid_point in rng.integers(-1000, 1000, 60):
        block = grid_point * step_arcsec + rng.uniform(-reach_in_steps, reach_in_steps, BLOCK_SAMPLES) * step_arcsec
        block[0] = grid_point * step_arcsec
        blocks.append(block)
    return np.concatenate(blocks)


@pytest.mark.parametrize("layout", ["sorted sweep", "blocks within one cell", "blocks across cell edges"])
def test_folded_blocks_give_the_per_sample_result(layout):
    # the same samples in order (blocks in one cell of the long-period table are folded) and shuffled (every
    # block looked up per sample) agree to rounding: folding changes nothing but the cost
    comp = full_compensator()
    step = comp.fast_path.long_table.step_arcsec
    rng = np.random.default_rng(13)
    angle = {
        "sorted sweep": np.sort(rng.uniform(-REVOLUTION, REVOLUTION, 100 * BLOCK_SAMPLES)),
        "blocks within one cell": _blocks_near_grid_points(step, 0.45, rng),
        "blocks across cell edges": _blocks_near_grid_points(step, 0.8, rng),
    }[layout]
    torque = rng.uniform(-1000, 1000, angle.size)
    order = rng.permutation(angle.size)
    in_order = comp.apply(angle, torque)
    shuffled = np.empty_like(angle)
    shuffled[order] = comp.apply(angle[order], torque[order])
    np.testing.assert_allclose(in_order, shuffled, rtol=0, atol=1e-8)


def test_terms_are_sorted_into_tables_by_period():
    comp = full_compensator().with_terms(Periodic(70.0, 0.1, 0.0), Drift(0.01))
    fast = comp.fast_path
    assert fast.short_table is not None and fast.short_table.period_arcsec == pytest.approx(72.0)
    assert fast.long_table is not None and fast.long_table.period_arcsec == pytest.approx(REVOLUTION)
    # 70″ does not divide a revolution and drift depends on time: both evaluated directly
    assert {t.label() for t in fast.direct_terms} == {"periodic:70", "drift"}
    assert {t.label() for t in fast.tabulated_terms} == {
        "eccentricity", "periodic:72", "periodic:36", f"periodic:{REVOLUTION / 3:g}"
    }
    assert fast.gain == pytest.approx(1.19) and fast.arcsec_per_nm == 0.004 and fast.offset_arcsec == 1.5
    for table in (fast.short_table, fast.long_table):
        assert table.size & (table.size - 1) == 0  # a power of two
        assert table.max_error_arcsec <= comp.tolerance_arcsec / 4
        assert not table.values_arcsec.flags.writeable and not table.steps_arcsec.flags.writeable
    assert LONG_PERIOD_MIN_ARCSEC > 72.0


def test_zero_tolerance_evaluates_every_term_directly():
    comp = full_compensator(tolerance_arcsec=0.0)
    assert comp.fast_path.short_table is None and comp.fast_path.long_table is None
    x = np.linspace(-5000, 5000, 1001)
    np.testing.assert_allclose(comp.apply(x, x), comp.apply(x, x, exact=True), rtol=0, atol=1e-9)


def test_tabulate_meets_its_error_bound_between_the_checked_points():
    def wave(x):
        return 0.5 * np.sin(2 * np.pi * x / 72.0) + 0.2 * np.cos(4 * np.pi * x / 72.0 + 0.3)

    table = kernel.tabulate(wave, 72.0, 1e-4)
    assert table is not None and table.size & (table.size - 1) == 0
    assert kernel.tabulate(wave, 72.0, 1e-4, max_points=table.size // 2) is None
    # the tangent lookup, evaluated by the kernel, against the function on random angles over many periods
    rng = np.random.default_rng(14)
    angle = rng.uniform(-1e6, 1e6, 100_000)
    out = np.empty_like(angle)
    kernel.compensate(angle, angle, out, 1.0, 0.0, 0.0, table, None)
    assert np.max(np.abs((angle - out) - wave(angle))) <= 1e-4
    with pytest.raises(ValueError, match="period"):
        kernel.tabulate(wave, 0.0, 1e-4)


@pytest.mark.parametrize(
    "terms",
    [
        [Scale(0.03), Torsion(0.004), Offset(2.0)],  # linear only: no table
        [Torsion(0.004)],  # gain 1, no offset
        [Offset(-1.0), Periodic(72.0, 0.3, 0.1)],  # short-period table only, no torque term
        [Scale(-0.19), Eccentricity(eccentricity_mm=0.01, radius_mm=30.0)],  # long-period table only
    ],
)
@pytest.mark.parametrize("scalar_torque", [False, True])
def test_variants_match_the_terms_one_by_one(terms, scalar_torque):
    comp = Compensator(terms)
    rng = np.random.default_rng(1)
    n = 3 * BLOCK_SAMPLES + 999
    angle = rng.uniform(-REVOLUTION, REVOLUTION, n)
    torque = 750.0 if scalar_torque else rng.uniform(-1500, 1500, n)
    by_hand = angle - sum(t.evaluate(angle, torque, None) for t in terms)
    assert np.max(np.abs(comp.apply(angle, torque) - by_hand)) <= comp.tolerance_arcsec / 2
    np.testing.assert_allclose(comp.apply(angle, torque, exact=True), by_hand, rtol=0, atol=1e-6)
    # in place, across block boundaries
    buf = angle.copy()
    comp.apply(buf, torque, out=buf)
    np.testing.assert_array_equal(buf, comp.apply(angle, torque))


def test_output_overlapping_the_input_shifted_reads_the_input_first():
    comp = full_compensator()
    data = np.linspace(-300, 300, 2 * BLOCK_SAMPLES + 1)
    expected = comp.apply(data[1:], 0.0)
    comp.apply(data[1:], 0.0, out=data[:-1])
    np.testing.assert_array_equal(data[:-1], expected)


def test_non_finite_samples_give_nan_there_and_nothing_else_changes():
    comp = full_compensator()
    rng = np.random.default_rng(15)
    n = 4 * BLOCK_SAMPLES + 7
    angle = rng.uniform(-REVOLUTION, REVOLUTION, n)
    torque = rng.uniform(-1000, 1000, n)
    bad_angle = angle.copy()
    bad_at = {BLOCK_SAMPLES + 3: np.nan, 2 * BLOCK_SAMPLES: np.inf, 2 * BLOCK_SAMPLES + 1: -np.inf,
              3 * BLOCK_SAMPLES + 5: 2.0 * MAX_ABS_ANGLE_ARCSEC, 7: -1e300}
    for i, value in bad_at.items():
        bad_angle[i] = value
    bad_torque = torque.copy()
    bad_torque[100] = np.nan
    clean = comp.apply(angle, torque)
    with np.errstate(all="raise"):  # nothing may raise, whatever the caller's error handling
        before = np.geterr()
        fast = comp.apply(bad_angle, bad_torque)
        exact = comp.apply(bad_angle, bad_torque, exact=True)
        assert np.geterr() == before
    expected_nan = sorted([*bad_at, 100])
    assert np.flatnonzero(np.isnan(fast)).tolist() == expected_nan
    assert np.flatnonzero(np.isnan(exact)).tolist() == expected_nan
    ok = ~np.isnan(fast)
    np.testing.assert_array_equal(fast[ok], clean[ok])


def test_torque_is_ignored_when_no_term_uses_it():
    comp = Compensator([Scale(0.01), Periodic(72.0, 0.3, 0.0)])
    angle = np.linspace(-100, 100, 1000)
    torque = np.full_like(angle, np.nan)
    np.testing.assert_array_equal(comp.apply(angle, torque), comp.apply(angle, 0.0))


def test_the_kernel_is_compiled_when_the_compensator_is_built():
    comp = full_compensator()
    compiled = len(kernel.compensate.signatures)
    comp.apply(np.linspace(-1, 1, 10), np.zeros(10))
    comp.apply(np.linspace(-1, 1, 10), 5.0)
    assert len(kernel.compensate.signatures) == compiled


def test_a_compensator_is_immutable_and_pickles():
    comp = full_compensator(meta={"description": "test"})
    with pytest.raises(AttributeError, match="immutable"):
        comp.terms = ()  # type: ignore[misc]
    with pytest.raises(TypeError):
        comp.meta["description"] = "changed"  # type: ignore[index]
    again = pickle.loads(pickle.dumps(comp))
    assert again == comp
    x = np.linspace(-1000, 1000, 777)
    np.testing.assert_array_equal(again.apply(x, x), comp.apply(x, x))


# ---- the vectorised pass: lanes, tails, streaming output, input layouts ----


def _by_hand(comp: Compensator, angle: np.ndarray, torque) -> np.ndarray:
    """θ − Σ term(θ, T), each term evaluated on its own; NaN where θ is out of the domain."""
    angle = np.asarray(angle, dtype=float)
    with np.errstate(invalid="ignore"):
        result = angle - sum(t.evaluate(angle, torque, None) for t in comp.terms)
    result[~(np.abs(angle) <= MAX_ABS_ANGLE_ARCSEC)] = np.nan
    return result


@pytest.mark.parametrize("n", [0, 1, 2, 3, 4, 5, 7, 8, 9, 511, 512, 513, 515, 1027, 2 * BLOCK_SAMPLES + 3])
@pytest.mark.parametrize("span", [SPANS["hysteresis ±230″"], SPANS["±1 revolution"]], ids=["hysteresis", "revolution"])
def test_every_batch_length_agrees_with_the_terms(n, span):
    # four samples at a time and the samples left over, in blocks folded and not
    comp = full_compensator()
    rng = np.random.default_rng(n)
    angle = np.sort(rng.uniform(*span, n))
    torque = rng.uniform(-1500, 1500, n)
    fast = comp.apply(angle, torque)
    assert fast.shape == (n,)
    assert np.max(np.abs(fast - _by_hand(comp, angle, torque)), initial=0.0) <= comp.tolerance_arcsec / 2


def test_a_streamed_output_agrees_with_the_terms_and_with_the_in_place_result():
    # outputs of STREAMING_MIN_BYTES and more are written with non-temporal stores from a cache-line boundary on;
    # an output starting 1 … 7 samples past such a boundary exercises the short first block
    comp = full_compensator()
    n = kernel.STREAMING_MIN_BYTES // 8 + 2 * BLOCK_SAMPLES + 3
    rng = np.random.default_rng(21)
    angle = np.linspace(-REVOLUTION / 2, REVOLUTION / 2, n) + rng.normal(0, 0.2, n)
    torque = 1000 * np.sin(np.linspace(0, 30, n))
    bad_at = [0, 5, BLOCK_SAMPLES + 1, n // 2, n - 2]
    for i, value in zip(bad_at, [np.nan, np.inf, -np.inf, 2 * MAX_ABS_ANGLE_ARCSEC, np.nan], strict=True):
        angle[i] = value
    expected = _by_hand(comp, angle, torque)
    backing = np.empty(n + 8)
    for shift in range(8):
        out = backing[shift: shift + n]
        comp.apply(angle, torque, out=out)
        assert np.flatnonzero(np.isnan(out)).tolist() == bad_at
        ok = ~np.isnan(out)
        assert np.max(np.abs(out[ok] - expected[ok])) <= comp.tolerance_arcsec / 2
    in_place = angle.copy()
    comp.apply(in_place, torque, out=in_place)  # an output that is an input is not streamed
    np.testing.assert_allclose(in_place, out, rtol=0, atol=1e-9)


def test_inputs_of_any_dtype_and_layout_give_the_float64_result():
    comp = full_compensator()
    rng = np.random.default_rng(22)
    n = 3 * BLOCK_SAMPLES + 5
    wide_angle = rng.uniform(-REVOLUTION, REVOLUTION, 2 * n)
    wide_torque = rng.uniform(-1500, 1500, 2 * n)
    angle, torque = wide_angle[::2], wide_torque[::2]  # strided views
    reference = comp.apply(angle.copy(), torque.copy())
    np.testing.assert_array_equal(comp.apply(angle, torque), reference)
    np.testing.assert_array_equal(comp.apply(angle.astype(">f8"), torque.astype(">f8")), reference)  # big-endian
    np.testing.assert_array_equal(comp.apply(angle.reshape(-1, 1), torque.reshape(-1, 1)).ravel(), reference)
    single = angle.astype(np.float32)  # read as the float64 of each float32 value
    np.testing.assert_array_equal(comp.apply(single, torque), comp.apply(single.astype(float), torque))
    unaligned = np.frombuffer(b"\0" * 4 + angle.tobytes(), dtype=np.float64, offset=4)
    assert not unaligned.flags.aligned
    np.testing.assert_array_equal(comp.apply(unaligned, torque), reference)
    with pytest.raises(ValueError, match="aligned"):
        comp.apply(angle.copy(), torque, out=np.frombuffer(bytearray(8 * n + 4), dtype=np.float64, offset=4))


def test_an_output_that_is_the_torque_or_overlaps_it_reads_the_torque_first():
    comp = full_compensator()
    rng = np.random.default_rng(23)
    n = 2 * BLOCK_SAMPLES + 9
    angle = rng.uniform(-REVOLUTION, REVOLUTION, n)
    torque = rng.uniform(-1500, 1500, n + 1)
    expected = comp.apply(angle, torque[1:])
    same = torque[1:].copy()
    comp.apply(angle, same, out=same)
    np.testing.assert_array_equal(same, expected)
    comp.apply(angle, torque[1:], out=torque[:-1])  # out one sample before the torque it reads
    np.testing.assert_array_equal(torque[:-1], expected)


@pytest.mark.parametrize("offset_in_group", [0, 1, 2, 3])
def test_a_sample_out_of_the_domain_gives_nan_in_its_lane_only(offset_in_group):
    # in a group of four computed together, and in a block that is otherwise folded
    comp = full_compensator()
    n = 2 * BLOCK_SAMPLES + 3
    angle = np.linspace(-100.0, 100.0, n)
    torque = np.linspace(-500.0, 500.0, n)
    clean = comp.apply(angle, torque)
    for bad in (np.nan, np.inf, -np.inf, np.nextafter(MAX_ABS_ANGLE_ARCSEC, np.inf), -1e300):
        for first in (4 * 10, BLOCK_SAMPLES + 4 * 7, n - 3):  # a vector group, another block, the left-over tail
            at = min(first + offset_in_group, n - 1)
            damaged = angle.copy()
            damaged[at] = bad
            result = comp.apply(damaged, torque)
            assert np.flatnonzero(np.isnan(result)).tolist() == [at]
            keep = np.arange(n) != at
            np.testing.assert_allclose(result[keep], clean[keep], rtol=0, atol=1e-9)
    at_the_limit = np.full(5, MAX_ABS_ANGLE_ARCSEC)
    assert np.all(np.isfinite(comp.apply(at_the_limit, 0.0)))
