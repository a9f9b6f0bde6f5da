"""Human-readable table of an Evaluation (what `tcms analyze` and `tcms run` print)."""

from __future__ import annotations

from tcms_daq.analysis.evaluation import Evaluation, decision_of, overall_decision
from tcms_daq.analysis.rounding import with_uncertainty

DECISION_WORDS = {"pass": "PASS", "fail": "FAIL", "undecided": "UNDECIDED"}


def _num(value: float | None, digits: int = 2) -> str:
    return "—" if value is None else f"{value:.{digits}f}"


def _sci(value: float | None) -> str:
    return "—" if value is None else f"{value:.4g}"


def format_evaluation(ev: Evaluation) -> str:
    """A plain-text table: value ± U (k) and std over loops, per direction, per loop, limits and the ISO 14253-1
    decision, the uncertainty basis with the dominant contributor of each result, the warnings."""
    pos, neg = ev.per_direction["positive"], ev.per_direction["negative"]
    checks = ev.verdict["checks"] if ev.verdict else {}
    unc = ev.uncertainty or {}

    def limit_text(quantity: str) -> tuple[str, str]:
        found = [c for c in checks.values() if c["quantity"] == quantity]
        if not found:
            return "", ""
        limit = " ".join(f"{c['comparison']} {c['limit']:g}" for c in found)
        decision = overall_decision(decision_of(c) or "fail" for c in found)
        return limit, DECISION_WORDS[decision]

    lo, hi = ev.rigidity_interval
    lines = [
        f"Hysteresis evaluation: {ev.n_loops} loop(s) evaluated"
        + (f" ({ev.skipped_loops} skipped)" if ev.skipped_loops else "")
        + f", test torque ±{ev.test_torque_nm:g} Nm, rated {ev.rated_torque_nm:g} Nm, "
        f"loading rate {_num(ev.loading_rate_nm_per_s, 1)} Nm/s",
        "",
        f"{'quantity':<34}{'value ± U (95 %)':<28}{'std':>8}{'positive':>10}{'negative':>10}"
        + (f"  {'limit':<19}decision" if checks else ""),
    ]
    rows = [
        (
            f"rigidity [Nm/arcmin] {lo:.0%}…{hi:.0%}",
            "rigidity_nm_per_arcmin",
            ev.rigidity_nm_per_arcmin,
            pos.rigidity_nm_per_arcmin,
            neg.rigidity_nm_per_arcmin,
        ),
        (
            f"lost motion [arcsec] ±{ev.lost_motion_torque_nm:.4g} Nm",
            "lost_motion_arcsec",
            ev.lost_motion_arcsec,
            pos.half_lost_motion_arcsec,
            neg.half_lost_motion_arcsec,
        ),
        ("backlash [arcsec] at 0 Nm", "backlash_arcsec", ev.backlash_arcsec, None, None),
    ]
    for label, key, value, p, n in rows:
        limit, result = limit_text(key)
        lines.append(
            f"{label:<34}{with_uncertainty(value, unc.get(key), ''):<28}{_num(ev.std.get(key)):>8}{_num(p):>10}"
            f"{_num(n):>10}" + (f"  {limit:<19}{result}" if checks else "")
        )
    lines.append(
        f"{'loop energy [J/cycle]':<34}{with_uncertainty(ev.loop_energy_j, unc.get('loop_energy_j'), ''):<28}"
        f"{_num(ev.std.get('loop_energy_j'), 4):>8}"
    )
    lines.append(
        f"{'torsion at interval end [arcsec]':<34}{'':<28}{'':>8}"
        f"{_num(pos.torsion_angle_arcsec):>10}{_num(neg.torsion_angle_arcsec):>10}"
    )
    if ev.hd_breakpoints_nm is not None:
        t1, t2 = ev.hd_breakpoints_nm
        for i, key in enumerate(("k1_nm_per_rad", "k2_nm_per_rad", "k3_nm_per_rad"), start=1):
            region = (f"0…{t1:g} Nm", f"{t1:g}…{t2:g} Nm", f">{t2:g} Nm")[i - 1]
            lines.append(
                f"{f'K{i} [Nm/rad] {region}':<34}{with_uncertainty(getattr(ev, key), unc.get(key), ''):<28}"
                f"{_sci(ev.std.get(key)):>8}{_sci(getattr(pos, key)):>10}{_sci(getattr(neg, key)):>10}"
            )
    lines += ["", f"{'loop':<6}{'order':<9}{'t [s]':>16}{'rigidity':>10}{'lost m.':>9}{'backlash':>10}{'rate':>8}"]
    for r in ev.loops:
        lines.append(
            f"{r.index:<6}{r.order:<9}{f'{r.start_time_s:.1f}…{r.end_time_s:.1f}':>16}"
            f"{_num(r.rigidity_nm_per_arcmin):>10}{_num(r.lost_motion_arcsec):>9}{_num(r.backlash_arcsec):>10}"
            f"{_num(r.loading_rate_nm_per_s, 1):>8}" + ("" if r.evaluated else "  (skipped)")
        )
    if unc or ev.uncertainty_basis:
        lines += ["", f"uncertainty: {ev.uncertainty_basis or 'U not stated'}; expanded U for 95 % coverage, "
                  "k from the Welch–Satterthwaite degrees of freedom"]
        for name, entry in unc.items():
            if name in ("rigidity_nm_per_arcmin", "lost_motion_arcsec", "backlash_arcsec") or name.startswith("k"):
                lines.append(f"  {name:<32}{with_uncertainty(entry.get('value'), entry):<36}dominant: "
                             f"{entry.get('dominant') or '—'}")
    if ev.verdict is not None:
        decision = decision_of(ev.verdict) or "fail"
        rule = ev.verdict.get("rule", "simple")
        how = "guard bands of U" if rule == "guarded" else "the value alone"
        lines += ["", f"verdict: {DECISION_WORDS[decision]} (ISO 14253-1 {rule} rule: {how})"]
    lines += [f"warning: {w}" for w in ev.warnings]
    return "\n".join(line.rstrip() for line in lines)
