"""The compiled compensation kernel: one pass over a batch, reading each input once and writing the result once.

For every sample the kernel computes, in arcsec,

    θ_c = gain·θ − offset − c_T·T − short(θ) − long(θ)

θ raw encoder reading (arcsec), T torque (N·m), gain = 1 − Σ scale coefficients, c_T = Σ torsion coefficients
(″/N·m), offset = Σ constant errors (arcsec). ``short`` and ``long`` are sums of angle-only periodic error terms
(see ``compensator``), each tabulated over its own period by :func:`tabulate`:

* **Table lookup.** A :class:`PeriodicTable` holds, at the grid points x_j = j·step over one period, the value
  f(x_j) and the change of f over one step around x_j. A lookup returns the tangent at the nearest grid point,
  f(x_j) + slope_j·(θ − x_j); the grid is fine enough that this is within a stated error of f everywhere
  (measured when the table is built). For the usual terms the tables are a few KiB: they stay in the CPU's L1
  cache beside the data streams.
* **Periodic index without a branch.** Adding 1.5·2^52 to x = θ/step rounds x to the nearest integer and leaves
  that integer in the low bits of the sum's bit pattern; masking them with n − 1 (n, the table size, is a power
  of two) gives the grid index modulo the period. Every input — negative, huge, NaN, ±inf — gives an index
  inside the table, so the lookup needs no range check and no float → integer conversion.
* **Long periods are folded per block.** The long-period table (errors that repeat once or a few times per
  revolution, e.g. eccentricity) has grid steps of hundreds of arcsec. The batch is processed in blocks of
  ``BLOCK_SAMPLES``; when every sample of a block lies in the same grid cell, that cell's tangent is linear in
  θ and is folded into the block's gain and offset, so the long-period terms cost nothing per sample — with the
  same result as the per-sample lookup. Blocks that span cells (or hold NaN) look the table up per sample.
* **Domain.** A reading that is not finite or has |θ| > ``MAX_ABS_ANGLE_ARCSEC`` (2^40″, about 850 000
  revolutions) gives NaN for that sample and only that sample; nothing raises. Non-finite torque gives a
  non-finite result through the arithmetic when the chain uses torque (``arcsec_per_nm`` ≠ 0).

The kernel is compiled with numba (``cache=True``: compiled once per machine and argument types, then loaded from
the cache). Its variants — with or without a short-period and a long-period table — are separate specialisations;
:func:`compile_variant` compiles (or loads) one ahead of the first batch.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import NamedTuple

import numba
import numpy as np

BLOCK_SAMPLES = 512  # samples per block: the block's inputs stay in L1 while it is checked and computed
MAX_ABS_ANGLE_ARCSEC = 2.0**40
MIN_TABLE_POINTS = 16
MAX_TABLE_POINTS = 1 << 20
_ROUNDING_SHIFT = 1.5 * 2.0**52  # x + this = 1.5·2^52 + round(x), exactly, for |x| < 2^51
_MAX_POINTS_PER_ARCSEC = 2.0**51 / MAX_ABS_ANGLE_ARCSEC  # so that |θ/step| < 2^51 for every θ in the domain
_VERIFY_POINTS_PER_CELL = 9  # the tangent's error is measured at 9 points across each cell, both edges included

# compiled once per machine and argument types, then loaded from numba's cache; no GIL held while it runs; no
# bounds checks (every index is masked into its table); fused multiply-add allowed, nothing else of fast-math
# (NaN and ±inf must propagate, and x + 1.5·2^52 − 1.5·2^52 must not be simplified away)
_KERNEL = numba.njit(cache=True, nogil=True, boundscheck=False, fastmath={"contract"})


class PeriodicTable(NamedTuple):
    """A periodic function of the angle, tabulated for tangent lookup over one period.

    values_arcsec[j]: f(x_j) at x_j = j / points_per_arcsec, j = 0 … n − 1 (n a power of two);
    steps_arcsec[j]: f(x_j + step/2) − f(x_j − step/2), the change of f over one grid step around x_j;
    points_per_arcsec: n / period (1/step); index_mask: n − 1;
    max_error_arcsec: the largest |tangent − f| measured when the table was built.
    """

    values_arcsec: np.ndarray
    steps_arcsec: np.ndarray
    points_per_arcsec: float
    index_mask: np.uint64
    max_error_arcsec: float

    @property
    def size(self) -> int:
        return self.values_arcsec.size

    @property
    def period_arcsec(self) -> float:
        return self.size / self.points_per_arcsec

    @property
    def step_arcsec(self) -> float:
        return 1.0 / self.points_per_arcsec


def tabulate(
    function: Callable[[np.ndarray], np.ndarray],
    period_arcsec: float,
    max_error_arcsec: float,
    *,
    max_points: int = MAX_TABLE_POINTS,
) -> PeriodicTable | None:
    """The smallest power-of-two table of ``function`` (arcsec → arcsec, periodic in ``period_arcsec``) whose
    tangent lookup stays within ``max_error_arcsec`` of the function, measured at 9 points across every cell
    (the error of a tangent peaks at the cell edges, which are among them). None if ``max_points`` are not
    enough, or the step would be below 1/2048″ (the caller evaluates the function directly instead)."""
    if not (period_arcsec > 0 and math.isfinite(period_arcsec)):
        raise ValueError(f"period must be a positive number of arcsec, got {period_arcsec}")
    if not max_error_arcsec > 0:
        raise ValueError("max_error_arcsec must be > 0")
    offsets_in_steps = np.linspace(-0.5, 0.5, _VERIFY_POINTS_PER_CELL)
    size = MIN_TABLE_POINTS
    while size <= max_points and size / period_arcsec <= _MAX_POINTS_PER_ARCSEC:
        step = period_arcsec / size
        grid = np.arange(size) * step
        values = np.asarray(function(grid), dtype=float)
        steps = np.asarray(function(grid + step / 2), dtype=float) - np.asarray(function(grid - step / 2), dtype=float)
        probe = grid[:, None] + offsets_in_steps[None, :] * step
        tangent = values[:, None] + steps[:, None] * offsets_in_steps[None, :]
        error = float(np.max(np.abs(np.asarray(function(probe.ravel()), dtype=float).reshape(probe.shape) - tangent)))
        if not math.isfinite(error):
            return None
        if error <= max_error_arcsec:
            for array in (values, steps):
                array.flags.writeable = False
            return PeriodicTable(values, steps, size / period_arcsec, np.uint64(size - 1), error)
        # the tangent's error falls with the square of the step: jump close to the size that meets the limit
        size *= max(2, 1 << math.ceil(math.log2(math.sqrt(error / max_error_arcsec))))
    return None


@numba.njit(inline="always")
def _tangent_lookup(table: PeriodicTable, angle_arcsec: float) -> float:
    """The table's tangent at the grid point nearest to ``angle_arcsec`` (see the module docstring)."""
    x = angle_arcsec * table.points_per_arcsec  # position in grid steps
    shifted = x + _ROUNDING_SHIFT
    index = np.float64(shifted).view(np.uint64) & table.index_mask
    steps_from_grid_point = x - (shifted - _ROUNDING_SHIFT)  # x − round(x), in [−½, ½]
    return table.values_arcsec[index] + steps_from_grid_point * table.steps_arcsec[index]


