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

from tcms_daq.cli.options import add_bench_config_options, add_decision_rule_option
from tcms_daq.config import (
    BenchConfig,
    ReducerSpec,
    get_reducer,
    load_bench_config,
    load_reducers_for,
)
from tcms_daq.errors import TcmsError
from tcms_daq.procedure import Profile, build_profile, check_test_bounds
from tcms_daq.samples import Samples, write_csv

CSV_COLUMNS = ("time_s", "torque_nm", "angle_arcsec", "encoder_arcsec", "applied_torque_nm", "true_angle_arcsec",
               "loop_index")


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
    p.add_argument("--out", type=Path, default=None, metavar="FILE.csv",
                   help="write the evaluated samples as canonical CSV")
    p.add_argument("--speed", type=_positive, default=None, metavar="X",
                   help="real-protocol benches: the simulators' speed (tcms sim serve --speed; default 1); "
                   "in-process bench: pace the simulated clock at X × real time (default: as fast as possible)")
    p.add_argument("--no-compensation", action="store_true",
                   help="evaluate the raw encoder: skip the bench's compensator ([bench] compensation)")
    add_decision_rule_option(p, default=None)
    p.add_argument("--json", action="store_true", help="print one JSON object instead of the table")
    p.set_defaults(func=run)


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


def simulate(cfg: BenchConfig, reducer: ReducerSpec, profile: Profile, seed: int | None = None,
             progress=None, speed: float | None = None, compensate: bool = True) -> SimulatedRun:
    """Run ``profile`` through the acquisition layer on the bench ``cfg`` composes (the in-process simulated
    bench for virtual instruments, else the configured real-protocol instruments).

    Raises TcmsError when the test does not complete (the message carries the state and the reason); the
    samples recorded so far are on the exception as ``record``.
    """

    from sim.bench import SimulatedBench
    from tcms_daq.acquisition import ProfileRejected, TestRun, compose_bench
    from tcms_daq.acquisition.bench import identity_compensator

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
    subscribers = []
    if progress is not None:
        total_s = profile.duration_s()
        first: list[float] = []

        def on_message(msg) -> None:
            if msg.kind == "data" and len(msg.samples):
                first[:1] = first[:1] or [float(msg.samples.time_s[0])]
                progress(min(float(msg.samples.time_s[-1]) - first[0], total_s), total_s)

        subscribers.append(on_message)
    try:
        run = TestRun(bench, profile, reducer_torque_limit_nm=1.1 * reducer.rated_torque_nm,
                      subscribers=subscribers, profile_info={"reducer": reducer.name})
    except ProfileRejected as exc:
        raise TcmsError(str(exc)) from None
    rec = run.run()
    record = rec.samples
    if rec.state != "completed":
        err = TcmsError(f"test {rec.state}: {rec.reason} ({len(record)} samples recorded)")
        err.record = record  # type: ignore[attr-defined]
        raise err
    if in_process:
        physics = built[0]
        truth = _truth(physics, profile, reducer)
        used_seed = physics.seed
    else:
        # the simulators run the config's [sim] physics: its truth is known when the config has that table
        truth = None
        if "sim" in cfg.model_fields_set:
            truth = _truth(SimulatedBench.from_config(cfg, reducer), profile, reducer)
            truth["source"] = "[sim] of the config (what tcms sim serve simulates when given the same file)"
        used_seed = cfg.sim.seed
    return SimulatedRun(cfg, reducer, profile, used_seed, record, rec.evaluated_samples(), truth, compensation)


def _truth(sim_bench, profile: Profile, reducer: ReducerSpec) -> dict[str, Any]:
    """The simulated reducer's exact characteristics for this test, with the physics parameters behind them."""
    truth = sim_bench.truth(profile.test_torque_nm, reducer.lost_motion_pct).to_dict()
    truth["physics"] = {k: v for k, v in sim_bench.physics.to_dict().items() if k != "name"}
    return truth


def evaluate_run(result: SimulatedRun, rule: str | None = None):
    """The evaluation of a run with the uncertainty the bench config declares and its decision rule (``rule``
    overrides the config's [bench] decision_rule)."""
    from tcms_daq.procedure.evaluation import evaluate_for_reducer

    cfg = result.config
    chain = cfg.chain_uncertainty()
    without = f"type A only (no uncertainty declared in {cfg.source_path or 'the bench config'})"
    ev = evaluate_for_reducer(result.evaluated, result.reducer, result.profile.test_torque_nm, chain=chain,
                              rule=rule or cfg.bench.decision_rule, no_chain_basis=without)
    if result.compensation.startswith("none") and cfg.bench.compensation:
        ev.uncertainty_basis = (f"{ev.uncertainty_basis}; compensation skipped: the measuring chain's geometric "
                                "errors it corrects are not in U")
    return ev


