"""``tcms run``: a stiffness test on any bench, evaluated like ``tcms analyze``.

The test goes through the acquisition layer (``tcms_daq.acquisition``: bench composed from the config's
instruments, acquisition loop, procedure state machine with interlocks). With the default config the bench is
the in-process simulated bench (virtual drivers, simulated clock: runs faster than real time); with
``--config config/bench-loopback.toml`` it talks ND 287, AED and CANopen to ``tcms sim serve`` in another
process (``--speed`` must then match the simulator's speed).

The bench, reducer and profile come from a bench config (default ``config/bench-sim.toml``); options override
them. The evaluation is ``tcms_daq.analysis.evaluate`` on the evaluated loops (the conditioning loop is
recorded but not evaluated); ``--out`` writes exactly those samples as canonical CSV, so
``tcms analyze FILE --rated-torque T`` (plus the options the run prints) gives the same numbers.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pydantic import ValidationError

from tcms_daq.analysis.evaluation import jsonable
from tcms_daq.analysis.gaps import exclude_gapped_loops
from tcms_daq.analysis.notices import prepend_warnings
from tcms_daq.cli.options import add_bench_config_options, add_decision_rule_option
from tcms_daq.config import BenchConfig, ReducerSpec, load_bench_config, load_reducers_for
from tcms_daq.errors import TcmsError
from tcms_daq.procedure import Profile
from tcms_daq.procedure.methods import METHODS
from tcms_daq.procedure.plan import (
    MAX_POSITIONS,
    REDUCER_TORQUE_HEADROOM,
    MethodTestPlan,
    Plan,
    PlanRejected,
    PlanRequest,
    TestPlan,
    plan_from_request,
    single_plan,
)
from tcms_daq.samples import Samples, write_csv

CSV_COLUMNS = ("time_s", "torque_nm", "angle_arcsec", "encoder_arcsec", "applied_torque_nm", "true_angle_arcsec",
               "loop_index", "stage_index")


def _positions(text: str) -> int | list[float]:
    """``--positions``: a count N (equally spaced over 360°) or a comma-separated list of degrees."""
    from tcms_daq.procedure.plan import positions_from

    try:
        spec: int | list[float] = int(text) if "," not in text and text.strip().lstrip("+").isdigit() else [
            float(part) for part in text.split(",")]
        positions_from(spec)
    except ValueError as exc:
        message = str(exc) if "positions" in str(exc) else f"not a count or a list of degrees: {text!r}"
        raise argparse.ArgumentTypeError(message) from None
    return spec


def _rates(text: str) -> list[float]:
    """``--rates R1,R2,…``: loading rates in N·m/s."""
    from tcms_daq.procedure.plan import rates_from

    try:
        return rates_from([float(part) for part in text.split(",")])
    except ValueError as exc:
        message = str(exc) if "rates" in str(exc) else f"not a list of numbers: {text!r}"
        raise argparse.ArgumentTypeError(message) from None


def _positive(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not value > 0:
        raise argparse.ArgumentTypeError(f"must be > 0, got {text}")
    return value


def _int_at_least(minimum: int):
    """An argparse type: an integer >= ``minimum``."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"not an integer: {text!r}") from None
        if value < minimum:
            raise argparse.ArgumentTypeError(f"must be >= {minimum}, got {text}")
        return value

    return parse