@_KERNEL
def _compensate_block(angle, torque, out, gain, arcsec_per_nm, offset_arcsec, short_table, long_table, in_domain):
    """out[i] ← gain·θ − offset − c_T·T − tables, for one block (a table given as None is compiled out);
    ``in_domain``: every |θ| ≤ MAX_ABS_ANGLE_ARCSEC, else the samples outside are set to NaN."""
    for i in range(angle.size):
        theta = angle[i]
        result = gain * theta - offset_arcsec - arcsec_per_nm * torque[i]
        if short_table is not None:
            result -= _tangent_lookup(short_table, theta)
        if long_table is not None:
            result -= _tangent_lookup(long_table, theta)
        if not (in_domain or abs(theta) <= MAX_ABS_ANGLE_ARCSEC):
            result = np.nan
        out[i] = result


@_KERNEL
def _all_in_domain(angle) -> bool:
    """Every |θ| ≤ MAX_ABS_ANGLE_ARCSEC (False for NaN and ±inf)."""
    inside = True
    for i in range(angle.size):
        inside &= abs(angle[i]) <= MAX_ABS_ANGLE_ARCSEC
    return inside


@_KERNEL
def _common_grid_point(angle, table) -> tuple[bool, float]:
    """(True, j) if every sample of the block rounds to the same grid point j of ``table`` (|θ/step − j| ≤ ½;
    then every |θ| is also below MAX_ABS_ANGLE_ARCSEC), else (False, 0). NaN or ±inf in the block gives False."""
    centre = np.rint(angle[0] * table.points_per_arcsec)
    inside = abs(centre) <= MAX_ABS_ANGLE_ARCSEC * table.points_per_arcsec - 1.0
    for i in range(angle.size):
        inside &= abs(angle[i] * table.points_per_arcsec - centre) <= 0.5
    return inside, centre if inside else 0.0


@_KERNEL
def compensate(angle, torque, out, gain, arcsec_per_nm, offset_arcsec, short_table, long_table) -> None:
    """out ← gain·angle − offset − arcsec_per_nm·torque − short(angle) − long(angle), sample by sample.

    angle, torque, out: float64 C-contiguous 1-d arrays of one length (out may be angle itself; with no torque
    array, pass angle as torque and arcsec_per_nm = 0: it is read from the same cache lines and adds 0);
    short_table, long_table: PeriodicTable or None.
    """
    for start in range(0, angle.size, BLOCK_SAMPLES):
        stop = min(start + BLOCK_SAMPLES, angle.size)
        block, block_torque, block_out = angle[start:stop], torque[start:stop], out[start:stop]
        if long_table is not None:
            one_cell, centre = _common_grid_point(block, long_table)
            if one_cell:
                # the tangent at grid point j, value_j + slope_j·(θ·points_per_arcsec − j), is linear in θ:
                # fold it into the block's gain and offset
                index = np.uint64(np.int64(centre)) & long_table.index_mask
                slope_per_step = long_table.steps_arcsec[index]
                block_gain = gain - slope_per_step * long_table.points_per_arcsec
                block_offset = offset_arcsec + long_table.values_arcsec[index] - slope_per_step * centre
                _compensate_block(
                    block, block_torque, block_out, block_gain, arcsec_per_nm, block_offset, short_table, None, True
                )
                continue
        _compensate_block(
            block, block_torque, block_out, gain, arcsec_per_nm, offset_arcsec, short_table, long_table,
            _all_in_domain(block),
        )


def compile_variant(short_table: PeriodicTable | None, long_table: PeriodicTable | None) -> None:
    """Compile (or load from numba's cache) the kernel variant for these tables, so that the first real batch
    does not wait for the compiler."""
    one = np.zeros(1)
    compensate(one, one, np.empty(1), 1.0, 0.0, 0.0, short_table, long_table)
