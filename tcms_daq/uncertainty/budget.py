"""GUM uncertainty budgets (JCGM 100) of the results of a hysteresis evaluation.

For each result y (rigidity per direction and mean, lost motion, backlash, K1–K3, loop energy):
- Type A from the data (:func:`record_type_a`): the loop-to-loop scatter, u = s/√n with n − 1 degrees of
  freedom, and the record's own noise (a parametric bootstrap: the record re-evaluated with fresh noise of the
  measured size, ``BOOTSTRAP_DRAWS`` times), pooled when they agree, the loop scatter alone when the loops vary
  more than the noise explains; with a single loop the bootstrap alone;
- Type B from the declared chain (``tcms_daq.uncertainty.chain``): sensitivities c_i = ∂y/∂x_i by central
  differences through the same ``evaluate`` (±step, the step at least the input's u, as JCGM 100 5.1.3 allows);
- Type B from the sampling: the interpolation error of the branches at the local sample spacing
  (``Evaluation.interpolation_u``, from the branches' curvature: ``tcms_daq.analysis.interpolation``);
- combined with GTC (the GUM Tree Calculator): u_c, Welch–Satterthwaite effective degrees of freedom, the
  t-based coverage factor k for 95 %, U = k·u_c.

The one entry point is :func:`evaluation_budgets` (arrays, settings and the declared chain in, budgets out).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, replace
from typing import Any

import numpy as np
import numpy.typing as npt
from GTC import reporting, type_a, ureal
from scipy.special import fdtri

from tcms_daq.analysis.evaluation import Evaluation, EvaluationSettings, evaluate
from tcms_daq.config.models import ChainUncertainty
from tcms_daq.errors import EvaluationError
from tcms_daq.uncertainty.chain import Input, chain_inputs

COVERAGE_PROBABILITY = 95.0  # percent, as GTC's reporting.k_factor takes it
BOOTSTRAP_DRAWS = 8
BOOTSTRAP_SEED = 20_240_611
SAMPLING_LINE = "interpolation at the local sample spacing"
BIAS_LINE = "estimator bias at the measured noise"
LOOPS_LINE = "repeatability (loop-to-loop, n = {n})"  # the Type A line when it is the loop scatter alone
# the level of the preliminary F-test that decides whether the loop scatter and the noise bootstrap are pooled
# (a "sometimes pool" rule: Bancroft 1944; Bancroft & Han 1983 give 0.25–0.35 for few degrees of freedom)
POOLING_LEVEL = 0.25

# result name → unit (the order results are reported in)
RESULT_UNITS: dict[str, str] = {
    "rigidity_nm_per_arcmin": "N·m/arcmin",
    "positive_rigidity_nm_per_arcmin": "N·m/arcmin",
    "negative_rigidity_nm_per_arcmin": "N·m/arcmin",
    "lost_motion_arcsec": "arcsec",
    "backlash_arcsec": "arcsec",
    "k1_nm_per_rad": "N·m/rad",
    "k2_nm_per_rad": "N·m/rad",
    "k3_nm_per_rad": "N·m/rad",
    "loop_energy_j": "J",
}


@dataclass(frozen=True)
class BudgetLine:
    """One source: its standard uncertainty ``u_input`` (in ``input_unit``), the sensitivity of the result to it
    (result unit per input unit; for a Type A line 1) and its contribution |c|·u in the result's unit."""

    source: str
    type: str  # "A" or "B"
    u_input: float
    input_unit: str
    sensitivity: float
    contribution: float
    dof: float | None  # None: infinite

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass(frozen=True)
class Budget:
    """The uncertainty of one result: value, combined standard uncertainty u, effective degrees of freedom
    (None = infinite), coverage factor k (95 %), expanded U = k·u, the lines (largest contribution first)."""

    value: float
    u: float
    k: float
    dof: float | None
    unit: str
    lines: list[BudgetLine] = field(default_factory=list)

    @property
    def expanded(self) -> float:
        return self.k * self.u

    @property
    def dominant(self) -> str | None:
        return self.lines[0].source if self.lines else None

    def to_dict(self) -> dict[str, Any]:
        """The JSON form of the shared result contract (``uncertainty.<result name>``)."""
        return {"value": self.value, "u": self.u, "U": self.expanded, "k": self.k, "dof": self.dof,
                "unit": self.unit, "dominant": self.dominant, "budget": [line.to_dict() for line in self.lines]}


