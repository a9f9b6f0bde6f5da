"""Hysteresis evaluation of a torsional characteristic test (DESIGN §2, domain.md §1.7).

Pure functions on arrays. Sign convention: positive torque twists the output towards positive angle.

Per full loop (a B↑ and a B↓ branch):
- backlash (loop width at zero torque) = |θ_B↓(0) − θ_B↑(0)|;
- midline m(T) = [θ_B↑(T) + θ_B↓(T)]/2; lost motion = m(+p·T_rated) − m(−p·T_rated);
- torsional rigidity per direction = secant ΔT/Δm over [lo, hi]·T_test on that side, averaged over both sides;
  the upper end is the torque the loop actually reached (its turning point, where the branches meet and the
  midline is the tip angle, estimated on the flanks: ``tcms_daq.analysis.tips``) when that is short of hi·T_test
  or at most 2 % beyond it, so a loop that stops a little short of T_test is still evaluated and a torque scale
  error moves the end smoothly;
- optional Harmonic Drive K1/K2/K3: least-squares lines of the midline per region, per direction;
- loop energy ∮T dθ (J per cycle): the loop width integrated over the torque range of both branches.
Results are reported per loop, per direction and as mean ± std over the evaluated loops.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import asdict, dataclass, field, replace
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy.ndimage import uniform_filter1d

from tcms_daq.analysis import harmonic, plausibility
from tcms_daq.analysis.interpolation import (
    MAX_SPAN_FRACTION,
    angle_at_torque,
    fit_window,
    spacing_bound_arcsec,
)
from tcms_daq.analysis.noise import white_noise_std
from tcms_daq.analysis.notices import Notice, notices_of
from tcms_daq.analysis.segmentation import TIP_VALID_FRACTION, Branch, Loop, segment_loops, turning_points
from tcms_daq.analysis.tips import MIN_FLANK_SAMPLES, TipPoint, tip_point
from tcms_daq.errors import DataFormatError, EvaluationError
from tcms_daq.units import ARCSEC_PER_ARCMIN, ARCSEC_PER_DEG, ARCSEC_PER_RAD

MIN_SAMPLES = 20
CLIP_WARNING = 0.02  # warn when the rigidity interval had to end more than 2 % below what was asked
SNAP_TO_RATED = 0.02  # a reached torque within 2 % of the rated torque is taken as a test at rated torque
TO_THE_TIP = 0.02  # the rigidity interval ends at the turning point when that is at most 2 % beyond its end
RATE_LEVELS = 0.4  # loading rate measured between ∓40 % of the test torque on each branch
SCALE_PERCENTILE = 99.5
MIN_SIGNAL_TO_NOISE = 20.0  # a torque excursion below 20 × the torque noise is not a test
DRIFT_SIGNIFICANCE = 3.0  # a drift rate beyond 3 standard uncertainties of its estimate is corrected

ENERGY_GRID_POINTS = 201  # torque levels for the loop-area integral
HISTOGRAM_SAMPLES_PER_BIN = 20  # the torque histogram of a branch's moving density: some 20 samples per bin
HISTOGRAM_MAX_BINS = 400

SIDES = (("positive", 1), ("negative", -1))


@dataclass(frozen=True)
class Limits:
    """Acceptance limits of a reducer (None = not checked). Angles in arcsec, rigidity in N·m/arcmin."""

    rigidity_min_nm_per_arcmin: float | None = None
    rigidity_max_nm_per_arcmin: float | None = None
    backlash_max_arcsec: float | None = None
    lost_motion_max_arcsec: float | None = None

    def judge(self, values: dict[str, float], expanded: dict[str, float] | None = None,
              rule: str = "simple", refusals: Sequence[str] = ()) -> dict[str, Any]:
        """Verdict of mean values per ISO 14253-1: ``{"passed", "decision", "rule", "checks": {limit_name: {...}}}``.

        ``expanded`` maps a quantity to its expanded uncertainty U (same unit). Rule "simple": the value alone
        decides (simple acceptance, guard band 0). Rule "guarded": the guard band is U — pass only when the
        value is inside the limit by at least U, fail only when it is outside by more than U, otherwise
        "undecided" (a quantity without U gets guard band 0 and says so: ``"U": None``). Each check carries a
        readable ``label`` of its limit ("rigidity ≥ 235.2 N·m/arcmin"); ``passed`` is True only for "pass".
        ``refusals``: reasons the record cannot be judged (angle units implausible, …): every check is then
        "undecided" whatever its value, and the verdict carries the reasons (``"reasons"``).
        """
        if rule not in DECISION_RULES:
            raise EvaluationError(f"decision rule must be one of {', '.join(DECISION_RULES)}, got {rule!r}")
        rules = (
            ("rigidity_min_nm_per_arcmin", "rigidity_nm_per_arcmin", ">="),
            ("rigidity_max_nm_per_arcmin", "rigidity_nm_per_arcmin", "<="),
            ("backlash_max_arcsec", "backlash_arcsec", "<="),
            ("lost_motion_max_arcsec", "lost_motion_arcsec", "<="),
        )
        readable = {"rigidity_nm_per_arcmin": ("rigidity", "N·m/arcmin"), "backlash_arcsec": ("backlash", "″"),
                    "lost_motion_arcsec": ("lost motion", "″")}
        checks: dict[str, Any] = {}
        for name, quantity, comparison in rules:
            limit = getattr(self, name)
            if limit is None:
                continue
            value = float(values[quantity])
            u_expanded = (expanded or {}).get(quantity)
            guard = float(u_expanded) if rule == "guarded" and u_expanded is not None else 0.0
            decision = "undecided" if refusals else _decide(value, float(limit), comparison, guard)
            what, unit = readable[quantity]
            sign = "≥" if comparison == ">=" else "≤"
            checks[name] = {
                "quantity": quantity,
                "value": value,
                "comparison": comparison,
                "limit": float(limit),
                "passed": decision == "pass",
                "decision": decision,
                "guard_band": guard,
                "U": None if u_expanded is None else float(u_expanded),
                "label": f"{what} {sign} {float(limit):.4g}{'' if unit == '″' else ' '}{unit}",
            }
        overall = "undecided" if refusals else overall_decision(c["decision"] for c in checks.values())
        verdict: dict[str, Any] = {"passed": overall == "pass", "decision": overall, "rule": rule, "checks": checks}
        if refusals:
            verdict["reasons"] = list(refusals)
            verdict["reason_notices"] = notices_of(refusals)
        return verdict


DECISION_RULES = ("simple", "guarded")
DECISIONS: tuple[str, ...] = ("pass", "fail", "undecided")


def overall_decision(decisions: Iterable[str]) -> str:
    """The decision of several checks: fail if any fails, else undecided if any is, else pass."""
    found = set(decisions)
    return "fail" if "fail" in found else "undecided" if "undecided" in found else "pass"


def decision_of(entry: Mapping[str, Any]) -> str | None:
    """The ISO 14253-1 decision a verdict or a check states; for results judged before decisions existed, pass
    or fail from its ``passed``; None when it states neither."""
    stated = entry.get("decision")
    if isinstance(stated, str) and stated in DECISIONS:
        return stated
    passed = entry.get("passed")
    return ("pass" if passed else "fail") if isinstance(passed, bool) else None


def _decide(value: float, limit: float, comparison: str, guard: float) -> str:
    """ISO 14253-1 decision for one limit: pass / fail / undecided with guard band ``guard`` (≥ 0)."""
    margin = value - limit if comparison == ">=" else limit - value  # > 0: inside the specification
    if margin >= guard:
        return "pass"
    if margin < -guard:
        return "fail"
    return "undecided"


@dataclass
class DirectionResult:
    """One side (positive or negative torque) of one loop or the mean over loops."""

    rigidity_nm_per_arcmin: float
    interval_nm: tuple[float, float]  # |torque| range of the rigidity secant on this side
    torsion_angle_arcsec: float  # |m(±hi) − m(0)|: midline twist from zero to the interval's upper end
    half_lost_motion_arcsec: float  # |m(±p·T_rated) − m(0)|
    k1_nm_per_rad: float | None = None
    k2_nm_per_rad: float | None = None
    k3_nm_per_rad: float | None = None


@dataclass
class LoopResult:
    index: int  # 0-based among the full loops found in the record
    evaluated: bool  # False for loops skipped (e.g. the conditioning loop)
    order: str  # "up-down" (B↑ then B↓) or "down-up"
    start_time_s: float
    end_time_s: float
    rigidity_nm_per_arcmin: float
    backlash_arcsec: float
    lost_motion_arcsec: float
    loading_rate_nm_per_s: float
    loop_energy_j: float  # ∮T dθ: energy dissipated per cycle (area enclosed by the loop)
    per_direction: dict[str, DirectionResult]
    k1_nm_per_rad: float | None = None
    k2_nm_per_rad: float | None = None
    k3_nm_per_rad: float | None = None
    # standard uncertainty of the results from interpolating at the local sample spacing (result name → u in the
    # result's unit; ``interpolation_u``)
    interpolation_u: dict[str, float] = field(default_factory=dict)


@dataclass
class Evaluation:
    """Result of ``evaluate``; ``to_dict()`` is the JSON form (snake_case names with units)."""

    rigidity_nm_per_arcmin: float
    lost_motion_arcsec: float
    backlash_arcsec: float
    loop_energy_j: float  # area enclosed by the loop (∮T dθ), J per cycle
    std: dict[str, float | None]  # std over evaluated loops (None with a single loop)
    per_direction: dict[str, DirectionResult]
    loops: list[LoopResult]
    n_loops: int  # loops evaluated
    skipped_loops: int
    loading_rate_nm_per_s: float
    test_torque_nm: float
    rated_torque_nm: float
    lost_motion_pct: float
    lost_motion_torque_nm: float
    rigidity_interval: tuple[float, float]
    k1_nm_per_rad: float | None = None
    k2_nm_per_rad: float | None = None
    k3_nm_per_rad: float | None = None
    hd_breakpoints_nm: tuple[float, float] | None = None
    verdict: dict[str, Any] | None = None
    n_samples: int = 0
    duration_s: float = 0.0
    noise: dict[str, float] = field(default_factory=dict)
    fit_window_samples: int = 2
    warnings: list[str] = field(default_factory=list)
    # loop closure: drift rate of the angle at the turning points (and its u), the closure over the record, the
    # bias drift gives the backlash, the drift-corrected backlash and whether the results are corrected for the
    # drift (None: fewer than three turning points)
    closure: dict[str, Any] | None = None
    # per result name {"value", "u", "U", "k", "dof", "unit", "dominant", "budget"} (tcms_daq.uncertainty);
    # empty until a budget is attached
    uncertainty: dict[str, Any] = field(default_factory=dict)
    uncertainty_basis: str | None = None
    # reasons no pass/fail decision can be given on this record (e.g. the angle column is not in arcsec)
    undecidable: list[str] = field(default_factory=list)
    # the evaluated loops' mean interpolation_u per result (an error of the sampling, common to the loops)
    interpolation_u: dict[str, float] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = jsonable(asdict(self))
        out["notices"] = notices_of(self.warnings)  # the warnings' codes, for their translation
        return out


def jsonable(obj: Any) -> Any:
    """``obj`` with tuples as lists, numpy scalars as Python numbers and NaN/±inf as None (strict JSON)."""
    if isinstance(obj, dict):
        return {k: jsonable(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [jsonable(v) for v in obj]
    if isinstance(obj, np.generic):
        obj = obj.item()
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj


def _validated(time_s: npt.ArrayLike, torque_nm: npt.ArrayLike, angle_arcsec: npt.ArrayLike
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    cols = {}
    for name, values in (("time_s", time_s), ("torque_nm", torque_nm), ("angle_arcsec", angle_arcsec)):
        try:
            arr = np.asarray(values, dtype=float)
        except (TypeError, ValueError):
            raise DataFormatError(f"{name} is not numeric") from None
        if arr.ndim != 1:
            raise DataFormatError(f"{name} must be one-dimensional, got shape {arr.shape}")
        cols[name] = arr
    lengths = {len(v) for v in cols.values()}
    if len(lengths) != 1:
        raise DataFormatError(
            "column lengths differ: " + ", ".join(f"{k} {len(v)}" for k, v in cols.items())
        )
    n = lengths.pop()
    if n < MIN_SAMPLES:
        raise DataFormatError(f"too few samples: {n} (need at least {MIN_SAMPLES} for an evaluation)")
    for name, arr in cols.items():
        bad = np.flatnonzero(~np.isfinite(arr))
        if bad.size:
            raise DataFormatError(f"non-finite value {arr[bad[0]]} in {name} at sample {bad[0]}")
    t = cols["time_s"]
    back = np.flatnonzero(np.diff(t) <= 0.0)
    if back.size:
        i = int(back[0])
        raise DataFormatError(
            f"time_s is not strictly increasing at sample {i + 1} ({float(t[i]):.9g} s then {float(t[i + 1]):.9g} s)"
        )
    return t, cols["torque_nm"], cols["angle_arcsec"]


def _shown(value: object) -> str:
    """A value as a message shows it: numbers as numbers (never ``np.float64(…)``), anything else as repr."""
    if isinstance(value, int | float | np.number) and not isinstance(value, bool):
        return f"{float(value):g}"
    return repr(value)


@dataclass(frozen=True)
class EvaluationSettings:
    """What an evaluation is asked for (DESIGN §2). Torques in N·m; ``rigidity_interval`` as fractions of the
    test torque on each side; ``test_torque_nm`` None = the torque reached (snapped to rated within 2 %)."""

    rated_torque_nm: float
    test_torque_nm: float | None = None
    lost_motion_pct: float = 3.0
    rigidity_interval: tuple[float, float] = (0.5, 1.0)
    hd_breakpoints_nm: tuple[float, float] | None = None
    skip_loops: int = 0

    def __post_init__(self) -> None:
        rated, test = self.rated_torque_nm, self.test_torque_nm
        if not (rated is not None and math.isfinite(rated) and rated > 0):
            raise EvaluationError(f"rated torque must be a positive number of N·m, got {_shown(rated)}")
        if test is not None and not (math.isfinite(test) and test > 0):
            raise EvaluationError(f"test torque must be a positive number of N·m, got {_shown(test)}")
        if not (0.0 < self.lost_motion_pct < 50.0):
            raise EvaluationError(
                f"lost-motion torque level must be between 0 and 50 % of rated, got {self.lost_motion_pct}")
        lo, hi = self.rigidity_interval
        if not (0.0 <= lo < hi <= 1.0):
            raise EvaluationError(
                f"rigidity interval must be fractions of the test torque with 0 <= lo < hi <= 1, got {lo}…{hi}")
        if self.skip_loops < 0:
            raise EvaluationError(f"skip_loops must be >= 0, got {self.skip_loops}")

    @property
    def lost_motion_torque_nm(self) -> float:
        return self.lost_motion_pct / 100.0 * self.rated_torque_nm


@dataclass(frozen=True)
class Conditioning:
    """The record prepared for the loop evaluation: torque scale and noise, the fit window and the smoothed
    torque that locates crossings and turning points."""

    scale_nm: float  # the 99.5th percentile of |T|
    torque_noise_nm: float
    angle_noise_arcsec: float
    window: int  # samples per local fit
    max_span_nm: float  # no fit or smoothing spans more torque than this
    torque_smooth_nm: np.ndarray
    flank_samples: int = MIN_FLANK_SAMPLES  # samples of a tip's flank fits: those spanning max_span_nm of torque


@dataclass(frozen=True)
class LoopContext:
    """Everything one loop's evaluation reads: the record, its conditioning and the evaluation levels."""

    time_s: np.ndarray
    torque_nm: np.ndarray
    angle_arcsec: np.ndarray
    cond: Conditioning
    test_torque_nm: float
    settings: EvaluationSettings

    @property
    def lo_nm(self) -> float:
        return self.settings.rigidity_interval[0] * self.test_torque_nm

    @property
    def hi_nm(self) -> float:
        return self.settings.rigidity_interval[1] * self.test_torque_nm


