"""Hidden-effect trials: does the workflow name the effect hidden in a simulated measurement?

For each case the simulated bench (``sim.bench.SimulatedBench``, RV-110E, sensor noise as in the default bench)
runs loops at two loading rates with the case's hidden effects switched on (``sim.effects``); the "simulated"
run is the bench's forward model (``sim.physics.twist_arcsec``) re-simulated on the measured torque trace,
without the effects. The noise floor is the residual RMS of the same seed with every effect off.
A case passes when the named effects are exactly the hidden ones, each primary parameter is within 10 %, the
held-out (nested CV) RMS after the workflow is within 30 % of the noise floor and the verdict is ``explained``.
The null case must name nothing and be ``consistent``.

Out-of-catalogue cases (``sim.unmodelled``: a slip, creep, a wider friction loop, clipping, glitches, thermal
wander, a housing that bulges in proportion to |T|) hide an effect the catalogue has no term for. Whatever they name, they pass only when the verdict is
not ``explained``: the honesty rate is the share of them that pass.

    python -m tcms_daq.discrepancy.trials [--seeds 5] [--json]      (or python -m tcms_daq.sim.trials)

prints the naming accuracy (cases named exactly right), the false-naming rate (null runs that name
anything), the parameter errors and the out-of-catalogue honesty rate.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import AbstractContextManager, contextmanager
from dataclasses import dataclass
from typing import Protocol

import numpy as np
from tcms_daq.sim.physics import ReducerPhysics
from tcms_daq.sim.unmodelled import UNMODELLED, Unmodelled

from tcms_daq.discrepancy import effects as fx
from tcms_daq.discrepancy.model_file import DiscrepancyModel
from tcms_daq.samples import Samples

# Hidden effects at the tested amplitudes (each effect's typical size, as in a [sim.effects] table).
_SINGLE = tuple(name for name, effect in fx.REGISTRY.items() if effect.simulated and effect.typical)


def _typical(*names: str) -> dict[str, dict[str, float]]:
    return {n: dict(fx.REGISTRY[n].typical) for n in names}


CASES: dict[str, dict[str, dict[str, float]]] = {
    "null": {},
    **{n: _typical(n) for n in _SINGLE},
    f"{fx.TIME_SKEW}+{fx.INTERPOLATION_ERROR}": _typical(fx.TIME_SKEW, fx.INTERPOLATION_ERROR),
    f"{fx.THERMAL_DRIFT}+{fx.BACKLASH}": _typical(fx.THERMAL_DRIFT, fx.BACKLASH),
}

# The parameter whose recovery is checked (within 10 %) per effect.
PRIMARY: dict[str, str] = {n: fx.REGISTRY[n].primary for n in _SINGLE}


@dataclass(frozen=True)
class TrialDesign:
    """The bench programme of a trial: ±amplitude loops at each rate, sampled at ``sample_rate_hz``."""

    reducer: str = "RV-110E"
    amplitude_nm: float = 800.0
    rates_nm_per_s: tuple[float, ...] = (200.0, 600.0)
    loops_per_rate: int = 3
    sample_rate_hz: float = 50.0
    torque_noise_nm: float = 0.3
    encoder_noise_arcsec: float = 0.2
    encoder_resolution_arcsec: float = 0.1


def bench_run(effects_table: dict, seed: int, design: TrialDesign = TrialDesign(),
              physics_scale: dict[str, float] | None = None) -> tuple[Samples, ReducerPhysics]:
    """Measured samples of the programme on a simulated bench with ``effects_table`` on; and the model's physics
    (the catalogue reducer's; the bench's own has ``physics_scale`` applied: field → factor)."""
    from dataclasses import replace

    from tcms_daq.sim.bench import SimulatedBench
    from tcms_daq.sim.effects import from_config
    from tcms_daq.sim.physics import physics_from_spec

    from tcms_daq.config import load_reducer_catalogue

    reducer = load_reducer_catalogue()[design.reducer]
    physics = physics_from_spec(reducer)
    actual = replace(physics, **{k: getattr(physics, k) * f for k, f in (physics_scale or {}).items()})
    bench = SimulatedBench(
        actual, reducer=reducer, sample_rate_hz=design.sample_rate_hz, torque_noise_nm=design.torque_noise_nm,
        encoder_noise_arcsec=design.encoder_noise_arcsec, encoder_resolution_arcsec=design.encoder_resolution_arcsec,
        seed=seed, effects=from_config(effects_table, seed=seed),
    )
    bench.set_drive_enabled(True)
    parts: list[Samples] = []
    level = 0.0

    def ramp(target: float, rate: float) -> None:
        nonlocal level
        bench.set_torque_target(target, rate)
        parts.append(bench.advance(abs(target - level) / rate + 0.05))
        level = target

    a = design.amplitude_nm
    for rate in design.rates_nm_per_s:
        ramp(-a, rate)
        for _ in range(design.loops_per_rate):
            ramp(a, rate)
            ramp(-a, rate)
    ramp(0.0, design.rates_nm_per_s[0])
    run = Samples.concat(parts)
    return Samples(run.time_s, run.torque_nm, run.angle_arcsec), physics


def make_pair(effects_table: dict, seed: int, design: TrialDesign = TrialDesign(),
              unmodelled: Unmodelled | None = None) -> tuple[Samples, Samples, float]:
    """(measured, simulated, noise floor RMS ″) for a case: simulated = the bench model on the measured torque
    (its applied-torque estimate, as for a stored run);
    ``unmodelled`` changes the measured run by an effect outside the catalogue."""
    from tcms_daq.sim.physics import twist_arcsec

    from tcms_daq.discrepancy.stored import applied_torque_estimate

    measured, physics = bench_run(effects_table, seed, design,
                                  unmodelled.physics_scale if unmodelled is not None else None)
    if unmodelled is not None and unmodelled.transform is not None:
        measured = unmodelled.transform(measured, np.random.default_rng([seed, 7]))
    def model_angle(run: Samples) -> np.ndarray:
        # driven, as the service drives it, by the torque the reducer felt: sensor noise on a hysteretic model
        # would walk it along minor loops (arcseconds at kHz rates)
        return twist_arcsec(applied_torque_estimate(run.time_s, run.torque_nm), physics)[0]

    simulated = Samples(measured.time_s, measured.torque_nm, model_angle(measured))
    null, _ = bench_run({}, seed, design)
    floor = float(np.std(null.angle_arcsec - model_angle(null)))
    return measured, simulated, floor


@dataclass
class TrialOutcome:
    case: str
    seed: int
    hidden: list[str]
    named: list[str]
    aliases: list[list[str]]
    parameter_errors: dict[str, float]  # relative error of the primary parameter per hidden effect
    cv_rms_after_arcsec: float
    noise_floor_arcsec: float
    seconds: float
    verdict: str = ""
    out_of_catalogue: bool = False

    @property
    def honest(self) -> bool:
        """An out-of-catalogue case is never called explained."""
        return self.verdict != "explained"

    @property
    def verdict_right(self) -> bool:
        return self.verdict == ("consistent" if not self.hidden else "explained")

    @property
    def named_exactly(self) -> bool:
        return sorted(self.named) == sorted(self.hidden)

    @property
    def parameters_ok(self) -> bool:
        return all(abs(e) <= 0.10 for e in self.parameter_errors.values()) and len(self.parameter_errors) == len(
            self.hidden)

    @property
    def floor_ok(self) -> bool:
        return self.cv_rms_after_arcsec <= 1.3 * self.noise_floor_arcsec

    @property
    def passed(self) -> bool:
        if self.out_of_catalogue:
            return self.honest
        return self.named_exactly and self.parameters_ok and self.floor_ok and self.verdict_right

    def to_dict(self) -> dict:
        return {"case": self.case, "seed": self.seed, "hidden": self.hidden, "named": self.named,
                "aliases": self.aliases, "parameter_errors": self.parameter_errors,
                "cv_rms_after_arcsec": self.cv_rms_after_arcsec, "noise_floor_arcsec": self.noise_floor_arcsec,
                "named_exactly": self.named_exactly, "parameters_ok": self.parameters_ok,
                "floor_ok": self.floor_ok, "verdict": self.verdict, "out_of_catalogue": self.out_of_catalogue,
                "passed": self.passed, "seconds": self.seconds}


def scaled(table: dict, factor: float) -> dict:
    """The case's effects with every amplitude-like parameter times ``factor`` (periods and phases kept)."""
    keep = {"period_arcsec", "phase_rad"}
    return {name: {k: (v if k in keep else v * factor) for k, v in params.items()} for name, params in table.items()}