_count = _int_at_least(1)
_seed = _int_at_least(0)


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "run",
        help="run a stiffness test on the simulated bench and evaluate it",
        description="Run a GB-style stiffness test (−T → 0 → +T → 0 → −T; conditioning loop, then N loops) on the "
        "simulated bench and print the evaluation (rigidity, lost motion, backlash) next to the simulated "
        "reducer's true values.",
    )
    add_bench_config_options(p)
    p.add_argument("--reducer", default=None, metavar="NAME", help="catalogue reducer (default: [sim] reducer)")
    p.add_argument("--max-torque", type=_positive, default=None, metavar="NM",
                   help="test torque T in N·m (default: the reducer's rated torque)")
    p.add_argument("--cycles", type=_count, default=None, metavar="N", help="evaluated loops (default 3)")
    p.add_argument("--conditioning", type=_count, default=None, metavar="N",
                   help="conditioning loops before the evaluated ones (default 1)")
    p.add_argument("--seed", type=_seed, default=None, metavar="S", help="noise seed (default: [sim] seed)")
    p.add_argument("--profile", choices=("continuous", "stepped"), default=None,
                   help="continuous torque rate or equal steps with dwell (default: [procedure] kind)")
    p.add_argument("--rate", type=_positive, default=None, metavar="NM_PER_S",
                   help="loading rate in N·m/s (default: a quarter of the test torque per second)")
    p.add_argument("--step", type=_positive, default=None, metavar="NM", help="stepped profile: torque step")
    p.add_argument("--dwell", type=float, default=None, metavar="S", help="stepped profile: dwell per step")
    p.add_argument("--positions", type=_positions, default=None, metavar="N|DEG,DEG,…",
                   help=f"test at several output positions (GB/T 40731): N equally spaced over 360° (1…{MAX_POSITIONS}) "
                   "or a list of degrees; the loader turns the output between them at zero torque")
    p.add_argument("--rates", type=_rates, default=None, metavar="R1,R2,…",
                   help="the same test at each of these loading rates (N·m/s); prints the rate sensitivity")
    p.add_argument("--move-velocity", type=_positive, default=None, metavar="DEG_PER_S",
                   help="output speed of the moves between positions (default 30 °/s)")
    p.add_argument("--out", type=Path, default=None, metavar="FILE.csv",
                   help="write the evaluated samples as canonical CSV")
    p.add_argument("--speed", type=_positive, default=None, metavar="X",
                   help="real-protocol benches: the simulators' speed (tcms sim serve --speed; default 1); "
                   "in-process bench: pace the simulated clock at X × real time (default: as fast as possible)")
    p.add_argument("--no-compensation", action="store_true",
                   help="evaluate the raw encoder: skip the bench's compensator ([bench] compensation)")
    add_decision_rule_option(p, default=None)
    turning = p.add_argument_group("turning tests (a bench with its second axis: e.g. --config bench-station.toml)")
    turning.add_argument("--method", choices=METHODS, default="stiffness",
                         help="the test: the stiffness test (default) or a turning test of the input (GB/T 35089 §7–8)")
    turning.add_argument("--input-speed", type=_positive, default=None, metavar="RPM",
                         help="transmission-error, efficiency: the input's speed (rpm)")
    turning.add_argument("--load", type=_positive, default=None, metavar="NM",
                         help="transmission-error: the light braking load (default 2 %% of rated); efficiency: the "
                         "braking torque (default the rated torque)")
    turning.add_argument("--revolutions", type=_positive, default=None, metavar="N",
                         help="transmission-error: output revolutions per direction (default 1.15)")
    turning.add_argument("--ramps", type=_count, default=None, metavar="N",
                         help="starting-torque: breakaways per direction (default 3)")
    turning.add_argument("--creep", type=_positive, default=None, metavar="DEG_PER_S",
                         help="starting-torque: the input's creep velocity while it sticks (default 0.05 deg/s)")
    turning.add_argument("--speeds", type=_speeds, default=None, metavar="RPM,RPM,…",
                         help="no-load-torque: the input speeds (default ¼, ½ and 1 × the rated input speed)")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of the table")
    p.set_defaults(func=run)