def _trapezoid(y: np.ndarray, x: np.ndarray) -> float:
    return float(np.sum(0.5 * (y[1:] + y[:-1]) * np.diff(x)))


def _smooth(x: np.ndarray, window: int) -> np.ndarray:
    return uniform_filter1d(x, size=window, mode="nearest") if window >= 3 else x


def _branch_rate(time_s: np.ndarray, torque_smooth_nm: np.ndarray, branch: Branch, test_torque_nm: float) -> float:
    """Mean |dT/dt| (N·m/s) between ∓RATE_LEVELS·T_test on one branch (includes any dwell in between)."""
    progress = branch.progress_nm(torque_smooth_nm)
    a, b = np.searchsorted(progress, [-RATE_LEVELS * test_torque_nm, RATE_LEVELS * test_torque_nm])
    t = time_s[branch.slice]
    if b >= t.size or b <= a:
        return float("nan")
    return float(2.0 * RATE_LEVELS * test_torque_nm / (t[b] - t[a]))


def evaluate(
    time_s: npt.ArrayLike,
    torque_nm: npt.ArrayLike,
    angle_arcsec: npt.ArrayLike,
    *,
    rated_torque_nm: float,
    test_torque_nm: float | None = None,
    lost_motion_pct: float = 3.0,
    rigidity_interval: tuple[float, float] = (0.5, 1.0),
    hd_breakpoints_nm: tuple[float, float] | None = None,
    limits: Limits | None = None,
    skip_loops: int = 0,
    drift_rate_arcsec_per_s: float | None = None,
) -> Evaluation:
    """Evaluate a hysteresis test record.

    time_s (s, strictly increasing), torque_nm (N·m), angle_arcsec (output twist, arcsec): equal-length
    arrays. rated_torque_nm sets the lost-motion level (lost_motion_pct % of it); test_torque_nm (default:
    the torque reached at the turning points, snapped to rated within 2 %) sets the rigidity interval
    ``rigidity_interval`` (fractions of the test torque, on each side). hd_breakpoints_nm = (T1, T2) adds
    Harmonic Drive K1/K2/K3. The first ``skip_loops`` full loops (e.g. a conditioning loop) are reported but
    not averaged. A significant angle drift (see ``_plausibility``) is taken out of the angle and the loops are
    evaluated again (``closure["corrected"]``); ``drift_rate_arcsec_per_s`` forces that correction with a given
    rate (the uncertainty budget's drift line). Raises DataFormatError for malformed arrays and EvaluationError for
    data that do not contain an evaluable loop.
    """
    t, torque, angle = _validated(time_s, torque_nm, angle_arcsec)
    settings = EvaluationSettings(
        rated_torque_nm, test_torque_nm, lost_motion_pct, tuple(float(x) for x in rigidity_interval),  # type: ignore[arg-type]
        hd_breakpoints_nm, skip_loops)
    cond = _condition(torque, angle)
    _, loops = segment_loops(cond.torque_smooth_nm, cond.scale_nm)
    if skip_loops >= len(loops):
        raise EvaluationError(
            f"no full loop left to evaluate: the record has {len(loops)} full loop(s) and {skip_loops} are skipped"
        )
    ctx = LoopContext(t, torque, angle, cond, _test_torque(loops[skip_loops:], settings, t, torque, angle, cond),
                      settings)
    warnings: list[str] = []
    undecidable: list[str] = []
    loop_results = _evaluate_loops(loops, ctx, warnings)
    used = [r for r in loop_results if r.evaluated]
    means, stds, hd = _loop_statistics(used, with_hd=hd_breakpoints_nm is not None)
    used_loops = [loops[r.index] for r in used]
    closure = _plausibility(ctx, used_loops, means, warnings, undecidable)
    rate = drift_rate_arcsec_per_s
    if rate is None and closure is not None and closure["corrected"]:
        rate = closure["drift_rate_arcsec_per_s"]
    if rate is not None:
        # the drift taken out of the angle and every loop evaluated again: the results are the drift-corrected ones
        uncorrected = float(means["backlash_arcsec"])
        ctx = replace(ctx, angle_arcsec=angle - rate * (t - t[0]))
        loop_results = _evaluate_loops(loops, ctx, [])
        used = [r for r in loop_results if r.evaluated]
        means, stds, hd = _loop_statistics(used, with_hd=hd_breakpoints_nm is not None)
        if closure is not None:
            closure.update(corrected=True, uncorrected_backlash_arcsec=uncorrected,
                           drift_corrected_backlash_arcsec=float(means["backlash_arcsec"]), applied_rate_arcsec_per_s=rate)
    rates = [r.loading_rate_nm_per_s for r in used if math.isfinite(r.loading_rate_nm_per_s)]
    return Evaluation(
        rigidity_nm_per_arcmin=means["rigidity_nm_per_arcmin"],
        lost_motion_arcsec=means["lost_motion_arcsec"],
        backlash_arcsec=means["backlash_arcsec"],
        loop_energy_j=means["loop_energy_j"],
        std=stds,
        per_direction=_mean_per_direction(used),
        loops=loop_results,
        n_loops=len(used),
        skipped_loops=skip_loops,
        loading_rate_nm_per_s=float(np.median(rates)) if rates else float("nan"),
        test_torque_nm=ctx.test_torque_nm,
        rated_torque_nm=float(rated_torque_nm),
        lost_motion_pct=float(lost_motion_pct),
        lost_motion_torque_nm=settings.lost_motion_torque_nm,
        rigidity_interval=settings.rigidity_interval,
        hd_breakpoints_nm=tuple(float(x) for x in hd_breakpoints_nm) if hd_breakpoints_nm else None,  # type: ignore[arg-type]
        verdict=limits.judge(means, refusals=undecidable) if limits is not None else None,
        n_samples=int(t.size),
        duration_s=float(t[-1] - t[0]),
        noise={"torque_nm": cond.torque_noise_nm, "angle_arcsec": cond.angle_noise_arcsec},
        fit_window_samples=cond.window,
        warnings=sorted(set(warnings)),
        closure=closure,
        k1_nm_per_rad=hd.get("k1_nm_per_rad"),
        k2_nm_per_rad=hd.get("k2_nm_per_rad"),
        k3_nm_per_rad=hd.get("k3_nm_per_rad"),
        undecidable=undecidable,
        interpolation_u={q: float(np.mean([r.interpolation_u[q] for r in used])) for q in used[0].interpolation_u},
    )


