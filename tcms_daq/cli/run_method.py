"""``tcms run --method transmission-error | starting-torque | no-load-torque | efficiency``: a turning test.

The test goes through the acquisition layer as the stiffness test does (``tcms_daq.acquisition.methodrun``: the
bench composed from the config, its second axis included, the acquisition in station mode, the procedure's state
machine with its interlocks) and is evaluated by ``tcms_daq.procedure.method_evaluation`` with the budgets of the
config's ``[uncertainty.station]``. On a simulated bench (the in-process one, or the protocol simulators when the
config has the ``[sim]`` they run) each result is printed beside the simulated unit's exact truth and whether it lies
within its U.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
from typing import Any

from tcms_daq.analysis.rounding import with_uncertainty
from tcms_daq.config import BenchConfig
from tcms_daq.errors import TcmsError
from tcms_daq.procedure.plan import MethodTestPlan
from tcms_daq.samples import Samples, write_csv

METHOD_CSV_COLUMNS = ("time_s", "torque_nm", "angle_arcsec", "encoder_arcsec", "input_angle_arcsec", "input_torque_nm",
                      "step_index")


def run_method_test(args: argparse.Namespace, cfg: BenchConfig, test: MethodTestPlan) -> int:
    """Run and print one turning test (``tcms run --method``); 0 when it completed."""
    if args.out is not None and not args.out.parent.is_dir():
        raise TcmsError(f"{args.out}: cannot write (no directory {args.out.parent})")
    result = run_method_on_bench(cfg, test, seed=args.seed, speed=args.speed, compensate=not args.no_compensation)
    results, record, truth = result["results"], result["record"], result["truth"]
    if args.out is not None:
        present = record.columns()
        try:
            write_csv(args.out, record, [c for c in METHOD_CSV_COLUMNS if c in present])
        except OSError as exc:
            raise TcmsError(f"{args.out}: cannot write ({exc.strerror or exc})") from None
    if args.json:
        out = {**results, "truth": truth, "within_u": within_u(results, truth), "seed": result["seed"],
               "n_samples_recorded": len(record), "compensation": result["compensation"],
               "profile": test.summary()}
        if args.out is not None:
            out["out"] = str(args.out)
        print(json.dumps(out, allow_nan=False, default=_json_default))
        return 0
    print(f"{cfg.bench.name}: {test.reducer.name}, {test.method}, "
          + ", ".join(f"{k} {_short(v)}" for k, v in test.method_plan.parameters.items())
          + f"; seed {result['seed']}, {len(record)} samples ({test.method_plan.duration_s():.1f} s planned)")
    print(f"compensation: {result['compensation']}")
    print(format_method_results(results, truth))
    if args.out is not None:
        print(f"wrote {len(record)} samples to {args.out}")
    return 0


def _short(value: Any) -> str:
    if isinstance(value, list):
        return ",".join(f"{v:g}" for v in value)
    return f"{value:g}" if isinstance(value, float) else str(value)


def _json_default(obj: Any) -> Any:
    import numpy as np

    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    raise TypeError(f"{type(obj).__name__} is not JSON serialisable")


def run_method_on_bench(cfg: BenchConfig, test: MethodTestPlan, *, seed: int | None = None, speed: float | None = None,
                        compensate: bool = True, config_dir: Path | None = None) -> dict[str, Any]:
    """Run ``test`` on the bench ``cfg`` composes and evaluate it: ``{"results", "record", "truth", "seed",
    "compensation"}`` (truth None when the bench is not simulated). Raises TcmsError when it does not complete."""
    from tcms_daq.acquisition import compose_bench
    from tcms_daq.acquisition.bench import identity_compensator
    from tcms_daq.acquisition.methodrun import MethodRun
    from tcms_daq.procedure.method_evaluation import evaluate_method
    from tcms_daq.sim.bench import SimulatedBench

    if config_dir is None and cfg.source_path:
        config_dir = Path(cfg.source_path).parent
    built: list[SimulatedBench] = []

    def factory(config: Any) -> SimulatedBench:
        built.append(SimulatedBench.from_config(config, reducer=test.reducer, seed=seed))
        return built[-1]

    bench = compose_bench(cfg, config_dir=config_dir, speed=speed, physics_factory=factory,
                          compensator=None if compensate else identity_compensator)
    in_process = bench.clock.stepped
    if not in_process and seed is not None:
        raise TcmsError("--seed applies to the in-process simulated bench only (the simulators' seed is their "
                        "config's [sim] seed)")
    chain = cfg.uncertainty.station
    source = cfg.source_path or "the bench config"

    def evaluate(samples: Samples) -> dict[str, Any]:
        return evaluate_method(samples, test.method, test.reducer, test.method_plan.parameters, chain=chain,
                               source=source)

    run = MethodRun(bench, test.method_plan, reducer_torque_limit_nm=test.reducer_torque_limit_nm,
                    evaluate=evaluate, profile_info={"reducer": test.reducer.name})
    rec = run.run()
    if rec.state != "completed":
        raise TcmsError(f"test {rec.state}: {rec.reason} ({len(rec.samples)} samples recorded)")
    results = rec.evaluation or {}
    unit, temperature = None, cfg.sim.transmission.temperature_c
    if in_process:
        axis = getattr(getattr(bench.input_drive, "bench", None), "second_axis", None)
        unit = getattr(getattr(axis, "drivetrain", None), "unit", None)
        used_seed: int | None = built[0].seed if built else None
    else:
        if "sim" in cfg.model_fields_set and cfg.sim.transmission.enabled:
            from tcms_daq.config import load_reducers_for
            from tcms_daq.sim.transmission import unit_for_bench

            unit = unit_for_bench(cfg, load_reducers_for(cfg))
        used_seed = cfg.sim.seed
    truth = None
    if unit is not None:
        from tcms_daq.sim.station import method_truth

        truth = method_truth(unit, test.method, results, temperature)
    compensation = (bench.description.get("compensation", "identity") if compensate
                    else "none (--no-compensation)")
    return {"results": results, "record": rec.samples, "truth": truth, "seed": used_seed,
            "compensation": compensation, "notes": list(rec.notes)}


def within_u(results: dict[str, Any], truth: dict[str, float] | None) -> dict[str, bool] | None:
    """For each result with a truth and a U: whether |value − truth| ≤ U."""
    if truth is None:
        return None
    table = results.get("uncertainty") or {}
    out = {}
    for name, expected in truth.items():
        entry = table.get(name)  # a result not found is not within U
        out[name] = entry is not None and bool(abs(float(entry["value"]) - expected) <= float(entry["U"]))
    return out


def headline_names(results: dict[str, Any]) -> list[str]:
    """The method's results in the order a table shows them (headline first, then per direction, then orders)."""
    table = results.get("uncertainty") or {}
    method = results.get("method")
    first = {"transmission-error": ["transmission_error_arcsec", "forward_transmission_error_arcsec",
                                    "reverse_transmission_error_arcsec"],
             "starting-torque": ["starting_torque_nm", "forward_starting_torque_nm", "reverse_starting_torque_nm"],
             "efficiency": ["forward_efficiency", "reverse_efficiency"]}.get(str(method), [])
    rest = [name for name in table if name not in first]
    if method == "transmission-error":
        rest.sort(key=lambda n: float(n.split("_")[2]) if n.startswith("te_order_") else -1.0)
    return [n for n in first if n in table] + rest