def result_values(ev: Evaluation) -> dict[str, float]:
    """The results of an evaluation that get a budget (those present), by name."""
    values: dict[str, Any] = {
        "rigidity_nm_per_arcmin": ev.rigidity_nm_per_arcmin,
        "positive_rigidity_nm_per_arcmin": ev.per_direction["positive"].rigidity_nm_per_arcmin,
        "negative_rigidity_nm_per_arcmin": ev.per_direction["negative"].rigidity_nm_per_arcmin,
        "lost_motion_arcsec": ev.lost_motion_arcsec,
        "backlash_arcsec": ev.backlash_arcsec,
        "k1_nm_per_rad": ev.k1_nm_per_rad,
        "k2_nm_per_rad": ev.k2_nm_per_rad,
        "k3_nm_per_rad": ev.k3_nm_per_rad,
        "loop_energy_j": ev.loop_energy_j,
    }
    return {k: float(v) for k, v in values.items() if v is not None and math.isfinite(v)}


def loop_values(ev: Evaluation, name: str) -> list[float]:
    """The per-loop values of a result over the evaluated loops."""
    out: list[float] = []
    for r in ev.loops:
        if not r.evaluated:
            continue
        side, _, rest = name.partition("_")
        v = (getattr(r.per_direction[side], rest) if side in ("positive", "negative") else getattr(r, name))
        if v is not None:
            out.append(float(v))
    return out


@dataclass(frozen=True)
class Contribution:
    """A Type B input of a budget with its sensitivity: ``line`` groups inputs reported together."""

    source: str
    unit: str
    u: float
    sensitivity: float
    line: str = ""
    dof: float | None = None  # None: infinite
    type: str = "B"


def combine(value: float, unit: str, type_a_u: float | None, type_a_dof: float | None, type_a_source: str,
            type_b: list[Contribution]) -> Budget:
    """Combine a Type A component (u, dof; None = none) and Type B inputs with their sensitivities (GTC), then
    report them one line per budget line (phase components of one periodic error merged root-sum-square)."""
    terms: list[Any] = []
    if type_a_u is not None:
        terms.append(ureal(0.0, type_a_u, math.inf if type_a_dof is None else type_a_dof, label=type_a_source))
    for b in type_b:
        terms.append(b.sensitivity * ureal(0.0, b.u, math.inf if b.dof is None else b.dof, label=b.source))
    if not terms:
        return Budget(value, 0.0, float(reporting.k_factor(math.inf, COVERAGE_PROBABILITY)), None, unit)
    y = value + sum(terms[1:], terms[0])
    u = float(y.u)
    dof = float(y.df) if u > 0.0 and math.isfinite(y.df) else None
    k = float(reporting.k_factor(math.inf if dof is None else dof, COVERAGE_PROBABILITY))
    lines: dict[str, BudgetLine] = {}
    if type_a_u is not None:
        lines[type_a_source] = BudgetLine(type_a_source, "A", type_a_u, unit, 1.0, type_a_u, type_a_dof)
    for b in type_b:
        line = b.line or b.source
        before = lines.get(line)
        if before is None:
            lines[line] = BudgetLine(line, b.type, b.u, b.unit, b.sensitivity, abs(b.sensitivity) * b.u, b.dof)
        else:  # another phase component of the same error: root-sum-square sensitivity
            s = math.hypot(before.sensitivity, b.sensitivity)
            lines[line] = replace(before, sensitivity=s, contribution=s * b.u)
    ordered = sorted(lines.values(), key=lambda ln: -ln.contribution)
    return Budget(value, u, k, dof, unit, ordered)


def _evaluate(time_s: np.ndarray, torque_nm: np.ndarray, angle_arcsec: np.ndarray,
              settings: EvaluationSettings) -> Evaluation:
    return evaluate(time_s, torque_nm, angle_arcsec, **asdict(settings))


