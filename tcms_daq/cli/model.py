"""``tcms model GEOMETRY.toml [--json]``: the geometric error model of the measuring chain (paper Eqs. 1–16)."""

from __future__ import annotations

import argparse
import json

from tcms_daq.compensation.geometry import evaluate_geometry, load_geometry
from tcms_daq.config import resolve_config_path


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "model",
        help="evaluate the geometric error model of the angle-measuring chain",
        description="Evaluate the paper's DH chain (Eqs. 1-14) and its consistent completion (scale k, axial "
        "shift dL, torsion slope) for a geometry TOML (Table 2 in [structure], Table 3 in [parts.N]).",
    )
    p.add_argument("geometry", help="geometry TOML: a path, or a packaged one by name (geometry-paper.toml, geometry-sim.toml)")
    p.add_argument("--json", action="store_true", help="print JSON")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    model = evaluate_geometry(load_geometry(resolve_config_path(args.geometry)))
    d = model.to_dict()
    if args.json:
        print(json.dumps(d, indent=2))
        return 0
    print(f"geometry: {d['source']}")
    print("assembly errors (Eqs. 5, 8):      dr_mm     de_mm    dt_rad")
    for joint, a in d["assembly_errors"].items():
        print(f"  joint {joint}:                  {a['dr_mm']:+9.4f} {a['de_mm']:+9.4f} {a['dt_rad']:+9.4f}")
    print("T64 (Eq. 9, mm):")
    for row in d["t64"]:
        print("  [" + " ".join(f"{v:+12.7f}" for v in row) + "]")
    print(f"tilt phi (Eq. 14):       {d['phi_rad']:.7f} rad = {d['phi_arcsec']:.1f}″")
    print(f"consistent completion (sigma = {d['sigma']:+d}, plane x6 = {d['measurement_plane_x_mm']:g} mm):")
    print(f"  eccentricity e:        ({d['eccentricity_mm'][0]:+.4f}, {d['eccentricity_mm'][1]:+.4f}) mm")
    print(f"  R1' = {d['r1_prime_mm']:.4f} mm, k = R1'/R2 = {d['k']:.5f} (true = k x reading)")
    print(f"  delta L = {d['delta_l_mm']:+.4f} mm, torsion {d['torsion_arcsec_per_nm']:.6f}″ per N·m")
    lit = d["literal_eq15_16"]
    if lit["k"] is not None:
        print(f"printed Eqs. 15/16 literally (dimensionally inconsistent): a = {lit['a']:.4f}, "
              f"k = {lit['k']:.4f}, PaPt = {lit['pa_pt']}")
    for note in d["notes"]:
        print(f"note: {note}")
    return 0
