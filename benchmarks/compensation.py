"""Compensation throughput (issue 7 item 1; target ≤ 4× the copy time).

The full compensator — geometric scale + torsion (consistent model of config/geometry-paper.toml), an Eq. 2
eccentricity and two periodic terms (72″ signal period and its 36″ harmonic) — applied to 10 million float64
samples of an RV-110E-like hysteresis test (±1078 N·m, 294 N·m/arcmin). Baselines measured in the same run:

* ``np.copyto`` of the same angle array into a preallocated output (the memory-bandwidth floor of the target);
* ``np.add(angle, torque, out=out)``: one pass that reads both inputs and writes the output, the memory floor
  of anything that compensates (reported for context, it is not a target);
* a per-sample Python loop with ``math`` functions (the naive way), timed on a subset and extrapolated.

Copy, floor and compensator are timed interleaved, in rounds whose order rotates, on the same arrays; each
figure is the median over the rounds of the calling thread's CPU time (so a call that another process on the
shared machine preempts is not charged for the wait) and the ratio is the ratio of the medians (the spread of
the per-round ratios and the wall-clock ratio are reported too). Reported for the default path (angle-only terms tabulated, error ≤ tolerance/2 =
0.0005″) and for the exact path (every term evaluated directly with numpy).
"""

from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np

from tcms_daq.compensation import Compensator, Eccentricity, Periodic
from tcms_daq.compensation import compensator as compensator_module
from tcms_daq.units import ARCSEC_PER_RAD

N_SAMPLES = 10_000_000
TARGET_RATIO = 4.0
GEOMETRY = Path(__file__).resolve().parents[1] / "config" / "geometry-paper.toml"


def full_compensator() -> Compensator:
    geometric = Compensator.from_geometry(GEOMETRY)
    return geometric.with_terms(
        Eccentricity(eccentricity_mm=0.005, radius_mm=30.0, phase_rad=0.7),
        Periodic(period_arcsec=72.0, sin_arcsec=0.35, cos_arcsec=-0.12),
        Periodic(period_arcsec=36.0, sin_arcsec=0.08, cos_arcsec=0.05),
    )