def _sensitivities(time_s: np.ndarray, torque_nm: np.ndarray, angle_arcsec: np.ndarray, settings: EvaluationSettings,
                   inputs: list[Input], names: list[str]) -> dict[str, list[Contribution]]:
    """c_i per result by central differences through the evaluation."""
    out: dict[str, list[Contribution]] = {name: [] for name in names}
    # inputs that perturb the record the same way (the angle scale and the compensation's scale residual, at the
    # same step) share their evaluations
    evaluated: dict[tuple[Any, float], dict[str, float]] = {}

    def moved(inp: Input, x: float) -> dict[str, float]:
        key = (inp.apply, x)
        if key not in evaluated:
            torque, angle = inp.apply(torque_nm, angle_arcsec, x)
            try:
                evaluated[key] = result_values(_evaluate(time_s, torque, angle, settings))
            except EvaluationError as exc:
                raise EvaluationError(
                    f"uncertainty budget: the evaluation fails with {inp.name} moved by {x:+.3g} {inp.unit}: {exc}"
                ) from None
        return evaluated[key]

    for inp in inputs:
        plus, minus = moved(inp, inp.step), moved(inp, -inp.step)
        for name in names:
            if name not in plus or name not in minus:
                raise EvaluationError(f"uncertainty budget: {name} is not evaluated with {inp.name} moved by "
                                      f"±{inp.step:.3g} {inp.unit}")
            c = (plus[name] - minus[name]) / (2.0 * inp.step)
            out[name].append(Contribution(inp.name, inp.unit, inp.u, c, inp.budget_line))
    return out


@dataclass(frozen=True)
class NoiseBootstrap:
    """What the record's own noise does to a result (a parametric bootstrap): the draws' standard deviation
    ``scatter`` (the within-record noise's Type A, correlations between loops included) and the mean shift
    ``shift`` of the draws from the nominal value (the estimator's bias at this noise), over ``draws`` draws."""

    scatter: float
    shift: float
    draws: int

    @property
    def shift_u(self) -> float:
        """The standard uncertainty the bias line carries: the shift and its own standard error, combined."""
        return math.hypot(self.shift, self.scatter / math.sqrt(self.draws))


def _noise_bootstrap(time_s: np.ndarray, torque_nm: np.ndarray, angle_arcsec: np.ndarray,
                     settings: EvaluationSettings, nominal: Evaluation, names: list[str]) -> dict[str, NoiseBootstrap]:
    """The record re-evaluated ``BOOTSTRAP_DRAWS`` times with fresh noise of the measured size added (torque and
    angle, white, as ``white_noise_std`` measured them). An estimator whose bias grows with the noise variance
    (a nonlinear one: tips, crossings, curved branches) is biased by the same amount again in the draws, so the
    mean shift estimates its bias at the record's own noise (SIMEX, Cook & Stefanski 1994, one step)."""
    rng = np.random.default_rng(BOOTSTRAP_SEED)
    sigma_t = nominal.noise.get("torque_nm", 0.0)
    sigma_a = nominal.noise.get("angle_arcsec", 0.0)
    values0 = result_values(nominal)
    draws: dict[str, list[float]] = {name: [] for name in names}
    if sigma_t <= 0.0 and sigma_a <= 0.0:
        return {}
    for _ in range(BOOTSTRAP_DRAWS):
        torque = torque_nm + sigma_t * rng.standard_normal(torque_nm.size)
        angle = angle_arcsec + sigma_a * rng.standard_normal(angle_arcsec.size)
        try:
            values = result_values(_evaluate(time_s, torque, angle, settings))
        except EvaluationError:
            continue
        for name in names:
            if name in values:
                draws[name].append(values[name])
    return {name: NoiseBootstrap(float(np.std(v, ddof=1)), float(np.mean(v)) - values0[name], len(v))
            for name, v in draws.items() if len(v) >= 2}