def _evaluate_loops(loops: list[Loop], ctx: LoopContext, warnings: list[str]) -> list[LoopResult]:
    """Every full loop of the record (the skipped ones reported when they evaluate)."""
    skip = ctx.settings.skip_loops
    out: list[LoopResult] = []
    for k, loop in enumerate(loops):
        try:
            out.append(_evaluate_loop(k, k >= skip, loop, ctx, warnings))
        except EvaluationError as exc:
            if k >= skip:
                raise
            warnings.append(Notice("skipped_loop_not_reported", "skipped loop {loop} not reported: {error}",
                                   loop=str(k), error=str(exc)))
    return out


def _plausibility(ctx: LoopContext, used: list[Loop], means: dict[str, Any], warnings: list[str],
                  undecidable: list[str]) -> dict[str, Any] | None:
    """Warnings for what must not pass silently (tcms_daq.analysis.plausibility), reasons no decision can be given
    (``undecidable``); returns the loop closure, with ``corrected`` True when the drift is significant: larger in
    its effect on the backlash than DRIFT_BIAS_WARNING_* and than DRIFT_SIGNIFICANCE × its own uncertainty."""
    cond, lm_nm = ctx.cond, ctx.settings.lost_motion_torque_nm
    span = plausibility.implausible_span(ctx.angle_arcsec)
    if span is not None:
        message = Notice(
            "angle_span_implausible", "angle span {span}″ over a ±{torque} N·m test is implausibly small for arcsec "
            "(in degrees it would be {as_degrees}″, in radians {as_radians}″): is angle_arcsec in degrees or radians?",
            span=f"{span:.3g}", torque=f"{ctx.test_torque_nm:.4g}", as_degrees=f"{span * ARCSEC_PER_DEG:.4g}",
            as_radians=f"{span * ARCSEC_PER_RAD:.4g}")
        warnings.append(message)
        undecidable.append(message)
    tips = turning_points(cond.torque_smooth_nm, cond.scale_nm)
    reduced, typical = plausibility.reduced_turning_points(tips, TIP_VALID_FRACTION)
    for tp in reduced:
        warnings.append(Notice(
            "reduced_amplitude", "reduced amplitude: the torque turns at {torque} N·m at t = {time} s, {share} of the "
            "typical {typical} N·m (a loop needs {needed}): the loop(s) through it are not evaluated",
            torque=f"{tp.torque_nm:+.4g}", time=f"{float(ctx.time_s[tp.index]):.2f}",
            share=f"{abs(tp.torque_nm) / typical:.0%}", typical=f"{typical:.4g}", needed=f"{TIP_VALID_FRACTION:.0%}"))
    branches = [b for lp in used for b in (lp.first, lp.second)]
    gap = plausibility.coarsest_sampling_nm(cond.torque_smooth_nm, branches, np.array([0.0, lm_nm, -lm_nm]))
    if gap > plausibility.COARSE_FRACTION * lm_nm:
        warnings.append(Notice(
            "sampling_too_coarse", "sampling too coarse for the loop: {gap} N·m between the samples at the evaluation "
            "levels, the lost motion is read at ±{level} N·m (want at most {want} N·m): sample faster or load more "
            "slowly", gap=f"{gap:.3g}", level=f"{lm_nm:.4g}", want=f"{plausibility.COARSE_FRACTION * lm_nm:.3g}"))
    rigidity = means.get("rigidity_nm_per_arcmin")
    if rigidity is None or not rigidity > 0.0:
        return None
    drift = plausibility.drift_from_turning_points(
        ctx.time_s, ctx.torque_nm, ctx.angle_arcsec, cond.torque_smooth_nm, tips, cond.scale_nm,
        ARCSEC_PER_ARCMIN / rigidity)
    if drift is None:
        return None
    per_rate = float(np.mean([plausibility.backlash_drift_bias_arcsec(ctx.time_s, cond.torque_smooth_nm, lp, 1.0)
                              for lp in used]))
    bias = drift.rate_arcsec_per_s * per_rate
    backlash = float(means["backlash_arcsec"])
    large = abs(bias) > max(plausibility.DRIFT_BIAS_WARNING_ARCSEC, plausibility.DRIFT_BIAS_WARNING_FRACTION * backlash)
    assessed = math.isfinite(drift.rate_u_arcsec_per_s)
    significant = large and (not assessed or abs(drift.rate_arcsec_per_s) > DRIFT_SIGNIFICANCE * drift.rate_u_arcsec_per_s)
    closure: dict[str, Any] = {
        "drift_rate_arcsec_per_s": drift.rate_arcsec_per_s,
        "drift_rate_u_arcsec_per_s": drift.rate_u_arcsec_per_s if assessed else None,
        "closure_arcsec": drift.closure_arcsec,
        "span_s": drift.span_s,
        "turning_points": drift.tips,
        "backlash_drift_bias_arcsec": bias,
        "drift_corrected_backlash_arcsec": backlash - bias,
        "corrected": significant,
    }
    if significant:
        drift_text = {"rate": f"{drift.rate_arcsec_per_s:+.3g}", "closure": f"{drift.closure_arcsec:+.3g}",
                      "span": f"{drift.span_s:.3g}", "bias": f"{bias:+.3g}", "corrected": f"{backlash - bias:.4g}",
                      "uncorrected": f"{backlash:.4g}"}
        warnings.append(Notice(
            "drift_corrected" if assessed else "drift_corrected_one_loop",
            "loop does not close: the angle at the turning points drifts by {rate}″/s ({closure}″ over {span} s); "
            "this moves the backlash by {bias}″: the results are drift-corrected (drift-corrected backlash "
            "{corrected}″, uncorrected {uncorrected}″)"
            + ("" if assessed else "; the correction's uncertainty cannot be assessed from one loop"), **drift_text))
        if not assessed:
            undecidable.append(Notice("drift_one_loop_undecidable", "angle drift of {rate}″/s corrected from one "
                                      "loop: the correction's uncertainty cannot be assessed", rate=drift_text["rate"]))
    elif large:
        warnings.append(Notice(
            "drift_not_significant", "the angle at the turning points may drift by {rate}″/s (± {u}″/s, not "
            "significant: not corrected); it would move the backlash by {bias}″",
            rate=f"{drift.rate_arcsec_per_s:+.3g}", u=f"{drift.rate_u_arcsec_per_s:.2g}", bias=f"{bias:+.3g}"))
    return closure


