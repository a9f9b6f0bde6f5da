"""A transmission-error generator written apart from the simulator (``sim/transmission.py``) and the evaluation: to
check the evaluation and the TE discrepancy workflow on records they did not make.

It shares no code with them (numpy only) and makes its own choices where they made theirs:

* **physics, not harmonics**: the TE comes from sizes of component errors through the first-order geometry of the
  gear train — an RV's output-bearing run-out e_o at radius R_o (order 1, e_o/R_o), the pin ring's eccentricity
  ε_p against the crank eccentricity e (order Zp − 1: the load zone sweeps the ring with the eccentrics, ε_p/(e·(Zp
  − 1))) and its ellipticity (2(Zp − 1)), a crank journal's run-out δ_c at the crank circle r_c (order Zp: the
  cranks turn Zp times relative to the carrier, δ_c/r_c), the input pinion's run-out ε_1 at its pitch radius r_1
  (order i − 1 relative to the carrier, ε_1/(r_1·i)); a Harmonic Drive's output run-out and the two-lobed pitch
  errors of its circular spline (order 2i) and flexspline (2(i + 1)) over their pitch radius; hidden sources;
* **its own phase convention**: each source is A·cos(k·(φ − φ_ref) − λ) with φ_ref the generator's reference mark
  (not the output encoder's zero) and λ a lag in degrees;
* **sampled encoders**: the output angle in counts of an 18 000-line encoder interpolated 4096-fold, with its
  interpolation error over the 72″ signal period and electrical noise; the input angle in counts of a 2^17-count
  motor encoder with its once-per-turn eccentricity error; the input latched a fixed skew after the output and
  every latch with a time jitter; optionally the output encoder's own error at orders 1 and 2 of its reading
  (``Recording.output_encoder_error``);
* **speed ripple in time**: the drive's speed has a ripple at a frequency in Hz (not locked to the angle) plus one
  per input turn, integrated on a fine grid and sampled at its own rate;
* the twist under the light load is a plain compliance with a lost-motion jump between the directions.

``python -m tcms_daq.sim.station_trials`` runs the evaluation and the workflow on it (and on the simulator) and
reports the rates per family.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

ARCSEC_PER_RAD = 180.0 * 3600.0 / math.pi
ARCSEC_PER_TURN = 1_296_000.0


@dataclass(frozen=True)
class Source:
    """One error source of the generator: A·cos(k·(φ − φ_ref) − λ), A in arcsec, k per output turn, λ in deg."""

    name: str
    order: float
    amplitude_arcsec: float
    lag_deg: float
    component: str | None  # the component it belongs to in the evaluation's words (None: it belongs to none)


@dataclass(frozen=True)
class RvErrors:
    """Sizes of an RV reducer's component errors (µm, mm) and its tooth numbers."""

    input_gear: int = 10
    spur_gear: int = 40
    pins: int = 40
    output_runout_um: float = 3.0
    output_radius_mm: float = 80.0
    pin_ring_eccentricity_um: float = 2.0
    pin_ring_ellipticity_um: float = 0.0
    crank_eccentricity_mm: float = 1.5
    crank_runout_um: float = 1.5
    crank_circle_mm: float = 60.0
    pinion_runout_um: float = 10.0
    pinion_pitch_radius_mm: float = 8.0

    @property
    def ratio(self) -> float:
        return 1.0 + self.pins * self.spur_gear / self.input_gear

    def sources(self, rng: np.random.Generator) -> list[Source]:
        """The sources with random lags (the assembly's)."""
        zc = self.pins - 1
        out = [
            Source("output run-out", 1.0, self.output_runout_um / (self.output_radius_mm * 1e3) * ARCSEC_PER_RAD,
                   rng.uniform(0, 360), "output"),
            Source("pin-ring eccentricity", float(zc),
                   self.pin_ring_eccentricity_um / (self.crank_eccentricity_mm * 1e3 * zc) * ARCSEC_PER_RAD,
                   rng.uniform(0, 360), "pin_ring"),
            Source("crank journal run-out", float(self.pins),
                   self.crank_runout_um / (self.crank_circle_mm * 1e3) * ARCSEC_PER_RAD, rng.uniform(0, 360),
                   "crankshaft"),
            Source("input pinion run-out", self.ratio - 1.0,
                   self.pinion_runout_um / (self.pinion_pitch_radius_mm * 1e3 * self.ratio) * ARCSEC_PER_RAD,
                   rng.uniform(0, 360), "input_pinion"),
        ]
        if self.pin_ring_ellipticity_um > 0:
            out.append(Source("pin-ring ellipticity", 2.0 * zc, self.pin_ring_ellipticity_um
                              / (self.crank_eccentricity_mm * 1e3 * zc) * ARCSEC_PER_RAD, rng.uniform(0, 360),
                              "pin_ring 2×"))
        return out