def _speeds(text: str) -> list[float]:
    """``--speeds N1,N2,…``: input speeds in rpm."""
    try:
        values = [float(part) for part in text.split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a list of numbers: {text!r}") from None
    if not values or any(not v > 0 for v in values):
        raise argparse.ArgumentTypeError(f"speeds must be numbers > 0 rpm, got {text!r}")
    return values


@dataclass
class SimulatedRun:
    """What a simulated run produced: the whole record, the evaluated part, the profile and the truth."""

    config: BenchConfig
    reducer: ReducerSpec
    profile: Profile
    seed: int
    record: Samples
    evaluated: Samples
    truth: dict[str, Any] | None
    compensation: str = "identity"
    plan: Plan | None = None
    stage_truths: list[dict[str, Any]] | None = None  # per stage of a plan of several (simulated benches)
    gap_warnings: tuple[str, ...] = ()  # the loops left out of ``evaluated`` for a gap in the data


def simulate(cfg: BenchConfig, reducer: ReducerSpec, profile: Profile | Plan, seed: int | None = None,
             progress=None, speed: float | None = None, compensate: bool = True) -> SimulatedRun:
    """Run ``profile`` (or a plan of several positions or rates) through the acquisition layer on the bench ``cfg`` composes (the in-process simulated
    bench for virtual instruments, else the configured real-protocol instruments).

    Raises TcmsError when the test does not complete (the message carries the state and the reason); the
    samples recorded so far are on the exception as ``record``.
    """

    from tcms_daq.acquisition import ProfileRejected, TestRun, compose_bench
    from tcms_daq.acquisition.bench import identity_compensator
    from tcms_daq.sim.bench import SimulatedBench

    config_dir = Path(cfg.source_path).parent if cfg.source_path else None
    built: list[SimulatedBench] = []  # the in-process bench's physics, kept for its truth

    def factory(config: Any) -> SimulatedBench:
        built.append(SimulatedBench.from_config(config, reducer=reducer, seed=seed))
        return built[-1]

    bench = compose_bench(cfg, config_dir=config_dir, speed=speed, physics_factory=factory,
                          compensator=None if compensate else identity_compensator)
    compensation = bench.description.get("compensation", "identity") if compensate else "none (--no-compensation)"
    in_process = bench.clock.stepped
    if not in_process and seed is not None:
        raise TcmsError("--seed applies to the in-process simulated bench only (the simulators' seed is their "
                        "config's [sim] seed)")
    plan = profile if isinstance(profile, Plan) else single_plan(profile)
    subscribers = []
    if progress is not None:
        def on_message(msg) -> None:
            if msg.kind == "event" and msg.event == "progress":
                progress(msg.details)

        subscribers.append(on_message)
    try:
        run = TestRun(bench, plan if plan.kind != "single" else plan.first, reducer_torque_limit_nm=REDUCER_TORQUE_HEADROOM * reducer.rated_torque_nm,
                      subscribers=subscribers, profile_info={"reducer": reducer.name})
    except ProfileRejected as exc:
        raise TcmsError(str(exc)) from None
    rec = run.run()
    record = rec.samples
    if rec.state != "completed":
        err = TcmsError(f"test {rec.state}: {rec.reason} ({len(record)} samples recorded)")
        err.record = record  # type: ignore[attr-defined]
        raise err
    truths: list[dict[str, Any]] | None = None
    if in_process:
        physics = built[0]
        truths = _truths(physics, plan, reducer)
        used_seed = physics.seed
    else:
        # the simulators run the config's [sim] physics: its truth is known when the config has that table
        if "sim" in cfg.model_fields_set:
            truths = _truths(SimulatedBench.from_config(cfg, reducer), plan, reducer)
            for t in truths:
                t["source"] = "[sim] of the config (what tcms sim serve simulates when given the same file)"
        used_seed = cfg.sim.seed
    truth = None if truths is None else (truths[0] if len(truths) == 1 else _worst_truth(truths))
    exclusion = exclude_gapped_loops(rec.evaluated_samples(), cfg.gaps.limits())
    if exclusion.reason is not None:
        raise TcmsError(f"test failed: {exclusion.reason}")
    return SimulatedRun(cfg, reducer, plan.first, used_seed, record, exclusion.samples, truth, compensation,
                        plan, truths if plan.kind != "single" else None, tuple(exclusion.warnings))


def _truths(sim_bench, plan: Plan, reducer: ReducerSpec) -> list[dict[str, Any]]:
    """The simulated reducer's exact characteristics for each stage of the test (its position, its rate), with
    the physics parameters behind them."""
    out = []
    for stage in plan.stages:
        truth = jsonable(sim_bench.profile_truth(stage.profile.segments, stage.profile.test_torque_nm,
                                                 stage.position_deg or 0.0, reducer.lost_motion_pct))
        truth["physics"] = {k: v for k, v in sim_bench.physics.to_dict().items() if k != "name"}
        truth["reducer_model"] = "rich" if getattr(sim_bench, "rich_model", None) is not None else "simple"
        out.append(truth)
    return out


def _worst_truth(truths: list[dict[str, Any]]) -> dict[str, Any]:
    """The truth of a plan's summary: the same worst-over-stages rule as the evaluation's summary."""
    from tcms_daq.procedure.evaluation import SUMMARY_QUANTITIES

    out = dict(truths[0])
    for key, rule in SUMMARY_QUANTITIES:
        values = [t[key] for t in truths]
        out[key] = min(values) if rule == "min" else max(values)
    out.pop("position_deg", None)
    return out


def _uncertainty_options(result: SimulatedRun, rule: str | None) -> dict[str, Any]:
    """The bench config's declared chain and decision rule (``rule`` overrides its [bench] decision_rule)."""
    cfg = result.config
    return {"chain": cfg.chain_uncertainty(), "rule": rule or cfg.bench.decision_rule,
            "no_chain_basis": f"type A only (no uncertainty declared in {cfg.source_path or 'the bench config'})"}


def evaluate_run(result: SimulatedRun, rule: str | None = None):
    """The evaluation of a single test with the uncertainty the bench config declares and its decision rule."""
    from tcms_daq.procedure.evaluation import evaluate_for_reducer

    ev = evaluate_for_reducer(result.evaluated, result.reducer, result.profile.test_torque_nm,
                              **_uncertainty_options(result, rule))
    ev.warnings[:0] = result.gap_warnings
    if result.compensation.startswith("none") and result.config.bench.compensation:
        ev.uncertainty_basis = (f"{ev.uncertainty_basis}; compensation skipped: the measuring chain's geometric "
                                "errors it corrects are not in U")
    return ev


def evaluate_plan_run(result: SimulatedRun, rule: str | None = None) -> dict[str, Any]:
    """The evaluation of a test at several positions or rates: the summary with its per-position/per-rate entries
    (each with its uncertainty and, on a simulated bench, its stage's truth)."""
    from tcms_daq.procedure.evaluation import evaluate_plan

    out = evaluate_plan(result.evaluated, result.plan, result.reducer, **_uncertainty_options(result, rule))
    if result.gap_warnings:
        prepend_warnings(out, result.gap_warnings)
    if result.stage_truths is not None:
        for entry, truth in zip(out.get("positions") or out.get("rates") or [], result.stage_truths, strict=True):
            entry["truth"] = {k: v for k, v in truth.items() if k != "physics"}
    return out


def _plan_from_args(cfg: BenchConfig, catalogue: dict[str, ReducerSpec], args: argparse.Namespace
                    ) -> TestPlan | MethodTestPlan:
    """The test the options ask for (``plan_from_request``: the one limit policy), over the config's
    ``[procedure]`` and ``[sim] reducer``."""
    if args.dwell is not None and args.dwell < 0:
        raise TcmsError(f"--dwell must be >= 0 s, got {args.dwell}")
    if args.rates is not None and args.rate is not None:
        raise TcmsError("--rate and --rates exclude each other")
    method = getattr(args, "method", "stiffness")
    turning = {"input_speed_rpm": getattr(args, "input_speed", None), "load_torque_nm": getattr(args, "load", None),
               "revolutions": getattr(args, "revolutions", None), "ramps": getattr(args, "ramps", None),
               "creep_deg_per_s": getattr(args, "creep", None), "speeds_rpm": getattr(args, "speeds", None)}
    try:
        request = PlanRequest(
            reducer=args.reducer or cfg.sim.reducer, max_torque_nm=args.max_torque, profile=args.profile,
            cycles=args.cycles, conditioning_loops=args.conditioning, rate_nm_per_s=args.rate, step_nm=args.step,
            dwell_s=args.dwell, positions=args.positions, rates=args.rates,
            move_velocity_deg_per_s=args.move_velocity, decision_rule=args.decision_rule, method=method,
            **{k: v for k, v in turning.items() if v is not None})
    except ValidationError as exc:
        message = str(exc.errors()[0]["msg"]).removeprefix("Value error, ")
        for field, option in OPTION_OF_FIELD.items():
            message = message.replace(field, option)
        raise TcmsError(message) from None
    try:
        return plan_from_request(request, cfg, catalogue)
    except PlanRejected as exc:
        where = cfg.source_path or "the config"
        source = cfg.resolve(cfg.bench.reducers) if str(exc).startswith("unknown reducer") else f"[bench] in {where}"
        raise TcmsError(f"{exc} ({source})") from None


#: the option of each request field, for the messages of the CLI
OPTION_OF_FIELD = {"input_speed_rpm": "--input-speed", "load_torque_nm": "--load", "revolutions": "--revolutions",
                   "creep_deg_per_s": "--creep", "speeds_rpm": "--speeds", "max_torque_nm": "--max-torque",
                   "conditioning_loops": "--conditioning", "rate_nm_per_s": "--rate", "step_nm": "--step",
                   "dwell_s": "--dwell", "move_velocity_deg_per_s": "--move-velocity",
                   "decision_rule": "--decision-rule", "ramps": "--ramps"}


def _analyze_hint(path: Path, result: SimulatedRun) -> str:
    r, p = result.reducer, result.profile
    cmd = f"tcms analyze {path} --rated-torque {r.rated_torque_nm:g} --test-torque {p.test_torque_nm:g}"
    if r.lost_motion_pct != 3.0:
        cmd += f" --lost-motion-pct {r.lost_motion_pct:g}"
    if r.hd_breakpoints_nm is not None:
        cmd += " --hd-breakpoints {:g} {:g}".format(*r.hd_breakpoints_nm)
    return cmd


def _write_samples(path: Path, samples: Samples) -> None:
    present = samples.columns()
    try:
        write_csv(path, samples, [c for c in CSV_COLUMNS if c in present])
    except OSError as exc:
        raise TcmsError(f"{path}: cannot write ({exc.strerror or exc})") from None


def _progress_text(event: dict[str, Any]) -> str:
    """'position 2/4 · loop 1/3' (conditioning, moving …) of a progress event."""
    parts = []
    if event.get("positions", 1) > 1:
        parts.append(f"position {event['position']}/{event['positions']}")
    elif event.get("stages", 1) > 1:
        parts.append(f"rate {event['stage']}/{event['stages']}")
    loop = event.get("loop", -1)
    parts.append("moving" if event.get("moving") else
                 "conditioning" if loop == 0 else f"loop {loop}/{event['loops']}" if loop > 0 else "approach")
    return " · ".join(parts)


def real_eta_s(eta_clock_s: float, elapsed_clock_s: float, elapsed_real_s: float) -> float | None:
    """The ETA in real seconds from the test clock's (a simulated clock runs faster or slower than the wall
    clock): the clock's seconds left times the real seconds each clock second has taken so far; None before
    a clock second has passed (no pace to scale by yet)."""
    if elapsed_clock_s <= 0.5 or elapsed_real_s <= 0:
        return None
    return eta_clock_s * elapsed_real_s / elapsed_clock_s


def run(args: argparse.Namespace) -> int:
    if args.out is not None and not args.out.parent.is_dir():  # fail before the test, not after it
        raise TcmsError(f"{args.out}: cannot write (no directory {args.out.parent})")
    cfg = load_bench_config(args.config, args.overrides)
    planned = _plan_from_args(cfg, load_reducers_for(cfg), args)
    if isinstance(planned, MethodTestPlan):
        from tcms_daq.cli.run_method import run_method_test

        return run_method_test(args, cfg, planned)
    test = planned
    reducer, plan = test.reducer, test.plan

    bar = None
    progress = None
    if sys.stderr.isatty():
        from tqdm import tqdm

        total_s = plan.duration_s()
        # the bar counts the test's own (clock) seconds; the ETA beside it is in real seconds
        bar = tqdm(total=round(total_s, 1), unit="s", desc=f"{reducer.name} (test time)", file=sys.stderr,
                   leave=False, bar_format="{desc}: {percentage:3.0f}%|{bar}| {n:.0f}/{total:.0f} s {postfix}")
        origin: list[float] = []  # (real, clock) time of the first event: the pace is measured from there

        def progress(event: dict[str, Any]) -> None:
            done_s = float(event.get("elapsed_s", 0.0))
            eta_s = float(event.get("eta_s", 0.0))
            bar.total = round(done_s + eta_s, 1) or bar.total
            bar.n = round(min(done_s, bar.total), 1)
            if not origin:
                origin.extend((time.monotonic(), done_s))
            left = real_eta_s(eta_s, done_s - origin[1], time.monotonic() - origin[0])
            shown = "–" if left is None else f"{left:.0f}"
            bar.set_postfix_str(f"{_progress_text(event)}, ETA {shown} s (real time)", refresh=False)
            bar.refresh()

    try:
        result = simulate(cfg, reducer, plan, seed=args.seed, progress=progress, speed=args.speed,
                          compensate=not args.no_compensation)
    except TcmsError as exc:
        kept = getattr(exc, "record", None)
        if args.out is not None and kept is not None and len(kept):
            _write_samples(args.out, kept)
            raise TcmsError(f"{exc}; samples written to {args.out}") from None
        raise
    finally:
        if bar is not None:
            bar.close()
    evaluation = evaluate_run(result, test.decision_rule) if plan.kind == "single" else None
    ev = evaluation.to_dict() if evaluation is not None else evaluate_plan_run(result, test.decision_rule)

    if args.out is not None:
        _write_samples(args.out, result.evaluated)

    if args.json:
        out = {
            **ev,
            "reducer": reducer.name,
            "seed": result.seed,
            "profile": {**result.profile.to_dict(), **(plan.to_dict() if plan.kind != "single" else {})},
            "truth": result.truth,
            "sample_rate_hz": cfg.sim.sample_rate_hz,
            "n_samples_recorded": len(result.record),
            "compensation": result.compensation,
        }
        if args.out is not None:
            out["out"] = str(args.out)
        print(json.dumps(out, allow_nan=False))
        return 0

    p, t = result.profile, result.truth
    print(f"{result.config.bench.name}: {reducer.name}, {p.kind} profile ±{p.test_torque_nm:g} N·m at "
          f"{p.mean_rate_nm_per_s:.4g} N·m/s, {p.conditioning_loops} conditioning + {p.cycles} loops, "
          f"seed {result.seed}, {len(result.record)} samples ({plan.duration_s():.1f} s planned)")
    print(f"compensation: {result.compensation}")
    if evaluation is not None:
        from tcms_daq.analysis import format_evaluation

        print(format_evaluation(evaluation))
    else:
        print(format_plan(ev))
    print()
    if t is not None:
        print(f"simulated truth: rigidity {t['rigidity_nm_per_arcmin']:.2f} N·m/arcmin, lost motion "
              f"{t['lost_motion_arcsec']:.2f}″, backlash {t['backlash_arcsec']:.2f}″"
              + ("" if t.get("k1_nm_per_rad") is None else
                 ", K1/K2/K3 " + "/".join(f"{t[k]:.4g}" for k in ("k1_nm_per_rad", "k2_nm_per_rad", "k3_nm_per_rad")
                                          if t.get(k) is not None) + " N·m/rad")
              + (" (worst over the stages)" if plan.kind != "single" else ""))
    if args.out is not None and plan.kind != "single":
        print(f"wrote {len(result.evaluated)} samples to {args.out} (column stage_index: the stage of each sample; "
              "tcms analyze evaluates one stage's rows at a time)")
    elif args.out is not None:
        print(f"wrote {len(result.evaluated)} samples to {args.out}; re-evaluate with: {_analyze_hint(args.out, result)}")
    return 0


def format_plan(ev: dict[str, Any]) -> str:
    """A table of a plan's stages (position or rate; rigidity, lost motion, backlash as value ± U; truth when
    known), its summary (max, min, spread), for rates the rate sensitivity, and the decision."""
    from tcms_daq.analysis.rounding import with_uncertainty

    entries = ev.get("positions") or ev.get("rates") or []
    positional = "positions" in ev
    columns = (("rigidity_nm_per_arcmin", "rigidity N·m/arcmin", 28), ("lost_motion_arcsec", "lost motion ″", 22),
               ("backlash_arcsec", "backlash ″", 22))
    lines = [f"{'position °' if positional else 'rate N·m/s':>11} "
             + " ".join(f"{label:>{width}}" for _, label, width in columns)
             + "   truth (rigidity / lost motion / backlash)"]
    for e in entries:
        key = f"{e['position_deg']:.1f}" if positional else f"{e['rate_nm_per_s']:g}"
        truth = e.get("truth")
        truth_text = ("" if truth is None else f"{truth['rigidity_nm_per_arcmin']:.2f} / "
                      f"{truth['lost_motion_arcsec']:.2f} / {truth['backlash_arcsec']:.2f}")
        uncertainty = e.get("uncertainty") or {}
        cells = [with_uncertainty(e[q], uncertainty.get(q), unit="").replace(" (U not stated)", "")
                 for q, _, _ in columns]
        lines.append(f"{key:>11} " + " ".join(f"{c:>{w}}" for c, (_, _, w) in zip(cells, columns, strict=True))
                     + f"   {truth_text}")
    for quantity, unit in (("rigidity_nm_per_arcmin", "N·m/arcmin"), ("lost_motion_arcsec", "″"),
                           ("backlash_arcsec", "″")):
        lines.append(f"{quantity}: max {ev[quantity + '_max']:.2f}, min {ev[quantity + '_min']:.2f}, spread "
                     f"{ev[quantity + '_spread']:.2f} {unit}")
    sensitivity = ev.get("rate_sensitivity")
    if sensitivity:
        lines.append("rate sensitivity (per tenfold loading rate): " + ", ".join(
            f"{k.removesuffix('_per_decade')} {v:+.3g}" for k, v in sensitivity.items()
            if k.endswith("_per_decade") and v is not None))
    if not any(e.get("uncertainty") for e in entries):
        lines.append("U not stated")
    verdict = ev.get("verdict")
    if verdict:
        from tcms_daq.analysis.evaluation import decision_of

        decision = decision_of(verdict) or "fail"
        rule = f" (ISO 14253-1, {verdict['rule']} rule)" if verdict.get("rule") else ""
        lines.append(f"decision (worst over the stages): {decision.upper()}{rule}")
    return "\n".join(lines)
