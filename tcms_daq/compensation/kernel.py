"""The compiled compensation kernel: one pass over a batch, reading each input once and writing the result once.

For every sample the kernel computes, in arcsec,

    θ_c = gain·θ − offset − c_T·T − short(θ) − long(θ)

θ raw encoder reading (arcsec), T torque (N·m), gain = 1 − Σ scale coefficients, c_T = Σ torsion coefficients
(″/N·m), offset = Σ constant errors (arcsec). ``short`` and ``long`` are sums of angle-only periodic error terms
(see ``compensator``), each tabulated over its own period by :func:`tabulate`:

* **Table lookup.** A :class:`PeriodicTable` holds, at the grid points x_j = j·step over one period, the value
  f(x_j) and the change of f over one step around x_j, side by side (one 16-byte load per lookup). A lookup
  returns the tangent at the nearest grid point, f(x_j) + slope_j·(θ − x_j); the grid is fine enough that this
  is within a stated error of f everywhere (measured when the table is built). For the usual terms the tables
  are a few KiB: they stay in the CPU's L1 cache beside the data streams.
* **Periodic index without a branch.** Adding 1.5·2^52 to x = θ/step rounds x to the nearest integer and leaves
  that integer in the low bits of the sum's bit pattern; masking them with n − 1 (n, the table size, is a power
  of two) gives the grid index modulo the period. Every input — negative, huge, NaN, ±inf — gives an index
  inside the table, so the lookup needs no range check and no float → integer conversion.
* **Long periods are folded per block.** The long-period table (errors that repeat once or a few times per
  revolution, e.g. eccentricity) has grid steps of hundreds of arcsec. The batch is processed in blocks of
  ``BLOCK_SAMPLES``; a block is computed with the tangent at the grid point of its first sample folded into
  its gain and offset (that tangent is linear in θ), and the same pass checks that every sample rounds to that
  grid point (their rounded bit patterns are compared). If one does not — the block crosses a cell edge, or
  holds NaN, ±inf or a reading out of the domain — the block is computed again with the table looked up per
  sample. The two agree to the rounding of the arithmetic (a few units in the last place of θ: below 1e-9″
  within ±1000 revolutions), so folding changes the cost, not the result.
* **Four samples at a time.** The pass over a block is emitted as LLVM IR on vectors of four float64 (numba
  intrinsics built with llvmlite): LLVM does not vectorise a loop with table lookups well by itself — it cannot
  tell that the output does not overwrite the tables, and where the CPU has no fast gather it recomputes every
  lane's index in scalar code (13 instructions per sample where 7 do). Here each lane's table entry is one
  scalar 16-byte load, declared not to alias the data streams (scoped no-alias metadata); LLVM's code generator
  still chooses the instructions for the CPU at hand. The samples left over (fewer than four per block) go
  through the same code on one lane.
* **Streaming stores.** When the output is large (at least ``STREAMING_MIN_BYTES``) and is not one of the
  inputs, the vector stores are non-temporal, as ``memcpy`` does for large copies: the output's cache lines are
  not read before they are written and do not push the inputs out of the cache. The first block is shortened
  so that every vector store is 32-byte aligned; a memory fence ends the call (non-temporal stores are weakly
  ordered). An output that is an input is written through a block buffer: a block computed again reads its
  inputs unchanged.
* **Domain.** A reading that is not finite or has |θ| > ``MAX_ABS_ANGLE_ARCSEC`` (2^40″, about 850 000
  revolutions) gives NaN for that sample and only that sample; nothing raises. Non-finite torque gives a
  non-finite result through the arithmetic when the chain uses torque (``arcsec_per_nm`` ≠ 0).

The kernel is compiled with numba (``cache=True``: compiled once per machine and argument types, then loaded from
the cache). Its variants — with or without a short-period and a long-period table — are separate specialisations;
:func:`compile_variant` compiles (or loads) one ahead of the first batch. Everything compiled lives in this one
module: numba's cache is invalidated by a change of the file that defines a cached function, not of the files
it calls into.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any, NamedTuple

import numba
import numpy as np
from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic

BLOCK_SAMPLES = 512  # samples per block: the block's inputs stay in L1 while it is computed (and again if needed)
LANES = 4  # float64 samples per vector: 256-bit registers (AVX); narrower CPUs split them in the code generator
STREAMING_MIN_BYTES = 8 << 20  # outputs from 8 MiB on (1 M samples) are written with non-temporal stores
MAX_ABS_ANGLE_ARCSEC = 2.0**40
MIN_TABLE_POINTS = 16
MAX_TABLE_POINTS = 1 << 20
_ROUNDING_SHIFT = 1.5 * 2.0**52  # x + this = 1.5·2^52 + round(x), exactly, for |x| < 2^51
_MAX_POINTS_PER_ARCSEC = 2.0**51 / MAX_ABS_ANGLE_ARCSEC  # so that |θ/step| < 2^51 for every θ in the domain
_VERIFY_POINTS_PER_CELL = 9  # the tangent's error is measured at 9 points across each cell, both edges included
_VECTOR_ALIGN_BYTES = 32  # a non-temporal vector store needs its address aligned to the vector's size
_CACHE_LINE_BYTES = 64

# compiled once per machine and argument types, then loaded from numba's cache; no GIL held while it runs; no
# bounds checks (every index is masked into its table); fused multiply-add allowed, nothing else of fast-math
# (NaN and ±inf must propagate, and x + 1.5·2^52 − 1.5·2^52 must not be simplified away)
_KERNEL = numba.njit(cache=True, nogil=True, boundscheck=False, fastmath={"contract"})


class PeriodicTable(NamedTuple):
    """A periodic function of the angle, tabulated for tangent lookup over one period.

    value_and_step_arcsec[j] = (f(x_j), f(x_j + step/2) − f(x_j − step/2)) at x_j = j / points_per_arcsec,
    j = 0 … n − 1 (n a power of two): the value and its change over one grid step around x_j;
    points_per_arcsec: n / period (1/step); index_mask: n − 1;
    max_error_arcsec: the largest |tangent − f| measured when the table was built.
    """

    value_and_step_arcsec: np.ndarray
    points_per_arcsec: float
    index_mask: np.uint64
    max_error_arcsec: float

    @property
    def values_arcsec(self) -> np.ndarray:
        return self.value_and_step_arcsec[:, 0]

    @property
    def steps_arcsec(self) -> np.ndarray:
        return self.value_and_step_arcsec[:, 1]

    @property
    def size(self) -> int:
        return len(self.value_and_step_arcsec)

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
            value_and_step = np.stack([values, steps], axis=1)
            value_and_step.flags.writeable = False
            return PeriodicTable(value_and_step, size / period_arcsec, np.uint64(size - 1), error)
        # the tangent's error falls with the square of the step: jump close to the size that meets the limit
        size *= max(2, 1 << math.ceil(math.log2(math.sqrt(error / max_error_arcsec))))
    return None


# ---- the pass over a block, as LLVM IR on vectors of float64 -------------------------------------------------

_F64 = ir.DoubleType()
_I64 = ir.IntType(64)
_I32 = ir.IntType(32)
_BYTE_POINTER = ir.IntType(8).as_pointer()
_CONTRACT = ("contract",)  # the one fast-math flag: a multiply and an add may fuse
_PAIR_BYTES_LOG2 = 4  # a table entry (value, step) is 16 bytes


class _Lanes:
    """Vector arithmetic on ``count`` float64 lanes for one emitted pass (an llvmlite IRBuilder underneath)."""

    def __init__(self, builder: ir.IRBuilder, count: int):
        self.builder = builder
        self.count = count
        self.f64 = ir.VectorType(_F64, count)
        self.i64 = ir.VectorType(_I64, count)
        module = builder.module
        # the tables are read through pointers LLVM cannot tell apart from the output's: the table loads belong
        # to one alias scope, the data stream accesses are declared not to alias it
        domain = module.add_metadata([ir.MetaDataString(module, "tcms_daq.compensation.kernel")])
        scope = module.add_metadata([ir.MetaDataString(module, "periodic tables"), domain])
        self.table_scope = module.add_metadata([scope])
        self.nontemporal = module.add_metadata([_I32(1)])

    def splat(self, scalar: ir.Value | float | int, vector_type: ir.VectorType | None = None) -> ir.Value:
        """A vector with ``scalar`` in every lane."""
        vector_type = vector_type or self.f64
        if not isinstance(scalar, ir.Value):
            scalar = ir.Constant(vector_type.element, scalar)
        one = self.builder.insert_element(ir.Constant(vector_type, ir.Undefined), scalar, _I32(0))
        return self.builder.shuffle_vector(one, ir.Constant(vector_type, ir.Undefined), self._lanes([0] * self.count))

    def _lanes(self, indices: list[int]) -> ir.Constant:
        return ir.Constant(ir.VectorType(_I32, len(indices)), indices)

    def mul(self, a: ir.Value, b: ir.Value) -> ir.Value:
        return self.builder.fmul(a, b, flags=_CONTRACT)

    def add(self, a: ir.Value, b: ir.Value) -> ir.Value:
        return self.builder.fadd(a, b, flags=_CONTRACT)

    def sub(self, a: ir.Value, b: ir.Value) -> ir.Value:
        return self.builder.fsub(a, b, flags=_CONTRACT)

    def load(self, data: ir.Value, index: ir.Value) -> ir.Value:
        """``count`` samples of a data stream (a float64 pointer) from ``index`` on."""
        pointer = self.builder.bitcast(self.builder.gep(data, [index]), self.f64.as_pointer())
        value = self.builder.load(pointer, align=8)
        value.set_metadata("noalias", self.table_scope)
        return value

    def store(self, value: ir.Value, data: ir.Value, index: ir.Value, streaming: bool) -> None:
        """Store ``count`` samples at ``data[index]``; ``streaming``: a non-temporal store (the caller guarantees
        the address is aligned to the vector's size)."""
        pointer = self.builder.bitcast(self.builder.gep(data, [index]), self.f64.as_pointer())
        store = self.builder.store(value, pointer, align=_VECTOR_ALIGN_BYTES if streaming else 8)
        store.set_metadata("noalias", self.table_scope)
        if streaming:
            store.set_metadata("nontemporal", self.nontemporal)

    def grid_point_bits(self, theta: ir.Value, points_per_arcsec: ir.Value) -> ir.Value:
        """The bit patterns of θ·points_per_arcsec + 1.5·2^52: the nearest grid point in the low bits."""
        return self.builder.bitcast(self.add(self.mul(theta, points_per_arcsec), self.splat(_ROUNDING_SHIFT)), self.i64)

    def tangent(self, table: _TableParts, theta: ir.Value) -> ir.Value:
        """The table's tangent at the grid point nearest to each lane's θ (see the module docstring)."""
        b = self.builder
        x = self.mul(theta, table.points_per_arcsec)  # position in grid steps
        shifted = self.add(x, self.splat(_ROUNDING_SHIFT))
        index = b.and_(b.bitcast(shifted, self.i64), table.index_mask)
        steps_from_grid_point = self.sub(x, self.sub(shifted, self.splat(_ROUNDING_SHIFT)))  # x − round(x)
        byte_offsets = b.shl(index, self.splat(_PAIR_BYTES_LOG2, self.i64))
        pairs = []
        for lane in range(self.count):
            entry = b.gep(table.entries, [b.extract_element(byte_offsets, _I32(lane))])
            pair = b.load(b.bitcast(entry, ir.VectorType(_F64, 2).as_pointer()), align=8)
            pair.set_metadata("alias.scope", self.table_scope)
            pairs.append(pair)
        while len(pairs) > 1:  # (v0, s0, v1, s1, …): concatenate the lanes' pairs
            pairs = [b.shuffle_vector(first, second, self._lanes(list(range(2 * first.type.count))))
                     for first, second in zip(pairs[::2], pairs[1::2], strict=True)]
        both = pairs[0]
        values = b.shuffle_vector(both, both, self._lanes(list(range(0, 2 * self.count, 2))))
        slopes = b.shuffle_vector(both, both, self._lanes(list(range(1, 2 * self.count, 2))))
        return self.add(values, self.mul(steps_from_grid_point, slopes))


class _TableParts(NamedTuple):
    """A PeriodicTable argument as the emitted pass uses it: the entries' address and the lookup constants."""

    entries: ir.Value  # byte pointer to value_and_step_arcsec[0, 0]
    points_per_arcsec: ir.Value  # splat over the lanes
    index_mask: ir.Value  # splat over the lanes


def _table_parts(context: Any, lanes: _Lanes, table_type: Any, table: ir.Value) -> _TableParts | None:
    """The parts of a PeriodicTable argument (numba type ``table_type``), or None for a None argument."""
    if isinstance(table_type, types.NoneType):
        return None
    b = lanes.builder
    fields = list(table_type.fields)

    def field(name: str) -> ir.Value:
        return b.extract_value(table, fields.index(name))

    array_type = table_type.types[fields.index("value_and_step_arcsec")]
    entries = context.make_array(array_type)(context, b, value=field("value_and_step_arcsec")).data
    return _TableParts(
        b.bitcast(entries, _BYTE_POINTER),
        lanes.splat(field("points_per_arcsec")),
        lanes.splat(field("index_mask"), lanes.i64),
    )


def _is_sample_array(array_type: Any) -> bool:
    """A 1-d C-contiguous float64 array: what the pass reads and writes as consecutive vectors."""
    return (isinstance(array_type, types.Array) and array_type.ndim == 1 and array_type.layout == "C"
            and array_type.dtype == types.float64)


def _data_pointer(context: Any, builder: ir.IRBuilder, array_type: types.Array, array: ir.Value) -> ir.Value:
    return context.make_array(array_type)(context, builder, value=array).data


def _block_pass(lane_count: int, streaming: bool) -> Callable[..., bool]:
    """An intrinsic computing samples ``start`` … ``stop`` − 1 (a multiple of ``lane_count`` of them), ``lane_count``
    at a time:

        out[i + out_shift] ← gain·θ − offset − c_T·T − short(θ) − long(θ),   θ = angle[i], T = torque[i]

    short_table, long_table: PeriodicTable or None (no such term). fold_grid_point: None, or the long table's grid
    point the caller folded into gain and offset: then the long table is not looked up, and the pass returns
    whether every θ rounds to that grid point (True without a fold). Without a fold, θ out of the domain gives
    NaN. ``streaming``: non-temporal stores, out[start + out_shift] aligned to the vector's size."""

    def typer(typingctx: Any, angle: Any, torque: Any, out: Any, out_shift: Any, start: Any, stop: Any, gain: Any,
              arcsec_per_nm: Any, offset_arcsec: Any, short_table: Any, long_table: Any, fold_grid_point: Any) -> Any:
        if not all(_is_sample_array(array) for array in (angle, torque, out)):
            return None  # numba reports the call as not typeable
        signature = types.boolean(angle, torque, out, out_shift, start, stop, gain, arcsec_per_nm, offset_arcsec,
                                  short_table, long_table, fold_grid_point)

        def codegen(context: Any, builder: ir.IRBuilder, sig: Any, args: Any) -> ir.Value:
            (angle_v, torque_v, out_v, out_shift_v, start_v, stop_v, gain_v, arcsec_per_nm_v, offset_v,
             short_v, long_v, fold_v) = args
            lanes = _Lanes(builder, lane_count)
            angle_data = _data_pointer(context, builder, sig.args[0], angle_v)
            torque_data = _data_pointer(context, builder, sig.args[1], torque_v)
            out_data = _data_pointer(context, builder, sig.args[2], out_v)
            gain_l, arcsec_per_nm_l, offset_l = lanes.splat(gain_v), lanes.splat(arcsec_per_nm_v), lanes.splat(offset_v)
            short = _table_parts(context, lanes, sig.args[9], short_v)
            long = _table_parts(context, lanes, sig.args[10], long_v)
            folded = not isinstance(sig.args[11], types.NoneType)
            if folded:
                assert long is not None, "a fold needs the long table"
                fold_bits = builder.bitcast(lanes.add(lanes.splat(fold_v), lanes.splat(_ROUNDING_SHIFT)), lanes.i64)
            no_sample_elsewhere = ir.Constant(lanes.i64, [0] * lane_count)

            entry = builder.block
            loop = builder.append_basic_block("lanes.loop")
            done = builder.append_basic_block("lanes.done")
            builder.cbranch(builder.icmp_signed("<", start_v, stop_v), loop, done)
            builder.position_at_end(loop)
            i = builder.phi(_I64)
            elsewhere = builder.phi(lanes.i64)  # OR of (sample's grid point bits ^ fold grid point bits)
            theta = lanes.load(angle_data, i)
            result = lanes.sub(lanes.mul(gain_l, theta), offset_l)
            result = lanes.sub(result, lanes.mul(arcsec_per_nm_l, lanes.load(torque_data, i)))
            if short is not None:
                result = lanes.sub(result, lanes.tangent(short, theta))
            if folded:
                assert long is not None
                sample_bits = lanes.grid_point_bits(theta, long.points_per_arcsec)
                next_elsewhere = builder.or_(elsewhere, builder.xor(sample_bits, fold_bits))
            else:
                next_elsewhere = elsewhere
                if long is not None:
                    result = lanes.sub(result, lanes.tangent(long, theta))
                fabs = cgutils.get_or_insert_function(
                    builder.module, ir.FunctionType(lanes.f64, [lanes.f64]), f"llvm.fabs.v{lane_count}f64"
                )
                in_domain = builder.fcmp_ordered("<=", builder.call(fabs, [theta]), lanes.splat(MAX_ABS_ANGLE_ARCSEC))
                result = builder.select(in_domain, result, lanes.splat(math.nan))
            lanes.store(result, out_data, builder.add(i, out_shift_v), streaming)
            next_i = builder.add(i, _I64(lane_count))
            i.add_incoming(start_v, entry)
            i.add_incoming(next_i, loop)
            elsewhere.add_incoming(no_sample_elsewhere, entry)
            elsewhere.add_incoming(next_elsewhere, loop)
            builder.cbranch(builder.icmp_signed("<", next_i, stop_v), loop, done)

            builder.position_at_end(done)
            final = builder.phi(lanes.i64)
            final.add_incoming(no_sample_elsewhere, entry)
            final.add_incoming(next_elsewhere, loop)
            reduce_or = cgutils.get_or_insert_function(
                builder.module, ir.FunctionType(_I64, [lanes.i64]), f"llvm.vector.reduce.or.v{lane_count}i64"
            )
            return builder.icmp_unsigned("==", builder.call(reduce_or, [final]), _I64(0))

        return signature, codegen

    typer.__name__ = f"block_pass_{lane_count}{'_streaming' if streaming else ''}"
    compiled: Callable[..., bool] = intrinsic(typer)
    return compiled


_vector_pass = _block_pass(LANES, streaming=False)
_vector_pass_streaming = _block_pass(LANES, streaming=True)
_sample_pass = _block_pass(1, streaming=False)


def _memory_fence_typer(typingctx: Any) -> Any:
    def codegen(context: Any, builder: ir.IRBuilder, sig: Any, args: Any) -> ir.Value:
        builder.fence("seq_cst")
        return context.get_dummy_value()

    return types.void(), codegen


# a full memory fence: the non-temporal stores before it are visible to every thread after it
_memory_fence: Callable[..., None] = intrinsic(_memory_fence_typer)


# ---- the driver: blocks, folding, streaming ----------------------------------------------------------------


@_KERNEL
def _compensate_block(angle, torque, out, out_shift, start, stop, gain, arcsec_per_nm, offset_arcsec,
                      short_table, long_table, streaming) -> None:
    """out[i + out_shift] for i in start … stop − 1: folded (see the module docstring) when the block allows it,
    else with both tables looked up per sample. ``streaming``: non-temporal vector stores (aligned)."""
    vector_stop = start + (stop - start) // LANES * LANES
    if long_table is not None:
        points_per_arcsec = long_table.points_per_arcsec
        grid_point = np.rint(angle[start] * points_per_arcsec)
        # a block within the cell of an in-domain grid point is in the domain (NaN and ±inf fail the comparison);
        # a block whose last sample is in another cell is not tried (a sweep crossing a cell edge)
        if (abs(grid_point) <= MAX_ABS_ANGLE_ARCSEC * points_per_arcsec - 1.0
                and np.rint(angle[stop - 1] * points_per_arcsec) == grid_point):
            # the tangent at grid point j, value_j + slope_j·(θ·points_per_arcsec − j), is linear in θ
            index = np.uint64(np.int64(grid_point)) & long_table.index_mask
            value = long_table.value_and_step_arcsec[index, 0]
            slope_per_step = long_table.value_and_step_arcsec[index, 1]
            block_gain = gain - slope_per_step * points_per_arcsec
            block_offset = offset_arcsec + value - slope_per_step * grid_point
            if streaming:
                folded = _vector_pass_streaming(angle, torque, out, out_shift, start, vector_stop, block_gain,
                                                arcsec_per_nm, block_offset, short_table, long_table, grid_point)
            else:
                folded = _vector_pass(angle, torque, out, out_shift, start, vector_stop, block_gain, arcsec_per_nm,
                                      block_offset, short_table, long_table, grid_point)
            if folded and _sample_pass(angle, torque, out, out_shift, vector_stop, stop, block_gain, arcsec_per_nm,
                                       block_offset, short_table, long_table, grid_point):
                return
            if streaming:
                _memory_fence()  # the streamed stores land before the block is written again
    if streaming:
        _vector_pass_streaming(angle, torque, out, out_shift, start, vector_stop, gain, arcsec_per_nm, offset_arcsec,
                               short_table, long_table, None)
    else:
        _vector_pass(angle, torque, out, out_shift, start, vector_stop, gain, arcsec_per_nm, offset_arcsec,
                     short_table, long_table, None)
    _sample_pass(angle, torque, out, out_shift, vector_stop, stop, gain, arcsec_per_nm, offset_arcsec,
                 short_table, long_table, None)


@_KERNEL
def compensate(angle, torque, out, gain, arcsec_per_nm, offset_arcsec, short_table, long_table) -> None:
    """out ← gain·angle − offset − arcsec_per_nm·torque − short(angle) − long(angle), sample by sample.

    angle, torque, out: float64 C-contiguous 1-d arrays of one length; out is angle or torque itself, or
    overlaps neither (with no torque array, pass angle as torque and arcsec_per_nm = 0: it is read from the
    same cache lines and adds 0); short_table, long_table: PeriodicTable or None.
    """
    n = angle.size
    out_address = np.int64(out.ctypes.data)
    is_input = out.ctypes.data == angle.ctypes.data or out.ctypes.data == torque.ctypes.data
    streaming = not is_input and out.nbytes >= STREAMING_MIN_BYTES and out_address % 8 == 0
    # the blocks lie on a grid that starts where out is aligned to a cache line when streaming, so that no
    # cache line is written both ways (the samples before it form a short first block)
    grid_start = (-out_address % _CACHE_LINE_BYTES) // 8 if streaming else 0
    destination = np.empty(BLOCK_SAMPLES) if is_input else out
    for block_start in range(grid_start - BLOCK_SAMPLES if grid_start > 0 else 0, n, BLOCK_SAMPLES):
        start = max(block_start, 0)
        stop = min(block_start + BLOCK_SAMPLES, n)
        out_shift = -start if is_input else 0
        block_streaming = streaming and (out_address + 8 * start) % _VECTOR_ALIGN_BYTES == 0
        _compensate_block(angle, torque, destination, out_shift, start, stop, gain, arcsec_per_nm, offset_arcsec,
                          short_table, long_table, block_streaming)
        if is_input:
            out[start:stop] = destination[: stop - start]
    if streaming:
        _memory_fence()


def compile_variant(short_table: PeriodicTable | None, long_table: PeriodicTable | None) -> None:
    """Compile (or load from numba's cache) the kernel variant for these tables, so that the first real batch
    does not wait for the compiler."""
    one = np.zeros(1)
    compensate(one, one, np.empty(1), 1.0, 0.0, 0.0, short_table, long_table)