def test_data(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(angle_arcsec, torque_nm): three ±1078 N·m loops at 10 kHz with noise."""
    rng = np.random.default_rng(seed)
    phase = np.linspace(0.0, 6.0 * np.pi, n)
    torque = 1078.0 * np.sin(phase) + 0.5 * rng.standard_normal(n)
    angle = torque * (60.0 / 294.0) + 12.0 * np.sign(np.cos(phase)) + 0.2 * rng.standard_normal(n)
    return angle, torque


def python_loop(comp: Compensator, angle: np.ndarray, torque: np.ndarray) -> list[float]:
    """The naive way: one Python iteration per sample with math functions (same terms as ``comp``)."""
    scale = torsion = 0.0
    ecc = None
    periodic = []
    for t in comp.terms:
        if t.type_name == "scale":
            scale = t.coefficient
        elif t.type_name == "torsion":
            torsion = t.arcsec_per_nm
        elif t.type_name == "eccentricity":
            ecc = t
        elif t.type_name == "periodic":
            periodic.append((2 * math.pi / t.period_arcsec, t.sin_arcsec, t.cos_arcsec))
    out = []
    for th, tq in zip(angle.tolist(), torque.tolist(), strict=True):
        corr = scale * th + torsion * tq
        if ecc is not None:
            psi = th / ARCSEC_PER_RAD + ecc.phase_rad
            e = ecc.eccentricity_mm
            corr += math.atan2(e * math.sin(psi), ecc.radius_mm - e * math.cos(psi)) * ARCSEC_PER_RAD
        for w, a, b in periodic:
            corr += a * math.sin(w * th) + b * math.cos(w * th)
        out.append(th - corr)
    return out


def _time(fn) -> tuple[float, float]:
    """(wall seconds, CPU seconds of this thread) of one call."""
    w0, c0 = time.perf_counter(), time.thread_time()
    fn()
    return time.perf_counter() - w0, time.thread_time() - c0


def _interleaved(fns: dict, rounds: int) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """(wall, cpu): seconds per call of each function, one call of each per round, the order rotating every
    round (so no function always runs right after the same neighbour on a shared machine)."""
    names = list(fns)
    wall: dict[str, list[float]] = {k: [] for k in names}
    cpu: dict[str, list[float]] = {k: [] for k in names}
    for r in range(rounds):
        for k in names[r % len(names):] + names[: r % len(names)]:
            w, c = _time(fns[k])
            wall[k].append(w)
            cpu[k].append(c)
    return {k: np.asarray(v) for k, v in wall.items()}, {k: np.asarray(v) for k, v in cpu.items()}


def run(quick: bool = False) -> dict:
    n = N_SAMPLES  # also in quick mode: with fewer samples the arrays sit in cache and the copy is no floor
    rounds = 5 if quick else 21
    angle, torque = test_data(n)
    out = np.empty_like(angle)
    comp = full_compensator()

    comp.apply(angle, torque, out=out)  # warm-up: builds the table over the data's range, touches ``out``
    wall, cpu = _interleaved(
        {
            "copy": lambda: np.copyto(out, angle),
            "floor": lambda: np.add(angle, torque, out=out),
            "compensate": lambda: comp.apply(angle, torque, out=out),
        },
        rounds,
    )
    fast = comp.apply(angle, torque)
    exact_s = float(np.median([_time(lambda: comp.apply(angle, torque, out=out, exact=True))[1] for _ in range(1 if quick else 3)]))
    max_dev = float(np.max(np.abs(fast - out)))

    m = 20_000 if not quick else 5_000
    c0 = time.thread_time()
    looped = python_loop(comp, angle[:m], torque[:m])
    loop_s = (time.thread_time() - c0) * n / m
    loop_dev = float(np.max(np.abs(np.asarray(looped) - out[:m])))

    med = {k: float(np.median(v)) for k, v in cpu.items()}
    wall_med = {k: float(np.median(v)) for k, v in wall.items()}
    copy_s, fast_s = med["copy"], med["compensate"]
    ratio = fast_s / copy_s
    per_round = cpu["compensate"] / cpu["copy"]
    return {
        "name": "compensation",
        "metrics": {
            "n_samples": n,
            "terms": ", ".join(t.label() for t in comp.terms),
            "rounds": rounds,
            "copy_s": copy_s,
            "compensate_s": fast_s,
            "compensate_ratio_to_copy": ratio,
            "compensate_ratio_per_round_min": float(per_round.min()),
            "compensate_ratio_per_round_max": float(per_round.max()),
            "compensate_wall_ratio_to_copy": wall_med["compensate"] / wall_med["copy"],
            "compensate_samples_per_s": n / fast_s,
            "two_input_floor_ratio_to_copy": med["floor"] / copy_s,
            "compensate_exact_s": exact_s,
            "compensate_exact_ratio_to_copy": exact_s / copy_s,
            "compensate_exact_samples_per_s": n / exact_s,
            "python_loop_s_extrapolated": loop_s,
            "python_loop_samples_per_s": n / loop_s,
            "speedup_vs_python_loop": loop_s / fast_s,
            "max_abs_fast_vs_exact_arcsec": max_dev,
            "max_abs_python_loop_vs_exact_arcsec": loop_dev,
        },
        "targets": {
            "compensate_ratio_to_copy": {"limit": TARGET_RATIO, "met": bool(ratio <= TARGET_RATIO)},
            "max_abs_fast_vs_exact_arcsec": {
                "limit": comp.tolerance_arcsec / 2,
                "met": bool(max_dev <= comp.tolerance_arcsec / 2 + 1e-9),
            },
        },
        "notes": (
            ("quick mode: fewer rounds; " if quick else "")
            + f"copy, two-input floor and compensator timed interleaved ({rounds} rounds, rotating order, same "
            "arrays). Times are the median CPU time of the calling thread (time.thread_time: a call preempted by "
            "another process on this shared machine is not charged for the wait; memory and cache contention "
            "still count); compensate_ratio_to_copy = median(compensate)/median(copy), the per-round ratios show "
            "the spread, compensate_wall_ratio_to_copy is the same ratio of wall-clock medians. What the ratio "
            "is made of: np.copyto reads the 80 MB angle array and writes 80 MB; the compensator must read angle "
            "and torque (160 MB) and write 80 MB - one np.add(angle, torque, out) pass doing just that costs "
            "two_input_floor_ratio_to_copy (on a shared machine under co-load this floor and the ratio rise "
            "together: np.copyto is the least contention-sensitive of the three); the rest is arithmetic on chunks of "
            f"{compensator_module.CHUNK} samples held in L2: index from the bit pattern of angle + K (2 passes), "
            "table gather (np.take), c_T*T, add, gain*angle, subtract, then one plain copy of the finished chunk "
            "into the output (a streaming copy does not read the destination first). Linear terms folded into "
            "gain, c_T and the table's constant; angle-only terms (eccentricity, periodic) tabulated with error "
            f"<= tolerance/2; no range check per chunk (signalling-NaN guard cells). The Python loop timed on {m} "
            f"samples (CPU time) and extrapolated to {n}."
        ),
    }


if __name__ == "__main__":  # pragma: no cover
    import json
    import sys

    print(json.dumps(run(quick="--quick" in sys.argv), indent=2))
