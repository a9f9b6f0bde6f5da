"""Do the discrepancy workflow's standard uncertainties cover the truth? Coverage over seeds, per effect and family.

For every run where the hidden effect is named, the named primary parameter x, its standard uncertainty u (k = 1,
``result.uncertainties``) and the truth x₀ give z = (x − x₀)/u. Over seeds, per effect (hidden-effect trials) or
family, grid and rate (independent-physics generator), the table gives n (runs where it was named / runs), the share
of |z| ≤ 1 and ≤ 2, the same with the Student t-factor for the g − 1 degrees of freedom of the delete-one-group
jackknife (t₆₈, and U = t₉₅·u as the workflow states it), the median |z|, the number of groups g, and what the under-coverage is made of: the mean
error over seeds against the RMS u (a bias common to every group, which no jackknife over the groups can see) and
the standard deviation of the errors over seeds against the RMS u (the jackknife's own accuracy).

Sources:

* ``trials`` — the simulated bench with the catalogue's forms hidden (``sim.trials``: 50 Hz, 3 + 3 loops); the
  truth is the hidden parameter.
* ``independent`` — the independent-physics generator (``sim.independent``); its truth is physical. Where the
  catalogue's form is not the physics the truth compared is: a play operator of width w → ``backlash_arcsec`` = w;
  a sin/cos gain imbalance g → the half-period sinusoid's amplitude |g/(2+g)|·P/2π (first order); a transport
  delay τ → ``skew_s`` = τ; a torque reading offset T0 → ``offset_nm`` = T0.

    python -m tcms_daq.sim.coverage --source trials --seeds 30 [--amplitude-scale 0.5] [--case NAME] [--diagnose]
    python -m tcms_daq.sim.coverage --source independent --seeds 10 --rate-hz 50 --rate-hz 1000 --grid both
    python -m tcms_daq.sim.coverage --matrix --from-jsonl RUNS.jsonl [--from-jsonl …]

Long (the workflow 0.5–1.5 s a run at 50 Hz, 2–15 s at 1 kHz, at load 3–9, plus making the data): not a test. Each run is printed to
stderr as it ends (one JSON line), which ``--from-jsonl`` reads back. docs/discrepancy.md has the measured table.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import asdict, dataclass

import numpy as np

from tcms_daq.discrepancy import effects as fx
from tcms_daq.discrepancy.workflow import coverage_factor


@dataclass(frozen=True)
class CoverageRun:
    """One named (or not named) hidden parameter of one run."""

    source: str  # "trials" or "independent"
    label: str  # the case, or family@grid@rate
    effect: str  # catalogue name
    seed: int
    truth: float
    value: float | None  # None: not named
    u: float | None  # standard uncertainty (k = 1); None: not named or not estimated
    groups: int  # the jackknife's groups g
    group_kind: str
    seconds: float
    jack_bias: float | None = None  # --diagnose: the jackknife's bias estimate (g − 1)(mean of leave-one-out − value)
    null_value: float | None = None  # --diagnose, trials: the same terms fitted on the same seed with nothing hidden

    @property
    def z(self) -> float | None:
        if self.value is None or not self.u:
            return None
        return (self.value - self.truth) / self.u


def summarise(runs: list[CoverageRun]) -> dict[str, dict[str, float | int | str]]:
    """Per (source, label, effect): n named / runs, shares within 1u, 2u, t₆₈·u, t₉₅·u, median |z|, median g, and
    the relative mean error, the relative SD of errors over seeds and the RMS relative u (all in % of the truth),
    with bias/u = mean error / RMS u and sd/u = SD of errors / RMS u."""
    out: dict[str, dict[str, float | int | str]] = {}
    for key in dict.fromkeys((r.source, r.label, r.effect) for r in runs):
        rs = [r for r in runs if (r.source, r.label, r.effect) == key]
        named = [r for r in rs if r.z is not None]
        row: dict[str, float | int | str] = {"source": key[0], "label": key[1], "effect": key[2], "runs": len(rs),
                                             "n": len(named)}
        if named:
            z = np.array([abs(r.z) for r in named if r.z is not None])
            g = np.array([r.groups for r in named], dtype=float)
            t68 = np.array([coverage_factor(int(gi) - 1, 0.6827) for gi in g])
            t95 = np.array([coverage_factor(int(gi) - 1) for gi in g])  # the workflow's U = k·u, about 95 %
            err = np.array([(r.value or 0.0) - r.truth for r in named])
            u = np.array([r.u or 0.0 for r in named])
            truth = abs(named[0].truth)
            rms_u = float(np.sqrt(np.mean(u ** 2)))
            row.update({
                "within_1u": float(np.mean(z <= 1)), "within_2u": float(np.mean(z <= 2)),
                "within_t68u": float(np.mean(z <= t68)), "within_t95u": float(np.mean(z <= t95)),
                "median_abs_z": float(np.median(z)), "groups": float(np.median(g)),
                "t68": float(np.median(t68)), "t95": float(np.median(t95)),
                "mean_error_pct": float(100 * err.mean() / truth), "sd_error_pct":
                    float(100 * err.std(ddof=1) / truth) if len(err) > 1 else float("nan"),
                "rms_u_pct": float(100 * rms_u / truth),
                "bias_over_u": float(err.mean() / rms_u) if rms_u else float("nan"),
                "sd_over_u": float(err.std(ddof=1) / rms_u) if rms_u and len(err) > 1 else float("nan"),
            })
        out[" ".join(key)] = row
    return out


def table(summary: dict[str, dict[str, float | int | str]]) -> str:
    """A Markdown table of :func:`summarise`."""
    lines = ["| source | case / family | effect | n | g | ≤ 1u | ≤ 2u | ≤ t₆₈u | ≤ U₉₅ | median abs(z) | "
             "mean err % | sd err % | rms u % | bias/u | sd/u |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for row in summary.values():
        if not row["n"]:
            lines.append(f"| {row['source']} | {row['label']} | {row['effect']} | 0/{row['runs']} | | | | | | | | | | | |")
            continue

        def f(k: str, fmt: str, row: dict[str, float | int | str] = row) -> str:
            return format(row[k], fmt)
        lines.append(f"| {row['source']} | {row['label']} | {row['effect']} | {row['n']}/{row['runs']} | "
                     f"{f('groups', 'g')} | {f('within_1u', '.0%')} | {f('within_2u', '.0%')} | "
                     f"{f('within_t68u', '.0%')} | {f('within_t95u', '.0%')} | {f('median_abs_z', '.2f')} | "
                     f"{f('mean_error_pct', '+.2f')} | {f('sd_error_pct', '.2f')} | {f('rms_u_pct', '.2f')} | "
                     f"{f('bias_over_u', '+.1f')} | {f('sd_over_u', '.1f')} |")
    return "\n".join(lines)


def _row_column(r: CoverageRun) -> tuple[str, str]:
    """(row, column) of a run in :func:`matrix`: the effect (with its companion in a combined trial case) and the
    data it came from (the trials at a size, or the independent generator's grid and rate)."""
    if r.source == "trials":
        case, _, scale = r.label.partition("×")
        row = r.effect if case == r.effect else f"{r.effect} (in {case})"
        return row, f"trials ×{scale or '1'}"
    _family, grid, rate = r.label.split("@")
    return r.effect, f"{rate.replace('Hz', ' Hz')}, {grid.replace('_', ' ')}"


def matrix(runs: list[CoverageRun]) -> str:
    """A Markdown table, an effect per row and a source per column: "≤ 1u / ≤ 2u / ≤ U" (shares of the runs that
    named it, U = k·u the workflow's expanded uncertainty) and n."""
    cells: dict[tuple[str, str], list[CoverageRun]] = {}
    for r in runs:
        cells.setdefault(_row_column(r), []).append(r)
    rows = list(dict.fromkeys(k[0] for k in cells))
    columns = list(dict.fromkeys(k[1] for k in cells))
    lines = ["| effect | " + " | ".join(columns) + " |", "|---|" + "---|" * len(columns)]
    for row in rows:
        out = []
        for col in columns:
            named = [r for r in cells.get((row, col), []) if r.z is not None]
            if not named:
                out.append("")
                continue
            z = np.array([abs(r.z or 0.0) for r in named])
            k = np.array([coverage_factor(r.groups - 1) or np.nan for r in named])
            out.append(f"{np.mean(z <= 1):.0%} / {np.mean(z <= 2):.0%} / {np.mean(z <= k):.0%} ({len(named)})")
        lines.append(f"| {row} | " + " | ".join(out) + " |")
    return "\n".join(lines)


def _diagnose(result: object, name: str) -> float | None:
    """The delete-one-group jackknife's bias estimate of ``name``'s primary parameter, (g − 1)(θ̄₍ᵢ₎ − θ̂)."""
    from tcms_daq.discrepancy.selection import Columns
    from tcms_daq.discrepancy.workflow import jackknife_fits

    data = result.data  # type: ignore[attr-defined]
    names = [n for n, _ in result.model_terms]  # type: ignore[attr-defined]
    if name not in names:
        return None
    primary = fx.REGISTRY[name].primary
    fits = jackknife_fits(Columns(data), data.residual_arcsec, data.groups, names)
    if not fits:
        return None
    value = dict(result.model_terms)[name][primary]  # type: ignore[attr-defined]
    return float((len(fits) - 1) * (np.mean([f[name][primary] for f in fits]) - value))


def _null_fit(measured: object, simulated: object, names: list[str]) -> dict[str, float]:
    """The primary parameters of ``names`` fitted (all rows, nonlinear values scanned) on a pair with nothing
    hidden: what the simulation's own imperfection and the noise give them."""
    from tcms_daq.discrepancy.selection import Columns, fit_model
    from tcms_daq.discrepancy.workflow import run_discrepancy

    data = run_discrepancy(measured, simulated, effects=[]).data  # type: ignore[arg-type]
    cols = Columns(data)
    fitted = fit_model(cols, data.residual_arcsec, np.arange(len(data)), names, rescan=tuple(names)).parameters()
    return {n: float(fitted[n][fx.REGISTRY[n].primary]) for n in names}


def _named(result: object, name: str) -> tuple[float | None, float | None]:
    primary = fx.REGISTRY[name].primary
    for e in result.effects:  # type: ignore[attr-defined]
        if e.name == name:
            return float(e.parameters[primary]), e.standard_uncertainty.get(primary)
    return None, None


def trials_runs(cases: list[str], seeds: list[int], amplitude_scale: float = 1.0, diagnose: bool = False
                ) -> list[CoverageRun]:
    """The hidden-effect trials' catalogue cases (``sim.trials.CASES``) at ``amplitude_scale`` × their typical
    sizes."""
    from tcms_daq.sim.trials import CASES, PRIMARY, make_pair, scaled

    from tcms_daq.discrepancy.workflow import run_discrepancy

    out = []
    for case in cases:
        table_ = scaled(CASES[case], amplitude_scale)
        for seed in seeds:
            measured, simulated, _ = make_pair(table_, seed)
            t0 = time.perf_counter()
            result = run_discrepancy(measured, simulated)
            seconds = time.perf_counter() - t0
            null = _null_fit(*make_pair({}, seed)[:2], list(table_)) if diagnose else {}
            for name, params in table_.items():
                value, u = _named(result, name)
                extra = {"jack_bias": _diagnose(result, name), "null_value": null.get(name)} if diagnose else {}
                label = case if amplitude_scale == 1.0 else f"{case}×{amplitude_scale:g}"
                run = CoverageRun("trials", label, name, seed, float(params[PRIMARY[name]]), value, u,
                                  int(result.groups["count"]), str(result.groups["kind"]), seconds, **extra)
                print(json.dumps(asdict(run)), file=sys.stderr, flush=True)
                out.append(run)
    return out


def independent_runs(families: list[str], seeds: list[int], rates_hz: list[float], grids: list[str],
                     diagnose: bool = False) -> list[CoverageRun]:
    """The independent generator's catalogue families (``sim.independent.FAMILIES`` with a truth)."""
    from tcms_daq.sim.independent import FAMILIES, Programme

    from tcms_daq.discrepancy.workflow import run_discrepancy

    out = []
    for rate in rates_hz:
        programme = Programme(rate_hz=rate)
        for family in families:
            for grid in grids:
                for seed in seeds:
                    run = FAMILIES[family].make(programme, np.random.default_rng([seed, 2026]), grid)
                    t0 = time.perf_counter()
                    result = run_discrepancy(run.measured, run.simulated)
                    seconds = time.perf_counter() - t0
                    for name, truth in run.truth.items():
                        value, u = _named(result, name)
                        jb = _diagnose(result, name) if diagnose else None
                        c = CoverageRun("independent", f"{family}@{grid}@{rate:g}Hz", name, seed, float(truth), value,
                                        u, int(result.groups["count"]), str(result.groups["kind"]), seconds, jb)
                        print(json.dumps(asdict(c)), file=sys.stderr, flush=True)
                        out.append(c)
    return out


def main(argv: list[str] | None = None) -> int:
    from tcms_daq.sim.independent import FAMILIES, GRIDS
    from tcms_daq.sim.trials import CASES

    parser = argparse.ArgumentParser(prog="python -m tcms_daq.sim.coverage", description=__doc__.split("\n")[0])
    parser.add_argument("--source", choices=("trials", "independent"), default="trials")
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--first-seed", type=int, default=None, help="default: 100 (trials), 1 (independent)")
    parser.add_argument("--case", action="append", help="trials: only these catalogue cases")
    parser.add_argument("--amplitude-scale", type=float, default=1.0, help="trials: × the typical sizes")
    parser.add_argument("--family", action="append", help="independent: only these catalogue families")
    parser.add_argument("--rate-hz", type=float, action="append", help="independent: sample rate (default 50)")
    parser.add_argument("--grid", choices=[*GRIDS, "both"], default="same_rows")
    parser.add_argument("--diagnose", action="store_true",
                        help="also the jackknife's bias estimate and (trials) the terms fitted with nothing hidden")
    parser.add_argument("--matrix", action="store_true",
                        help="an effect per row, a source per column: within 1u / 2u / U (docs/discrepancy.md)")
    parser.add_argument("--json", action="store_true", help="the summary and every run as one JSON object")
    parser.add_argument("--from-jsonl", metavar="FILE", action="append",
                        help="summarise runs printed earlier (their stderr lines; repeatable)")
    args = parser.parse_args(argv)
    if args.from_jsonl:
        runs = []
        for path in args.from_jsonl:
            with open(path) as fh:
                runs += [CoverageRun(**json.loads(line)) for line in fh if line.startswith("{")]
    elif args.source == "trials":
        first = 100 if args.first_seed is None else args.first_seed
        cases = args.case or [c for c in CASES if CASES[c]]
        runs = trials_runs(cases, list(range(first, first + args.seeds)), args.amplitude_scale, args.diagnose)
    else:
        first = 1 if args.first_seed is None else args.first_seed
        families = args.family or [f for f, fam in FAMILIES.items() if fam.in_catalogue and f != "null"]
        grids = list(GRIDS) if args.grid == "both" else [args.grid]
        runs = independent_runs(families, list(range(first, first + args.seeds)), args.rate_hz or [50.0], grids,
                                args.diagnose)
    summary = summarise(runs)
    if args.matrix:
        print(matrix(runs))
    elif args.json:
        print(json.dumps({"summary": summary, "runs": [asdict(r) for r in runs]}, indent=1))
    else:
        print(table(summary))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