def run_case(case: str, seed: int, design: TrialDesign = TrialDesign(), amplitude_scale: float = 1.0
             ) -> TrialOutcome:
    from tcms_daq.discrepancy.workflow import run_discrepancy

    unmodelled = UNMODELLED.get(case)
    table = {} if unmodelled is not None else scaled(CASES[case], amplitude_scale)
    measured, simulated, floor = make_pair(table, seed, design, unmodelled)
    t0 = time.perf_counter()
    result = run_discrepancy(measured, simulated)
    seconds = time.perf_counter() - t0
    if unmodelled is not None:
        return TrialOutcome(case, seed, [case], [e.name for e in result.effects], [a.names for a in result.aliases],
                            {}, result.cv_rms_after_arcsec, floor, seconds, result.verdict.verdict, True)
    found = {e.name: e.parameters for e in result.effects}
    errors = {}
    for name, params in table.items():
        if name in found:
            key = PRIMARY[name]
            errors[name] = (found[name][key] - params[key]) / params[key]
    return TrialOutcome(case, seed, sorted(table), [e.name for e in result.effects],
                        [a.names for a in result.aliases], errors, result.cv_rms_after_arcsec, floor, seconds,
                        result.verdict.verdict)


@dataclass
class ClosedLoop:
    """Run 1 → discrepancy → apply (the model file's terms with their uncertainties) → run 2 on new data, analysed
    against the applied model."""

    case: str
    size: float
    first: str  # run 1's verdict
    named: dict[str, dict[str, float]]  # run 1's named effects and parameters
    uncertainty: dict[str, dict[str, float]]  # their standard uncertainties (k = 1), carried by the model file
    expanded: dict[str, dict[str, float]]  # their expanded uncertainties U = k·u (about 95 %, Student's t)
    second: str  # run 2's verdict against the applied model
    second_named: list[str]
    second_cv_rms_arcsec: float
    noise_floor_arcsec: float
    apply_refused: str | None = None  # why the apply step refused run 1's terms (None: applied)

    @property
    def closed(self) -> bool:
        return self.apply_refused is None and self.second == "consistent" and not self.second_named

    def to_dict(self) -> dict:
        return {"case": self.case, "size": self.size, "first": self.first, "named": self.named,
                "uncertainty": self.uncertainty, "expanded_uncertainty": self.expanded, "second": self.second, "second_named": self.second_named,
                "second_cv_rms_arcsec": self.second_cv_rms_arcsec, "noise_floor_arcsec": self.noise_floor_arcsec,
                "apply_refused": self.apply_refused, "closed": self.closed}