def _profile_from_args(cfg: BenchConfig, reducer: ReducerSpec, args: argparse.Namespace) -> Profile:
    overrides = {
        "kind": args.profile,
        "max_torque_nm": args.max_torque,
        "cycles": args.cycles,
        "conditioning_loops": args.conditioning,
        "rate_nm_per_s": args.rate,
        "step_nm": args.step,
        "dwell_s": args.dwell,
    }
    data = cfg.procedure.model_dump()
    data.update({k: v for k, v in overrides.items() if v is not None})
    if data["dwell_s"] < 0:
        raise TcmsError(f"--dwell must be >= 0 s, got {data['dwell_s']}")
    from tcms_daq.config import load_test_profile

    test = load_test_profile(data, source=cfg.source_path or "<config>")
    try:
        check_test_bounds(test, test.max_torque_nm or reducer.rated_torque_nm, cfg.bench)
    except ValueError as exc:
        raise TcmsError(f"{exc} ([bench] in {cfg.source_path or 'the config'})") from None
    profile = build_profile(test, reducer)
    if profile.test_torque_nm > cfg.bench.max_torque_nm:
        raise TcmsError(
            f"test torque {profile.test_torque_nm:g} N·m exceeds the bench limit {cfg.bench.max_torque_nm:g} N·m "
            f"([bench] max_torque_nm in {cfg.source_path})"
        )
    return profile


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


def run(args: argparse.Namespace) -> int:
    if args.out is not None and not args.out.parent.is_dir():  # fail before the test, not after it
        raise TcmsError(f"{args.out}: cannot write (no directory {args.out.parent})")
    cfg = load_bench_config(args.config, args.overrides)
    catalogue = load_reducers_for(cfg)
    reducer = get_reducer(catalogue, args.reducer or cfg.sim.reducer, cfg.resolve(cfg.bench.reducers))
    profile = _profile_from_args(cfg, reducer, args)

    bar = None
    progress = None
    if sys.stderr.isatty():
        from tqdm import tqdm

        bar = tqdm(total=round(profile.duration_s(), 1), unit="s", desc=f"{reducer.name} (sim time)",
                   file=sys.stderr, leave=False)

        drawn_at = [0.0]

        def progress(done_s: float, total_s: float) -> None:
            now = time.monotonic()
            if now - drawn_at[0] >= 0.1 or done_s >= total_s:  # redraw at most 10 times a second
                drawn_at[0] = now
                bar.n = round(done_s, 1)
                bar.refresh()

    try:
        result = simulate(cfg, reducer, profile, seed=args.seed, progress=progress, speed=args.speed,
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
    ev = evaluate_run(result, args.decision_rule)

    if args.out is not None:
        _write_samples(args.out, result.evaluated)

    if args.json:
        out = {
            **ev.to_dict(),
            "reducer": reducer.name,
            "seed": result.seed,
            "profile": result.profile.to_dict(),
            "truth": result.truth,
            "sample_rate_hz": cfg.sim.sample_rate_hz,
            "n_samples_recorded": len(result.record),
            "compensation": result.compensation,
        }
        if args.out is not None:
            out["out"] = str(args.out)
        print(json.dumps(out, allow_nan=False))
        return 0

    from tcms_daq.analysis import format_evaluation

    p, t = result.profile, result.truth
    print(f"{result.config.bench.name}: {reducer.name}, {p.kind} profile ±{p.test_torque_nm:g} N·m at "
          f"{p.mean_rate_nm_per_s:.4g} N·m/s, {p.conditioning_loops} conditioning + {p.cycles} loops, "
          f"seed {result.seed}, {len(result.record)} samples ({p.duration_s():.1f} s simulated)")
    print(f"compensation: {result.compensation}")
    print(format_evaluation(ev))
    print()
    if t is not None:
        print(f"simulated truth: rigidity {t['rigidity_nm_per_arcmin']:.2f} N·m/arcmin, lost motion "
              f"{t['lost_motion_arcsec']:.2f}″, backlash {t['backlash_arcsec']:.2f}″"
          + ("" if t.get("k1_nm_per_rad") is None else
             ", K1/K2/K3 " + "/".join(f"{t[k]:.4g}" for k in ("k1_nm_per_rad", "k2_nm_per_rad", "k3_nm_per_rad")
                                      if t.get(k) is not None) + " N·m/rad"))
    if args.out is not None:
        print(f"wrote {len(result.evaluated)} samples to {args.out}; re-evaluate with: {_analyze_hint(args.out, result)}")
    return 0