@dataclass(frozen=True)
class HdErrors:
    """Sizes of a Harmonic Drive's errors and its tooth numbers: the output's run-out, and the two-lobed
    (elliptical) tangential pitch errors of the circular spline and of the flexspline at their pitch radius: the
    flexspline follows the circular-spline teeth it meshes with at the wave's two zones, which sweep the circular
    spline twice per wave turn (order 2i) and the flexspline twice per turn of the wave relative to it (2(i + 1))."""

    flexspline: int = 200
    circular_spline: int = 202
    output_runout_um: float = 3.0
    output_radius_mm: float = 45.0
    circular_spline_pitch_um: float = 1.2
    flexspline_pitch_um: float = 0.6
    pitch_radius_mm: float = 40.0

    @property
    def ratio(self) -> float:
        return self.flexspline / (self.circular_spline - self.flexspline)

    def sources(self, rng: np.random.Generator) -> list[Source]:
        i = self.ratio
        radius_um = self.pitch_radius_mm * 1e3
        return [
            Source("output run-out", 1.0, self.output_runout_um / (self.output_radius_mm * 1e3) * ARCSEC_PER_RAD,
                   rng.uniform(0, 360), "output"),
            Source("circular-spline pitch (two lobes)", 2.0 * i, self.circular_spline_pitch_um / radius_um
                   * ARCSEC_PER_RAD, rng.uniform(0, 360), "circular_spline"),
            Source("flexspline pitch (two lobes)", 2.0 * (i + 1.0), self.flexspline_pitch_um / radius_um
                   * ARCSEC_PER_RAD, rng.uniform(0, 360), "flexspline"),
        ]


@dataclass(frozen=True)
class Recording:
    """Settings of the recording (what the station and its drive do)."""

    input_rpm: float = 2000.0
    revolutions: float = 1.15
    sample_rate_hz: float = 2000.0
    fine_rate_hz: float = 16000.0
    output_noise_arcsec: float = 0.05
    output_interpolation_arcsec: float = 0.1
    input_counts: int = 2**17
    input_eccentricity_arcsec: float = 30.0
    skew_s: float = 50e-6
    jitter_s: float = 5e-6
    ripple_pct: float = 0.8
    ripple_hz: float = 7.3
    ripple_per_turn_pct: float = 0.3
    reference_deg: float = 17.0  # the generator's reference mark, in the output encoder's angle
    compliance_arcsec_per_nm: float = 0.2
    load_nm: float = 20.0
    lost_motion_arcsec: float = 12.0
    pause_s: float = 0.3
    # the output encoder's own error over its revolution (mounting and graduation): (a1, λ1, a2, λ2), a_m·cos(m·θ −
    # λ_m) with θ the encoder's reading (rad), a in arcsec, λ in degrees; none by default
    output_encoder_error: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)


@dataclass
class Generated:
    """A record of both directions with what made it: the sources (generator convention)."""

    time_s: np.ndarray
    input_angle_arcsec: np.ndarray
    output_angle_arcsec: np.ndarray
    ratio: float
    sources: list[Source]
    recording: Recording
    extra: dict[str, float] = field(default_factory=dict)

    def project_phase_deg(self, source: Source) -> float:
        """The source's phase in the evaluation's convention (TE = A·sin(kφ + ϕ), φ from the output encoder's zero):
        A·cos(k(φ − φ_ref) − λ) = A·sin(kφ + 90° − λ − k·φ_ref)."""
        return (90.0 - source.lag_deg - source.order * self.recording.reference_deg) % 360.0