def _condition(torque: np.ndarray, angle: np.ndarray) -> Conditioning:
    """Torque scale and noise; a pilot segmentation on the raw torque sizes the fit window from the overall
    compliance; the smoothing never spans more than the fit's torque span."""
    scale = float(np.percentile(np.abs(torque), SCALE_PERCENTILE))
    if scale <= 0.0:
        raise EvaluationError("torque is zero throughout the record: no hysteresis loop")
    torque_noise = white_noise_std(torque)
    angle_noise = white_noise_std(angle)
    if scale < MIN_SIGNAL_TO_NOISE * torque_noise:
        raise EvaluationError(
            f"no hysteresis loop: torque stays within its noise (|T| ≤ {scale:.3g} Nm, noise {torque_noise:.3g} Nm)"
        )
    pilot_branches, _ = segment_loops(torque, scale)
    tips = [(b.start, b.start_torque_nm) for b in pilot_branches] + [
        (pilot_branches[-1].stop, pilot_branches[-1].stop_torque_nm)
    ]
    pos = [i for i, tq in tips if tq > 0]
    neg = [i for i, tq in tips if tq < 0]
    compliance = abs(
        (angle[pos].mean() - angle[neg].mean()) / (torque[pos].mean() - torque[neg].mean())
    ) if pos and neg else 0.0
    window = fit_window(angle_noise, torque_noise, compliance)
    max_span_nm = MAX_SPAN_FRACTION * scale
    # the smoothing only finds where a level is crossed (the fits are bounded by the torque span): it spans at most
    # the branch's mean samples per max_span_nm, holds included, which keeps a hold at a level steady
    samples_per_nm = float(
        np.median([(b.stop - b.start) / max(abs(b.stop_torque_nm - b.start_torque_nm), 1e-9) for b in pilot_branches])
    )
    torque_smooth = _smooth(torque, min(window, max(1, int(max_span_nm * samples_per_nm))))
    # a tip's flanks span max_span_nm on the move: on a staircase the mean would reach back into the last step's hold
    # and pull the tip's torque down (the rigidity's upper end with it)
    moving_per_nm = float(np.median([_samples_per_nm_moving(torque[b.start:b.stop + 1]) for b in pilot_branches]))
    return Conditioning(scale, torque_noise, angle_noise, window, max_span_nm, torque_smooth,
                        max(MIN_FLANK_SAMPLES, int(max_span_nm * moving_per_nm)))


