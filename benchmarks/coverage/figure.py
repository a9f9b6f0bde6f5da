"""``python -m benchmarks.coverage.figure``: docs/uncertainty-tip.png, how the rigidity's upper end is read at a
sharp (no-hold) tip: the samples, the smoothed torque's maximum (what the evaluation used to read), the flank
fits and the estimated turning point, against the true tip; one run of the rv-dahl-soft-50hz family at 3× noise."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from benchmarks.coverage.families import FAMILIES, draw_run  # noqa: E402
from tcms_daq.analysis.evaluation import _condition  # noqa: E402
from tcms_daq.analysis.segmentation import turning_points  # noqa: E402
from tcms_daq.analysis.tips import tip_point  # noqa: E402

OUT = Path(__file__).resolve().parents[2] / "docs" / "uncertainty-tip.png"


def main() -> None:
    family = dataclasses.replace(next(f for f in FAMILIES if f.name == "rv-dahl-soft-50hz"), noise=(3.0, 3.0))
    record, reducer = draw_run(family, np.random.default_rng(4))
    t, torque, angle = record.time_s, record.torque_nm, record.angle_arcsec
    cond = _condition(torque, angle)
    tp = next(p for p in turning_points(cond.torque_smooth_nm, cond.scale_nm) if p.sign > 0)
    tip = tip_point(t, torque, angle, tp.index, cond.flank_samples, cond.torque_noise_nm)
    i, n = tp.index, cond.flank_samples
    around = slice(max(0, i - 3 * n), i + 3 * n)
    fig, ax = plt.subplots(figsize=(8, 4.2), dpi=110)
    ax.plot(t[around] - t[i], torque[around], ".", color="0.55", label="torque samples (3× declared noise)")
    ax.plot(t[around] - t[i], cond.torque_smooth_nm[around], "-", color="tab:orange",
            label=f"smoothed torque (its maximum {tp.torque_nm:.1f} N·m)")
    for sl in (slice(i - n + 1, i + 1), slice(i, i + n)):
        tt = t[sl] - t[i]
        coef = np.polyfit(tt, torque[sl], 1)
        span = np.linspace(tt[0] - 0.6 * (tt[-1] - tt[0]), tt[-1] + 0.6 * (tt[-1] - tt[0]), 20)
        ax.plot(span, np.polyval(coef, span), "-", color="tab:blue", lw=1)
    ax.axhline(tip.torque_nm, color="tab:blue", ls="--", lw=1,
               label=f"turning point from the flank fits ({tip.torque_nm:.1f} N·m)")
    ax.set_xlabel("time from the smoothed maximum (s)")
    ax.set_ylabel("torque (N·m)")
    ax.set_title(f"A sharp tip at 50 Hz ({reducer.rated_torque_nm:.0f} N·m reducer): the smoothed maximum falls short")
    ax.legend(loc="lower center", fontsize=8)
    fig.tight_layout()
    fig.savefig(OUT)
    print(OUT)


if __name__ == "__main__":
    main()