def format_method_results(results: dict[str, Any], truth: dict[str, float] | None) -> str:
    """A table: each result as value ± U (k) with its dominant contributor, its truth and whether it lies within U;
    for the transmission error each order's component."""
    table = results.get("uncertainty") or {}
    components = {f"te_order_{ln['order']:.4g}_amplitude_arcsec": ln.get("component") or "(no component)"
                  for ln in results.get("te_orders") or []}
    lines = [f"{'result':<40} {'value ± U (k)':>30}   {'truth':>10}  within U   dominant"]
    for name in headline_names(results):
        entry = table[name]
        unit = entry.get("unit") or ""
        value = with_uncertainty(float(entry["value"]), entry, "").strip()
        expected = None if truth is None else truth.get(name)
        ok = "" if expected is None else ("yes" if abs(float(entry["value"]) - expected) <= float(entry["U"])
                                          else "NO")
        label = name + (f" ({components[name]})" if name in components else "")
        shown = "" if expected is None else f"{expected:.4g}"
        lines.append(f"{label:<40} {value + ' ' + (unit if unit != '1' else ''):>30}   {shown:>10}  {ok:^8}   "
                     f"{entry.get('dominant') or ''}")
    for name, expected in (truth or {}).items():
        if name not in table:  # a result the simulated unit has that the evaluation did not give (an order missed)
            lines.append(f"{name:<40} {'not found':>30}   {expected:>10.4g}  {'NO':^8}")
    if results.get("method") == "transmission-error":
        lines.append(f"hysteresis (forward − reverse mean TE): {results.get('hysteresis_arcsec', math.nan):.2f}″")
    for w in results.get("warnings") or []:
        lines.append(f"warning: {w}")
    lines.append(f"uncertainty: {results.get('uncertainty_basis')}")
    return "\n".join(lines)