# Run 2 is another programme than run 1 (a smaller amplitude, another seed): the model must carry over.
SECOND_RUN = TrialDesign(amplitude_nm=600.0)


@dataclass(frozen=True)
class LoopAnalysis:
    """One run of a closed loop and its discrepancy analysis: the verdict, the names, the model file it would
    apply (parsed from its TOML, with the standard uncertainties), the held-out RMS and the noise floor."""

    verdict: str
    names: list[str]
    model: DiscrepancyModel
    cv_rms_after_arcsec: float
    noise_floor_arcsec: float
    ref: str = ""  # the rig's handle of the analysis (the service's analysis id)


class LoopRig(Protocol):
    """Where a closed loop runs: the bench with the hidden effects, its discrepancy analysis and its apply step.
    ``InProcessRig`` (simulated bench and workflow called directly) and ``tcms_daq.service.closed_loop.ServiceRig`` (the
    service over HTTP: POST /api/tests, /api/discrepancy, /api/discrepancy/{id}/apply)."""

    def analyse(self, design: TrialDesign, seed: int) -> LoopAnalysis:
        """Run the programme ``design`` on the bench (new data) and analyse it against the model applied so far."""
        ...

    def apply(self, analysis: LoopAnalysis) -> str | None:
        """Add ``analysis``'s terms to the model; None when applied, else why not (one line)."""
        ...


class InProcessRig:
    """The closed loop in process: ``bench_run`` with ``table`` hidden, the workflow on (measured, simulated +
    the applied model), the model carried through its file as the service stores it."""

    def __init__(self, table: dict[str, dict[str, float]]):
        self.table = table
        self.model: DiscrepancyModel | None = None

    def analyse(self, design: TrialDesign, seed: int) -> LoopAnalysis:
        from tcms_daq.discrepancy.model_file import apply_model, model_from_result, parse_model
        from tcms_daq.discrepancy.workflow import run_discrepancy

        measured, simulated, floor = make_pair(self.table, seed, design)
        if self.model is not None:
            simulated = apply_model(self.model, simulated)
        result = run_discrepancy(measured, simulated)
        model = parse_model(model_from_result(result).to_toml())  # through the file, as the service stores it
        return LoopAnalysis(result.verdict.verdict, result.names, model, result.cv_rms_after_arcsec, floor)

    def apply(self, analysis: LoopAnalysis) -> str | None:
        self.model = analysis.model
        return None