def evaluation_budgets(time_s: npt.ArrayLike, torque_nm: npt.ArrayLike, angle_arcsec: npt.ArrayLike,
                       settings: EvaluationSettings, chain: ChainUncertainty | None = None,
                       nominal: Evaluation | None = None) -> dict[str, Budget]:
    """The uncertainty budget of every result of ``evaluate(time_s, torque_nm, angle_arcsec, **settings)``.

    ``chain``: the declared standard uncertainties of the measuring chain (None: Type A only). ``nominal``: the
    evaluation of these arrays with these settings, when the caller already has it. Perturbed evaluations keep
    the nominal test torque (the measurand's evaluation interval is defined by it). Raises EvaluationError when
    a perturbation within the declared uncertainties makes the record unevaluable.
    """
    t = np.asarray(time_s, dtype=float)
    torque = np.asarray(torque_nm, dtype=float)
    angle = np.asarray(angle_arcsec, dtype=float)
    if nominal is None:
        nominal = _evaluate(t, torque, angle, settings)
    fixed = replace(settings, test_torque_nm=nominal.test_torque_nm)
    values = result_values(nominal)
    names = list(values)
    inputs = chain_inputs(chain, nominal.test_torque_nm) if chain is not None else []
    sens = _sensitivities(t, torque, angle, fixed, inputs, names)
    for name, contribution in _drift_correction(t, torque, angle, fixed, nominal, names).items():
        sens[name].append(contribution)
    for name, u_sampling in nominal.interpolation_u.items():
        if name in sens and u_sampling > 0.0:
            sens[name].append(Contribution(SAMPLING_LINE, RESULT_UNITS[name], u_sampling, 1.0))
    noise = _noise_bootstrap(t, torque, angle, fixed, nominal, names)
    lines_a = record_type_a(nominal, names, noise)
    for name in names:
        boot = noise.get(name)
        if boot is not None and boot.shift_u > 0.0:
            sens[name].append(Contribution(BIAS_LINE, RESULT_UNITS[name], boot.shift_u, 1.0, dof=boot.draws - 1.0,
                                            type="A"))  # a statistical evaluation of the draws
    return {name: combine(values[name], RESULT_UNITS[name], lines_a[name].u, lines_a[name].dof,
                          lines_a[name].source, sens[name]) for name in names}


@dataclass(frozen=True)
class TypeA:
    """The Type A line of one result: standard uncertainty u (None: none), degrees of freedom, source name."""

    u: float | None
    dof: float | None
    source: str


def record_type_a(nominal: Evaluation, names: list[str], noise: dict[str, NoiseBootstrap]) -> dict[str, TypeA]:
    """The Type A line of each result from the loop-to-loop scatter and the noise bootstrap (``noise``).

    Both estimate the standard uncertainty of the mean over the loops: the loops as u_L = s/√n (n − 1 degrees of
    freedom), the bootstrap as the draws' scatter u_N (draws − 1), the noise's effect only, correlations between
    loops that share a turning point included. When the loops scatter no more than the noise explains (one-sided
    F-test: u_L²/u_N² below its 1 − POOLING_LEVEL quantile) the two are pooled, variances weighted by their
    degrees of freedom, degrees of freedom summed: two estimates of one variance (the larger of them, the rule
    before, overstated u by some 14 % and, when the loops happened to be larger, brought their k of 3.2–4.3).
    When the loops scatter significantly more they vary beyond the noise (creep, temperature, a loop unlike the
    others), which the bootstrap cannot see and pooling would average away: the loop scatter alone is the line.
    With 2–3 degrees of freedom no level catches a twofold excess reliably; the lenient 0.25 catches more of it
    (docs/uncertainty.md gives the trade).
    """
    n = nominal.n_loops
    out: dict[str, TypeA] = {}
    for name in names:
        boot = noise.get(name)
        u_l, dof_l = _type_a(loop_values(nominal, name)) if n >= 2 else (None, None)
        if u_l is None or dof_l is None:
            out[name] = (TypeA(None, None, LOOPS_LINE.format(n=n)) if boot is None else
                         TypeA(boot.scatter, boot.draws - 1.0,
                               f"noise within the record ({boot.draws} re-evaluations with fresh noise)" if n >= 2
                               else "noise within the one loop (loop-to-loop repeatability not assessed)"))
        elif boot is None:
            out[name] = TypeA(u_l, dof_l, LOOPS_LINE.format(n=n))
        else:
            u, dof, loops_alone = pooled_type_a(u_l, dof_l, boot.scatter, boot.draws - 1.0)
            out[name] = (TypeA(u_l, dof_l, LOOPS_LINE.format(n=n)) if loops_alone else
                         TypeA(float(u), float(dof), f"repeatability and noise within the record, pooled (n = {n}, "
                                                     f"{boot.draws} re-evaluations with fresh noise)"))
    return out


