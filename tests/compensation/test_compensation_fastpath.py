"""The chunked fast path of Compensator.apply: guard cells, slow-path fallback, chunk boundaries, errstate."""

import numpy as np
import pytest

from tcms_daq.compensation import Compensator, Eccentricity, Offset, Periodic, Scale, Torsion
from tcms_daq.compensation import compensator as compensator_module
from tcms_daq.compensation.compensator import CHUNK, _AngleTable


def full_compensator() -> Compensator:
    return Compensator(
        [
            Scale(-0.19),
            Torsion(0.004),
            Offset(1.5),
            Eccentricity(eccentricity_mm=0.005, radius_mm=30.0, phase_rad=0.7),
            Periodic(72.0, 0.35, -0.12),
            Periodic(36.0, 0.08, 0.05),
        ]
    )


def _index(table: _AngleTable, theta: np.ndarray) -> np.ndarray:
    """The fast path's table index (before np.take clips it)."""
    u = np.asarray(theta, dtype=float) + table.add_const
    return u.view(np.int64) - table.bits_offset


def test_every_angle_outside_the_table_lands_on_a_guard_cell():
    comp = full_compensator()
    table = _AngleTable(comp._tabulable, 0.0, comp._table_h, -300.0, 250.0)
    inside = np.linspace(table.lo, table.hi, 10_001)
    idx = _index(table, inside)
    assert idx.min() >= 1 and idx.max() <= table.size - 2
    outside = np.array(
        [table.lo - 2 * table.h, table.hi + 2 * table.h, -1e6, 1e6, -1e12, 1e12, -1e300, 1e300,
         np.nan, -np.nan, np.inf, -np.inf]
    )
    with np.errstate(invalid="ignore"):
        clipped = np.clip(_index(table, outside), 0, table.size - 1)
    assert set(clipped.tolist()) <= {0, table.size - 1}
    # the guard cells hold a signalling NaN (quiet bit clear), which np.take copies bit for bit
    bits = table.values.view(np.uint64)
    assert bits[0] == bits[-1] == 0x7FF0000000000001
    assert np.isnan(table.values[[0, -1]]).all()
    with np.errstate(invalid="raise"), pytest.raises(FloatingPointError):
        np.add(np.take(table.values, [0, 5]), 1.0)


def test_misses_mid_batch_are_redone_exactly():
    # table built on a narrow range, then a multi-chunk batch that leaves it in the middle of a chunk and
    # contains NaN and ±inf: every chunk matches the exact path (NaN where the exact path gives NaN)
    comp = full_compensator()
    comp.apply(np.linspace(-10, 10, 1000), 0.0)
    first = comp._table
    rng = np.random.default_rng(7)
    n = 2 * CHUNK + CHUNK // 2 + 17
    angle = rng.uniform(-5, 5, n)
    angle[CHUNK + 123] = 4000.0  # outside the table: the chunk must be redone after extending it
    angle[CHUNK + 124] = -4000.0
    angle[2 * CHUNK + 5] = np.nan
    angle[2 * CHUNK + 6] = np.inf
    angle[2 * CHUNK + 7] = -np.inf
    torque = rng.uniform(-1000, 1000, n)
    with np.errstate(invalid="ignore"):
        fast = comp.apply(angle, torque)
        exact = comp.apply(angle, torque, exact=True)
    assert comp._table is not first and comp._table.hi >= 4000.0
    np.testing.assert_array_equal(np.isnan(fast), np.isnan(exact))
    ok = ~np.isnan(exact)
    assert np.max(np.abs(fast[ok] - exact[ok])) <= comp.tolerance_arcsec / 2 + 1e-9
    assert np.isnan(exact[2 * CHUNK + 5 : 2 * CHUNK + 8]).all()


def test_table_is_kept_while_data_stay_in_range():
    comp = full_compensator()
    x = np.linspace(-200, 200, 3 * CHUNK)
    comp.apply(x, 0.0)
    table = comp._table
    comp.apply(x[::-1] * 0.5, np.ones_like(x))
    assert comp._table is table


def test_callers_errstate_is_respected_and_restored():
    comp = full_compensator()
    x = np.linspace(-100, 100, 5000)
    before = np.geterr()
    with np.errstate(all="raise"):
        out = comp.apply(x, x)  # finite data: nothing to raise
        with pytest.raises(FloatingPointError):
            comp.apply(np.array([1.0, np.inf]), 0.0)  # sin(inf) in the direct evaluation: the caller asked to raise
    assert np.geterr() == before
    with np.errstate(invalid="ignore"):
        res = comp.apply(np.array([1.0, np.inf]), 0.0)
    assert np.isnan(res[1]) and np.isfinite(res[0])
    assert np.max(np.abs(out - comp.apply(x, x, exact=True))) <= comp.tolerance_arcsec / 2 + 1e-9


@pytest.mark.parametrize(
    "terms",
    [
        [Scale(0.03), Torsion(0.004), Offset(2.0)],  # linear only: no table
        [Torsion(0.004)],  # gain 1, no table, no offset
        [Offset(-1.0), Periodic(72.0, 0.3, 0.1)],  # gain 1, no torque term
        [Scale(-0.19), Eccentricity(eccentricity_mm=0.01, radius_mm=30.0)],
    ],
)
@pytest.mark.parametrize("scalar_torque", [False, True])
def test_variants_match_the_terms_one_by_one(terms, scalar_torque):
    comp = Compensator(terms)
    rng = np.random.default_rng(1)
    n = CHUNK + 999
    angle = rng.uniform(-300, 300, n)
    torque = 750.0 if scalar_torque else rng.uniform(-1500, 1500, n)
    by_hand = angle - sum(t.evaluate(angle, torque, None) for t in terms)
    tol = comp.tolerance_arcsec / 2 + 1e-9
    assert np.max(np.abs(comp.apply(angle, torque) - by_hand)) <= tol
    np.testing.assert_allclose(comp.apply(angle, torque, exact=True), by_hand, atol=1e-9)
    # in place, across chunk boundaries
    buf = angle.copy()
    comp.apply(buf, torque, out=buf)
    np.testing.assert_array_equal(buf, comp.apply(angle, torque))


def test_chunk_size_does_not_change_the_result(monkeypatch):
    comp = full_compensator()
    rng = np.random.default_rng(2)
    angle = rng.uniform(-250, 250, 50_000)
    torque = rng.uniform(-1000, 1000, 50_000)
    ref = comp.apply(angle, torque)
    monkeypatch.setattr(compensator_module, "CHUNK", 4096 + 3)
    np.testing.assert_array_equal(comp.apply(angle, torque), ref)