RigFactory = Callable[[dict[str, dict[str, float]], int], AbstractContextManager[LoopRig]]


@contextmanager
def in_process(table: dict[str, dict[str, float]], seed: int) -> Iterator[LoopRig]:
    yield InProcessRig(table)


def closed_loop(case: str, size: float, seed: int, design: TrialDesign = TrialDesign(),
                second_design: TrialDesign = SECOND_RUN, rig: RigFactory = in_process) -> ClosedLoop:
    """The closed loop of one case at ``size`` × its typical amplitude on ``rig`` (in process by default):
    run 1 (seed ``seed``) → apply → run 2 (``second_design``, seed ``seed + 1``: new data)."""
    table = scaled(CASES[case], size)
    with rig(table, seed) as bench:
        first = bench.analyse(design, seed)
        refused = bench.apply(first)
        second = bench.analyse(second_design, seed + 1)
    return ClosedLoop(case, size, first.verdict, {t.name: t.parameters for t in first.model.terms},
                      {t.name: t.standard_uncertainty for t in first.model.terms},
                      {t.name: t.expanded_uncertainty for t in first.model.terms},
                      second.verdict, second.names, second.cv_rms_after_arcsec, first.noise_floor_arcsec,
                      apply_refused=refused)


def closed_loop_table(loops: list[ClosedLoop]) -> str:
    """A Markdown table of closed loops (the README's demonstration)."""
    lines = ["| hidden effect | size | run 1 | named (primary parameter ± u; U, about 95 %) | "
             "run 2 against the applied model |",
             "|---|---|---|---|---|"]
    nan = float("nan")
    for lp in loops:
        named = "; ".join(
            f"{n} {p[fx.REGISTRY[n].primary]:.4g} ± {lp.uncertainty.get(n, {}).get(fx.REGISTRY[n].primary, nan):#.2g}; "
            f"U {lp.expanded.get(n, {}).get(fx.REGISTRY[n].primary, nan):#.2g}"
            for n, p in lp.named.items()) or "-"
        hidden = "; ".join(f"{n} {v[fx.REGISTRY[n].primary]:.4g}" for n, v in scaled(CASES[lp.case], lp.size).items())
        refused = f"apply refused ({lp.apply_refused.split(':')[0]}); " if lp.apply_refused else ""
        second_named = f", named {', '.join(lp.second_named)}" if lp.second_named else ""
        lines.append(f"| {hidden} | ×{lp.size:g} | {lp.first} | {named} | {refused}{lp.second}{second_named} "
                     f"({lp.second_cv_rms_arcsec:.3f}″ vs floor {lp.noise_floor_arcsec:.3f}″) |")
    return "\n".join(lines)


def summarise(outcomes: list[TrialOutcome]) -> dict:
    every_run = outcomes
    unknown_runs = [o for o in outcomes if o.out_of_catalogue]
    outcomes = [o for o in outcomes if not o.out_of_catalogue]
    effect_runs = [o for o in outcomes if o.hidden]
    null_runs = [o for o in outcomes if not o.hidden]
    per_case: dict[str, dict] = {}
    for o in outcomes:
        c = per_case.setdefault(o.case, {"runs": 0, "named_exactly": 0, "passed": 0, "max_parameter_error": 0.0})
        c["runs"] += 1
        c["named_exactly"] += int(o.named_exactly)
        c["passed"] += int(o.passed)
        if o.parameter_errors:
            c["max_parameter_error"] = max(c["max_parameter_error"], *(abs(v) for v in o.parameter_errors.values()))
    wrong_names = sum(len(set(o.named) - set(o.hidden)) for o in outcomes)
    return {
        "runs": len(every_run),
        "naming_accuracy": sum(o.named_exactly for o in effect_runs) / len(effect_runs) if effect_runs else None,
        "false_naming_rate_null": (sum(bool(o.named) for o in null_runs) / len(null_runs)) if null_runs else None,
        "spurious_names_per_run": wrong_names / len(outcomes) if outcomes else None,
        "pass_rate": sum(o.passed for o in every_run) / len(every_run) if every_run else None,
        "max_parameter_error": max((abs(v) for o in outcomes for v in o.parameter_errors.values()), default=None),
        "held_out_over_floor_max": max((o.cv_rms_after_arcsec / o.noise_floor_arcsec for o in outcomes),
                                       default=None),
        "verdict_right_rate": sum(o.verdict_right for o in outcomes) / len(outcomes) if outcomes else None,
        "per_case": per_case,
        "mean_seconds_per_run": float(np.mean([o.seconds for o in outcomes])) if outcomes else None,
        "out_of_catalogue": {
            "runs": len(unknown_runs),
            "honesty_rate": sum(o.honest for o in unknown_runs) / len(unknown_runs) if unknown_runs else None,
            "verdicts": {v: sum(o.verdict == v for o in unknown_runs)
                         for v in ("consistent", "explained", "partially_explained", "unexplained")},
            "per_case": {c: [o.verdict for o in unknown_runs if o.case == c]
                         for c in dict.fromkeys(o.case for o in unknown_runs)},
        },
    }