def pooled_type_a(u_loops: npt.ArrayLike, dof_loops: npt.ArrayLike, u_noise: npt.ArrayLike, dof_noise: npt.ArrayLike,
                  level: float = POOLING_LEVEL) -> tuple[Any, Any, Any]:
    """(u, degrees of freedom, loops alone?) of the Type A from the loop scatter and the noise bootstrap, elementwise:
    pooled unless u_loops²/u_noise² exceeds the 1 − ``level`` quantile of F(dof_loops, dof_noise) (level 0: always
    pooled), then the loop scatter alone. ``benchmarks.coverage.pooling`` gives the trade of ``level``."""
    u_l, u_n = np.asarray(u_loops, dtype=float), np.asarray(u_noise, dtype=float)
    dof_l, dof_n = np.asarray(dof_loops, dtype=float), np.asarray(dof_noise, dtype=float)
    loops_alone = u_l**2 > fdtri(dof_l, dof_n, 1.0 - level) * u_n**2
    pooled = np.sqrt((dof_l * u_l**2 + dof_n * u_n**2) / (dof_l + dof_n))
    return np.where(loops_alone, u_l, pooled), np.where(loops_alone, dof_l, dof_l + dof_n), loops_alone


def _drift_correction(time_s: np.ndarray, torque_nm: np.ndarray, angle_arcsec: np.ndarray,
                      settings: EvaluationSettings, nominal: Evaluation, names: list[str]) -> dict[str, Contribution]:
    """The drift correction's line when the results are drift-corrected: the rate's standard uncertainty (Type A,
    from the fit over the turning points, its degrees of freedom) with sensitivities from evaluating with the
    rate moved by ±u."""
    closure = nominal.closure or {}
    u = closure.get("drift_rate_u_arcsec_per_s")
    if not closure.get("corrected") or u is None or not u > 0.0:
        return {}
    rate = float(closure["applied_rate_arcsec_per_s"])
    dof = max(int(closure["turning_points"]) - 3, 1)  # the fit: a rate and one offset per sign
    moved = [result_values(evaluate(time_s, torque_nm, angle_arcsec, **asdict(settings),
                                    drift_rate_arcsec_per_s=rate + x)) for x in (u, -u)]
    return {name: Contribution("drift correction", "arcsec/s", float(u),
                               (moved[0][name] - moved[1][name]) / (2.0 * u), dof=float(dof), type="A")
            for name in names if name in moved[0] and name in moved[1]}


def _type_a(values: list[float]) -> tuple[float | None, float | None]:
    """u = s/√n and n − 1 degrees of freedom of the mean of ``values`` (GTC's type_a.estimate)."""
    if len(values) < 2:
        return None, None
    est = type_a.estimate(values)
    return float(est.u), float(est.df)


def attach(ev: Evaluation, budgets: dict[str, Budget], basis: str) -> Evaluation:
    """Store the budgets on the evaluation in their JSON form (``ev.uncertainty``) with their basis."""
    ev.uncertainty = {name: b.to_dict() for name, b in budgets.items()}
    ev.uncertainty_basis = basis
    return ev


def expanded_by_quantity(ev: Evaluation) -> dict[str, float]:
    """The expanded uncertainty U per result name of an evaluation with budgets attached."""
    return {name: float(entry["U"]) for name, entry in ev.uncertainty.items() if entry.get("U") is not None}