def generate(errors: RvErrors | HdErrors, hidden: list[Source] | None = None, recording: Recording | None = None,
             seed: int = 0, unit_seed: int = 0) -> Generated:
    """A record of ``errors`` (+ ``hidden`` sources) turning forward then in reverse (``recording``): ``unit_seed``
    draws the unit's assembly (the sources' lags: the same unit for the same seed), ``seed`` the recording's noise."""
    rec = recording or Recording()
    sources = errors.sources(np.random.default_rng(unit_seed)) + list(hidden or [])
    rng = np.random.default_rng(seed)
    i = errors.ratio
    duration = rec.revolutions * i * 60.0 / rec.input_rpm
    accel_s = 0.2
    seg = accel_s + duration + accel_s
    total = 2.0 * seg + 2.0 * rec.pause_s
    t_fine = np.arange(0.0, total, 1.0 / rec.fine_rate_hz)

    def envelope(t: np.ndarray, start: float) -> np.ndarray:
        x = np.clip((t - start) / accel_s, 0.0, 1.0) * np.clip((start + seg - t) / accel_s, 0.0, 1.0)
        return np.minimum(x, 1.0)

    direction = np.where(t_fine < seg + rec.pause_s, 1.0, -1.0)
    shape = np.where(t_fine < seg + rec.pause_s, envelope(t_fine, 0.0), envelope(t_fine, seg + rec.pause_s))
    nominal = rec.input_rpm / 60.0 * ARCSEC_PER_TURN * direction * shape  # input arcsec per s
    turn_angle = np.cumsum(nominal) / rec.fine_rate_hz
    ripple = 1.0 + rec.ripple_pct / 100.0 * np.sin(2 * math.pi * rec.ripple_hz * t_fine + 0.4) \
        + rec.ripple_per_turn_pct / 100.0 * np.sin(2 * math.pi * turn_angle / ARCSEC_PER_TURN + 1.1)
    speed = nominal * ripple
    theta_in = np.concatenate(([0.0], np.cumsum(0.5 * (speed[1:] + speed[:-1])) / rec.fine_rate_hz))
    phi = theta_in / i  # output arcsec, the kinematic angle (the output encoder's zero)
    te = np.zeros_like(phi)
    for s in sources:
        arg = s.order * (phi / 3600.0 - rec.reference_deg) * math.pi / 180.0 - math.radians(s.lag_deg)
        te += s.amplitude_arcsec * np.cos(arg)
    moving = direction * shape > 0.5
    twist = np.where(direction > 0, -1.0, 1.0) * (rec.compliance_arcsec_per_nm * rec.load_nm
                                                 + 0.5 * rec.lost_motion_arcsec)
    twist = np.where(moving | (direction < 0), twist, 0.0)
    theta_out = phi + te + twist
    # sampling: each latch with jitter, the input latched a skew later
    t = np.arange(0.0, total - 0.01, 1.0 / rec.sample_rate_hz)
    t_out = t + rec.jitter_s * rng.standard_normal(t.size)
    t_in = t + rec.skew_s + rec.jitter_s * rng.standard_normal(t.size)
    out = np.interp(t_out, t_fine, theta_out)
    out = out + rec.output_interpolation_arcsec * np.sin(2 * math.pi * out / 72.0 + 0.3)
    a1, lag1, a2, lag2 = rec.output_encoder_error
    if a1 or a2:
        theta = out / ARCSEC_PER_RAD
        out = out + a1 * np.cos(theta - math.radians(lag1)) + a2 * np.cos(2.0 * theta - math.radians(lag2))
    out = out + rec.output_noise_arcsec * rng.standard_normal(t.size)
    count_out = ARCSEC_PER_TURN / (18000 * 4096)
    out = np.floor(out / count_out) * count_out
    inp = np.interp(t_in, t_fine, theta_in)
    inp = inp + rec.input_eccentricity_arcsec * np.sin(2 * math.pi * inp / ARCSEC_PER_TURN + 2.0)
    count_in = ARCSEC_PER_TURN / rec.input_counts
    inp = np.floor(inp / count_in) * count_in
    return Generated(t, inp, out, i, sources, rec, {"duration_s": duration})
