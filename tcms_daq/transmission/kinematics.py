"""Reducer kinematics: tooth numbers → total ratio and the order of each component's rotation, per output revolution.

The derivation is in docs/transmission.md ("Kinematics"); in short (case fixed, the output turns once):

RV reducer (input pinion Z1 on the input shaft, a spur gear Z2 on each of N crankshafts held by the output carrier,
cycloid discs with Zc = Zp − 1 teeth on the crank eccentrics, Zp pins in the case):

* the discs turn with the carrier (once); meshing with the fixed pins makes the eccentrics turn −Zc times in the case,
  so the crankshafts turn Zc + 1 = Zp times relative to the carrier;
* the first stage: (ω_in − ω_out)·Z1 = Zp·ω_out·Z2, so i = 1 + Zp·Z2/Z1;
* orders: output 1; pin ring (the pins swept by the discs' load zone, which turns with the eccentrics in the case)
  Zp − 1; crankshaft (relative to the carrier) Zp; cycloid disc (relative to its load zone) Zp; input pinion
  (relative to the carrier) i − 1; input shaft i; first-stage tooth mesh Z1·(i − 1) = Z2·Zp; cycloid–pin tooth
  passing Zp·(Zp − 1).

Harmonic Drive (circular spline Zcs fixed, wave generator input, flexspline Zf output; Zcs − Zf = 2 usually):

* the flexspline turns −(Zcs − Zf)/Zf per wave-generator turn, so i = Zf/(Zcs − Zf); the wave turns i times in the
  case and i + 1 times relative to the flexspline;
* orders: output 1; wave generator i; circular spline (the two-lobed wave against it) 2i; flexspline (the wave
  against it) 2(i + 1); tooth passing Zf·(i + 1).

Orders are magnitudes (a spectrum does not see the direction of rotation). Two components can share an order (RV:
crankshaft and cycloid disc): a transmission error at that order names both, as the discrepancy workflow names an
alias group — the transmission error alone cannot tell them apart.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

Kind = Literal["rv", "harmonic"]

#: the components of each kind and what each order's errors come from (docs/transmission.md)
COMPONENTS: dict[str, dict[str, str]] = {
    "rv": {
        "output": "output flange and carrier: eccentricity, main-bearing run-out, the pin ring's once-round error",
        "pin_ring": "cycloid–pin meshing: the pin ring's pitch and position errors swept by the discs' load zone",
        "crankshaft": "crankshafts relative to the carrier: eccentric and bearing run-out, spur-gear run-out",
        "cycloid_disc": "cycloid discs relative to their load zone: profile and pitch errors",
        "input_pinion": "input pinion relative to the carrier: its run-out against the spur gears",
        "input": "input shaft in the case: run-out, coupling",
        "spur_mesh": "first-stage tooth meshing (pinion against spur gears)",
        "cycloid_mesh": "cycloid–pin tooth passing",
    },
    "harmonic": {
        "output": "output flange and bearing: eccentricity, run-out",
        "wave_generator": "wave generator in the case: plug and bearing run-out, input coupling",
        "circular_spline": "the two-lobed wave against the circular spline (2× the wave generator's rotation)",
        "flexspline": "the two-lobed wave against the flexspline (2× its rotation relative to the flexspline)",
        "tooth_mesh": "tooth passing (flexspline teeth through the wave's two zones)",
    },
}

#: a component's own harmonics that are named after it (m × its order, m = 1 … MAX_HARMONIC)
MAX_HARMONIC = 2


@dataclass(frozen=True)
class Teeth:
    """Tooth numbers of one reducer. RV: ``input_gear`` Z1, ``spur_gear`` Z2, ``crankshafts`` N, ``cycloid`` Zc,
    ``pins`` Zp; Harmonic Drive: ``flexspline`` Zf, ``circular_spline`` Zcs. Fields of the other kind are None."""

    kind: Kind
    input_gear: int | None = None
    spur_gear: int | None = None
    crankshafts: int | None = None
    cycloid: int | None = None
    pins: int | None = None
    flexspline: int | None = None
    circular_spline: int | None = None

    def __post_init__(self) -> None:
        if self.kind == "rv":
            needed = {"input_gear": self.input_gear, "spur_gear": self.spur_gear, "crankshafts": self.crankshafts,
                      "cycloid": self.cycloid, "pins": self.pins}
            other = {"flexspline": self.flexspline, "circular_spline": self.circular_spline}
        elif self.kind == "harmonic":
            needed = {"flexspline": self.flexspline, "circular_spline": self.circular_spline}
            other = {"input_gear": self.input_gear, "spur_gear": self.spur_gear, "crankshafts": self.crankshafts,
                     "cycloid": self.cycloid, "pins": self.pins}
        else:
            raise ValueError(f"unknown reducer kind {self.kind!r} (rv, harmonic)")
        missing = [k for k, v in needed.items() if v is None]
        if missing:
            raise ValueError(f"{self.kind} kinematics need {', '.join(missing)}")
        stray = [k for k, v in other.items() if v is not None]
        if stray:
            raise ValueError(f"{', '.join(stray)}: not a tooth number of a {self.kind} reducer")
        if any(v is not None and v < 1 for v in (*needed.values(),)):
            raise ValueError("tooth numbers must be >= 1")
        if self.kind == "rv" and self.pins != self.cycloid + 1:  # type: ignore[operator]
            raise ValueError(f"an RV's pins must be one more than its cycloid teeth (pins {self.pins}, cycloid "
                             f"{self.cycloid})")
        if self.kind == "harmonic" and not self.circular_spline > self.flexspline:  # type: ignore[operator]
            raise ValueError(f"the circular spline needs more teeth than the flexspline ({self.circular_spline} vs "
                             f"{self.flexspline})")


def ratio(teeth: Teeth) -> float:
    """Total ratio i = input turns per output turn (positive: the output's positive direction is defined as the one
    the input's positive rotation drives). RV: 1 + Zp·Z2/Z1; Harmonic Drive: Zf/(Zcs − Zf)."""
    if teeth.kind == "rv":
        return 1.0 + teeth.pins * teeth.spur_gear / teeth.input_gear  # type: ignore[operator]
    return teeth.flexspline / (teeth.circular_spline - teeth.flexspline)  # type: ignore[operator]


def component_orders_per_output_rev(teeth: Teeth) -> dict[str, float]:
    """Each component's fundamental order: how many times its errors repeat per output revolution (the module
    docstring and docs/transmission.md derive them)."""
    i = ratio(teeth)
    if teeth.kind == "rv":
        zp = float(teeth.pins)  # type: ignore[arg-type]
        return {
            "output": 1.0,
            "pin_ring": zp - 1.0,
            "crankshaft": (i - 1.0) * teeth.input_gear / teeth.spur_gear,  # type: ignore[operator]  # = Zp
            "cycloid_disc": zp,
            "input_pinion": i - 1.0,
            "input": i,
            "spur_mesh": teeth.input_gear * (i - 1.0),  # type: ignore[operator]
            "cycloid_mesh": zp * (zp - 1.0),
        }
    return {
        "output": 1.0,
        "wave_generator": i,
        "circular_spline": 2.0 * i,
        "flexspline": 2.0 * (i + 1.0),
        "tooth_mesh": teeth.flexspline * (i + 1.0),  # type: ignore[operator]
    }


@dataclass(frozen=True)
class ComponentOrder:
    """One named order: ``harmonic`` × the fundamental order of ``component`` (per output revolution)."""

    component: str
    harmonic: int
    order_per_output_rev: float

    @property
    def label(self) -> str:
        """``pin_ring`` or ``pin_ring 2×``."""
        return self.component if self.harmonic == 1 else f"{self.component} {self.harmonic}×"


def order_table(teeth: Teeth, max_harmonic: int = MAX_HARMONIC,
                max_order_per_output_rev: float | None = None) -> list[ComponentOrder]:
    """Every named order (components and their harmonics up to ``max_harmonic``; a harmonic that is another
    component's fundamental order is named by that component only), lowest first; orders above
    ``max_order_per_output_rev`` (the record's band) are left out."""
    fundamentals = component_orders_per_output_rev(teeth)
    rows = [ComponentOrder(name, m, m * order)
            for name, order in fundamentals.items() for m in range(1, max_harmonic + 1)
            # a 2× that is another component's own order is that component (HD: the wave generator's 2× is the
            # two-lobed wave against the circular spline)
            if m == 1 or not any(abs(m * order - other) < 1e-9 for other in fundamentals.values())]
    if max_order_per_output_rev is not None:
        rows = [r for r in rows if r.order_per_output_rev <= max_order_per_output_rev]
    return sorted(rows, key=lambda r: (r.order_per_output_rev, r.harmonic, r.component))


def components_at(order_per_output_rev: float, tolerance: float, table: list[ComponentOrder]) -> list[ComponentOrder]:
    """The named orders within ``tolerance`` (orders per output revolution) of a measured order: empty when the
    order belongs to no component (then it is reported by its order alone, never given a name)."""
    return [row for row in table if abs(row.order_per_output_rev - order_per_output_rev) <= tolerance]