def _samples_per_nm_moving(branch_torque_nm: np.ndarray) -> float:
    """Samples per N·m of one branch where its torque moves: the median density of its torque histogram. A hold
    (a tip hold, a staircase's steps) piles its samples into a bin or two and leaves the median to the ramps; on a
    continuous ramp this is the samples per N·m of the branch."""
    span_nm = float(np.ptp(branch_torque_nm))
    if span_nm <= 0.0:
        return float(branch_torque_nm.size) / 1e-9
    bins = int(np.clip(branch_torque_nm.size // HISTOGRAM_SAMPLES_PER_BIN, 10, HISTOGRAM_MAX_BINS))
    counts, _ = np.histogram(branch_torque_nm, bins=bins)
    return float(np.median(counts)) * bins / span_nm


def _tip_points(time_s: np.ndarray, torque_nm: np.ndarray, angle_arcsec: np.ndarray, cond: Conditioning,
                indices: Iterable[int]) -> dict[int, TipPoint]:
    """The turning points at these samples (extremes of the smoothed torque), estimated on their flanks."""
    return {i: tip_point(time_s, torque_nm, angle_arcsec, i, cond.flank_samples, cond.torque_noise_nm,
                         cond.torque_smooth_nm, cond.max_span_nm) for i in indices}


def _test_torque(evaluated: list[Loop], settings: EvaluationSettings, time_s: np.ndarray, torque_nm: np.ndarray,
                 angle_arcsec: np.ndarray, cond: Conditioning) -> float:
    """The requested test torque, else the median torque reached at the turning points (N·m, estimated on their
    flanks: the smoothed extreme falls short of a sharp tip), taken as the rated torque when within 2 % of it."""
    if settings.test_torque_nm is not None:
        return float(settings.test_torque_nm)
    indices = {i for lp in evaluated for i in (lp.first.start, lp.first.stop, lp.second.stop)}
    tips = _tip_points(time_s, torque_nm, angle_arcsec, cond, sorted(indices))
    reached = float(np.median([min(abs(tips[i].torque_nm) for i in (lp.first.start, lp.first.stop, lp.second.stop)
                                   if tips[i].torque_nm * s > 0.0) for lp in evaluated for _, s in SIDES]))
    if abs(reached - settings.rated_torque_nm) <= SNAP_TO_RATED * settings.rated_torque_nm:
        return float(settings.rated_torque_nm)
    return float(round(reached, 1))


def _mean_or_none(values: list[float | None]) -> float | None:
    """Mean, or None when any value is missing."""
    vals = [v for v in values if v is not None]
    return float(np.mean(vals)) if len(vals) == len(values) and vals else None


def _std_or_none(values: list[float | None]) -> float | None:
    """Sample standard deviation, or None when any value is missing or there are fewer than two."""
    vals = [v for v in values if v is not None]
    return float(np.std(vals, ddof=1)) if len(vals) == len(values) and len(vals) >= 2 else None


def _mean_per_direction(used: list[LoopResult]) -> dict[str, DirectionResult]:
    """Each side's results averaged over the evaluated loops."""
    out: dict[str, DirectionResult] = {}
    for name, _ in SIDES:
        ds = [r.per_direction[name] for r in used]
        out[name] = DirectionResult(
            rigidity_nm_per_arcmin=_mean_or_none([d.rigidity_nm_per_arcmin for d in ds]),  # type: ignore[arg-type]
            interval_nm=(
                _mean_or_none([d.interval_nm[0] for d in ds]),
                _mean_or_none([d.interval_nm[1] for d in ds]),
            ),  # type: ignore[arg-type]
            torsion_angle_arcsec=_mean_or_none([d.torsion_angle_arcsec for d in ds]),  # type: ignore[arg-type]
            half_lost_motion_arcsec=_mean_or_none([d.half_lost_motion_arcsec for d in ds]),  # type: ignore[arg-type]
            k1_nm_per_rad=_mean_or_none([d.k1_nm_per_rad for d in ds]),
            k2_nm_per_rad=_mean_or_none([d.k2_nm_per_rad for d in ds]),
            k3_nm_per_rad=_mean_or_none([d.k3_nm_per_rad for d in ds]),
        )
    return out


def _loop_statistics(used: list[LoopResult], with_hd: bool
                     ) -> tuple[dict[str, Any], dict[str, float | None], dict[str, float | None]]:
    """(means, standard deviations, Harmonic Drive K means) over the evaluated loops."""
    quantities = ("rigidity_nm_per_arcmin", "backlash_arcsec", "lost_motion_arcsec", "loop_energy_j")
    means = {q: _mean_or_none([getattr(r, q) for r in used]) for q in quantities}
    stds: dict[str, float | None] = {q: _std_or_none([getattr(r, q) for r in used]) for q in quantities}
    for name, _ in SIDES:
        stds[f"{name}_rigidity_nm_per_arcmin"] = _std_or_none(
            [r.per_direction[name].rigidity_nm_per_arcmin for r in used])
    hd: dict[str, float | None] = {}
    if with_hd:
        for q in ("k1_nm_per_rad", "k2_nm_per_rad", "k3_nm_per_rad"):
            hd[q] = _mean_or_none([getattr(r, q) for r in used])
            stds[q] = _std_or_none([getattr(r, q) for r in used])
    return means, stds, hd


def _evaluate_loop(index: int, is_evaluated: bool, loop: Loop, ctx: LoopContext, warnings: list[str]) -> LoopResult:
    """One full loop: both branches interpolated at the evaluation torque levels, then per side and per loop.
    A level within the flank span of a tip (the rigidity interval's upper end when the loop reaches about the
    test torque, or falls short of it) is read from the tip estimated on its flanks (``tcms_daq.analysis.tips``)."""
    cond = ctx.cond
    tips = _tip_points(ctx.time_s, ctx.torque_nm, ctx.angle_arcsec, cond,
                       (loop.first.start, loop.first.stop, loop.second.stop))
    his = _upper_ends(index, loop, ctx, warnings, tips)
    levels = _EvaluationLevels.build(loop, ctx, his)

    def branch_angles(branch: Branch) -> np.ndarray:
        sl = branch.slice
        return angle_at_torque(ctx.time_s[sl], ctx.torque_nm[sl], ctx.angle_arcsec[sl], cond.torque_smooth_nm[sl],
                               branch.direction, levels.torque_nm, cond.window, cond.max_span_nm)

    def branch_bounds(branch: Branch) -> np.ndarray:
        sl = branch.slice
        return spacing_bound_arcsec(ctx.torque_nm[sl], ctx.angle_arcsec[sl], cond.torque_smooth_nm[sl],
                                    branch.direction, levels.torque_nm[:_EvaluationLevels.FIXED], cond.window,
                                    cond.max_span_nm)

    up = branch_angles(loop.up)
    down = branch_angles(loop.down)
    bounds = {}
    for branch, angles in ((loop.up, up), (loop.down, down)):
        at_tip = _read_at_tips(branch, angles, levels, tips, cond.max_span_nm)
        bounds[branch.direction] = np.where(at_tip[:_EvaluationLevels.FIXED], 0.0, branch_bounds(branch))
    if np.isnan(up).any() or np.isnan(down).any():
        raise EvaluationError(f"loop {index}: a branch does not cover the evaluation torque levels")
    mid = 0.5 * (up + down)
    per_direction = {name: _direction_result(index, name, sign, mid, levels, ctx.lo_nm, his[sign])
                     for name, sign in SIDES}

    def both(q: str) -> float | None:
        a, b = (getattr(per_direction[name], q) for name, _ in SIDES)
        return None if a is None or b is None else 0.5 * (a + b)

    interpolation_u = _interpolation_u(bounds[1], bounds[-1], per_direction, mid, levels)
    t = ctx.time_s
    rates = [_branch_rate(t, cond.torque_smooth_nm, b, ctx.test_torque_nm) for b in (loop.first, loop.second)]
    energy = levels.energy
    return LoopResult(
        index=index,
        evaluated=is_evaluated,
        order=loop.order,
        start_time_s=float(t[loop.first.start]),
        end_time_s=float(t[loop.second.stop]),
        rigidity_nm_per_arcmin=both("rigidity_nm_per_arcmin"),  # type: ignore[arg-type]
        backlash_arcsec=float(abs(down[0] - up[0])),
        loop_energy_j=_trapezoid(down[energy] - up[energy], levels.torque_nm[energy]) / ARCSEC_PER_RAD,
        lost_motion_arcsec=float(mid[_EvaluationLevels.LM_POS] - mid[_EvaluationLevels.LM_NEG]),
        loading_rate_nm_per_s=float(np.nanmean(rates)) if not all(map(math.isnan, rates)) else float("nan"),
        per_direction=per_direction,
        k1_nm_per_rad=both("k1_nm_per_rad"),
        k2_nm_per_rad=both("k2_nm_per_rad"),
        k3_nm_per_rad=both("k3_nm_per_rad"),
        interpolation_u=interpolation_u,
    )


def _interpolation_u(bound_up: np.ndarray, bound_down: np.ndarray, per_direction: dict[str, DirectionResult],
                     mid: np.ndarray, levels: _EvaluationLevels) -> dict[str, float]:
    """Standard uncertainties of one loop's results from the branches' interpolation at the sample spacing: each
    level's error on each branch rectangular within ±its bound (u = bound/√3), independent, propagated through
    backlash = θ↓(0) − θ↑(0), lost motion = m(+p) − m(−p) and K = ΔT/Δm with m = (θ↑ + θ↓)/2."""
    L = _EvaluationLevels
    u2 = (bound_up**2 + bound_down**2) / 3.0  # per level: both branches' u², not yet halved for the midline

    out = {"backlash_arcsec": math.sqrt(u2[L.ZERO]),
           "lost_motion_arcsec": 0.5 * math.sqrt(u2[L.LM_POS] + u2[L.LM_NEG])}
    sides = []
    for name, lo, hi in (("positive", L.LO_POS, L.HI_POS), ("negative", L.LO_NEG, L.HI_NEG)):
        twist = abs(mid[hi] - mid[lo])
        k = per_direction[name].rigidity_nm_per_arcmin
        u_k = k / twist * 0.5 * math.sqrt(u2[lo] + u2[hi])
        out[f"{name}_rigidity_nm_per_arcmin"] = u_k
        sides.append(u_k)
    out["rigidity_nm_per_arcmin"] = 0.5 * math.hypot(*sides)
    return out


def _read_at_tips(branch: Branch, angles: np.ndarray, levels: _EvaluationLevels, tips: dict[int, TipPoint],
                  max_span_nm: float) -> np.ndarray:
    """Angles of one branch at levels within the flank span of its tips, read from the tips' fits (in place): the
    rigidity's upper ends at a sharp tip, and any level beyond what the smoothed branch reaches (NaN). Returns
    which levels were read there."""
    upper = {_EvaluationLevels.HI_POS, _EvaluationLevels.HI_NEG}
    read = np.zeros(angles.size, dtype=bool)
    for tip_index, before in ((branch.stop, True), (branch.start, False)):  # into the tip it ends at, out of the other
        tip = tips[tip_index]
        near = np.flatnonzero(np.abs(levels.torque_nm - tip.torque_nm) <= max_span_nm)
        for k in near:
            if np.isnan(angles[k]) or (k in upper and tip.sharp(before)):
                angles[k] = tip.angle_on_flank(float(levels.torque_nm[k]), before)
                read[k] = True
    return read


def _upper_ends(index: int, loop: Loop, ctx: LoopContext, warnings: list[str], tips: dict[int, TipPoint]
                ) -> dict[int, float]:
    """The upper end of the rigidity interval per side (sign → |T| in N·m): the asked one, or the torque the loop
    reached (the smaller tip torque of that side, estimated on the flanks) when it stops short (a warning when
    more than 2 % short). A loop that does not pass the lower end or the lost-motion level is not evaluable."""
    lo, lm_torque = ctx.lo_nm, ctx.settings.lost_motion_torque_nm
    his: dict[int, float] = {}
    for name, sign in SIDES:
        reached = min(abs(tp.torque_nm) for tp in tips.values() if tp.torque_nm * sign > 0.0)
        if reached <= lo or reached <= lm_torque:
            need = max(lo, lm_torque)
            raise EvaluationError(
                f"torque never reaches the evaluation interval: loop {index} reaches {sign * reached:+.4g} Nm on "
                f"the {name} side, the evaluation needs beyond {sign * need:+.4g} Nm"
            )
        # a loop that turns within 2 % beyond the asked end is evaluated to its turning point: the end does not
        # jump from the tip to a level just short of it when a torque scale error moves the tip across it
        hi = reached if reached <= ctx.hi_nm * (1.0 + TO_THE_TIP) else ctx.hi_nm
        if hi < ctx.hi_nm * (1.0 - CLIP_WARNING):
            warnings.append(Notice(
                f"rigidity_interval_clipped_{name}", "rigidity interval clipped on the {side} side: torque reached "
                "{reached} Nm, interval asks for {asked} Nm", side=name, reached=f"{reached:.4g}",
                asked=f"{ctx.hi_nm:.4g}"))
        his[sign] = hi
    return his


@dataclass(frozen=True)
class _EvaluationLevels:
    """The torque levels (N·m) both branches are interpolated at, in one array: first the fixed ones (indices
    below), then the Harmonic Drive region grids (``hd[(sign, region)]``), then the loop-area grid (``energy``)."""

    ZERO, LM_POS, LM_NEG, LO_POS, HI_POS, LO_NEG, HI_NEG = range(7)
    FIXED = 7  # the levels above

    torque_nm: np.ndarray
    hd: dict[tuple[int, int], slice]
    energy: slice

    @classmethod
    def build(cls, loop: Loop, ctx: LoopContext, his: dict[int, float]) -> _EvaluationLevels:
        lm, lo = ctx.settings.lost_motion_torque_nm, ctx.lo_nm
        levels = [0.0, lm, -lm, lo, his[1], -lo, -his[-1]]
        hd: dict[tuple[int, int], slice] = {}
        breakpoints = ctx.settings.hd_breakpoints_nm
        if breakpoints is not None:
            for _, sign in SIDES:
                for r, region in enumerate(harmonic.hd_regions(breakpoints, his[sign])):
                    if region is not None:
                        grid = sign * harmonic.region_grid(region)
                        hd[(sign, r)] = slice(len(levels), len(levels) + grid.size)
                        levels.extend(grid.tolist())
        # the loop area: the loop width integrated over the torque range both branches cover
        energy_grid = np.linspace(-loop.reached_torque_nm(-1), loop.reached_torque_nm(1), ENERGY_GRID_POINTS)
        energy = slice(len(levels), len(levels) + energy_grid.size)
        levels.extend(energy_grid.tolist())
        return cls(np.asarray(levels), hd, energy)


def _direction_result(index: int, name: str, sign: int, mid: np.ndarray, levels: _EvaluationLevels, lo: float,
                      hi: float) -> DirectionResult:
    """One side of one loop from the midline angles ``mid`` (arcsec) at ``levels``: the secant rigidity over
    [lo, hi] N·m, the twist from zero torque, half the lost motion and the Harmonic Drive K per region."""
    L = _EvaluationLevels
    m0 = mid[L.ZERO]
    m_lo, m_hi, m_lm = ((mid[L.LO_POS], mid[L.HI_POS], mid[L.LM_POS]) if sign > 0
                        else (mid[L.LO_NEG], mid[L.HI_NEG], mid[L.LM_NEG]))
    twist_arcsec = sign * (m_hi - m_lo)
    if twist_arcsec <= 0.0:
        raise EvaluationError(
            f"loop {index}: angle does not increase with torque on the {name} side "
            f"(midline {m_lo:.4g}″ at {sign * lo:+.4g} Nm, {m_hi:.4g}″ at {sign * hi:+.4g} Nm)"
        )
    ks: list[float | None] = [None, None, None]
    for r in range(3):
        sl = levels.hd.get((sign, r))
        if sl is not None:
            ks[r] = harmonic.stiffness_nm_per_rad(levels.torque_nm[sl], mid[sl])
    return DirectionResult(
        rigidity_nm_per_arcmin=(hi - lo) / twist_arcsec * ARCSEC_PER_ARCMIN,
        interval_nm=(lo, hi),
        torsion_angle_arcsec=abs(m_hi - m0),
        half_lost_motion_arcsec=abs(m_lm - m0),
        k1_nm_per_rad=ks[0],
        k2_nm_per_rad=ks[1],
        k3_nm_per_rad=ks[2],
    )