def main(argv: list[str] | None = None, prog: str = "python -m tcms_daq.sim.trials",
         rig: RigFactory = in_process) -> int:
    """The trials' command; ``rig`` is where a closed loop runs (in process here; over HTTP from
    ``python -m tcms_daq.service.closed_loop``)."""
    parser = argparse.ArgumentParser(prog=prog, description=__doc__.split("\n")[0])
    parser.add_argument("--seeds", type=int, default=5, help="seeds per case (default 5)")
    parser.add_argument("--first-seed", type=int, default=100)
    parser.add_argument("--case", action="append", choices=sorted(CASES) + sorted(UNMODELLED),
                        help="only these cases (catalogue cases and out-of-catalogue ones)")
    parser.add_argument("--catalogue-only", action="store_true", help="leave out the out-of-catalogue cases")
    parser.add_argument("--amplitude-scale", type=float, default=1.0,
                        help="multiply every hidden amplitude (skew, rate, coefficient, amplitude) by this")
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.add_argument("--closed-loop", type=float, action="append", metavar="SIZE",
                        help="run 1 → apply → run 2 for every catalogue case at SIZE × its typical amplitude "
                             "(repeatable); prints a Markdown table")
    args = parser.parse_args(argv)
    if args.closed_loop:
        names = [c for c in (args.case or CASES) if c in CASES and c != "null"]
        loops = []
        for c in names:
            for size in args.closed_loop:
                loops.append(closed_loop(c, size, args.first_seed, rig=rig))
                if not args.json:
                    print(json.dumps(loops[-1].to_dict()), file=sys.stderr, flush=True)
        print(json.dumps([lp.to_dict() for lp in loops], indent=1) if args.json else closed_loop_table(loops))
        return 0 if all(lp.closed for lp in loops) else 1
    cases = args.case or list(CASES) + ([] if args.catalogue_only else list(UNMODELLED))
    outcomes = []
    for case in cases:
        for seed in range(args.first_seed, args.first_seed + args.seeds):
            o = run_case(case, seed, amplitude_scale=args.amplitude_scale)
            outcomes.append(o)
            if not args.json:
                flag = "ok  " if o.passed else "FAIL"
                errs = ", ".join(f"{k} {v:+.1%}" for k, v in o.parameter_errors.items())
                print(f"{flag} {case:32s} seed {seed}: {o.verdict}; named {o.named or '-'}"
                      f"{' aliases ' + str(o.aliases) if o.aliases else ''}; {errs}; held-out "
                      f"{o.cv_rms_after_arcsec:.3f}″ vs floor {o.noise_floor_arcsec:.3f}″ ({o.seconds:.1f} s)",
                      flush=True)
    summary = summarise(outcomes)
    summary["amplitude_scale"] = args.amplitude_scale
    if args.json:
        print(json.dumps({"summary": summary, "runs": [o.to_dict() for o in outcomes]}, indent=1))
    else:
        def pct(v):
            return "n/a" if v is None else f"{v:.1%}"

        n_effect = sum(1 for o in outcomes if o.hidden and not o.out_of_catalogue)
        n_null = sum(1 for o in outcomes if not o.hidden)
        unknown = summary["out_of_catalogue"]
        ratio = summary["held_out_over_floor_max"]
        print(f"naming accuracy {pct(summary['naming_accuracy'])} over {n_effect} effect runs; false naming "
              f"{pct(summary['false_naming_rate_null'])} over {n_null} null runs; all criteria met in "
              f"{pct(summary['pass_rate'])} of {len(outcomes)} runs; max |parameter error| "
              f"{pct(summary['max_parameter_error'])}; max held-out RMS / noise floor "
              f"{'n/a' if ratio is None else format(ratio, '.2f')}; verdict right (explained / consistent) in "
              f"{pct(summary['verdict_right_rate'])}; out of the catalogue: never 'explained' in "
              f"{pct(unknown['honesty_rate'])} of {unknown['runs']} runs {unknown['verdicts']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
