"""Reducer torsion physics: the pure forward model torque → output twist angle (ground truth of the sim bench).

The twist of the reducer output (input shaft locked) under the transmitted torque T is the sum of three parts:

    θ(T) = θ_el(T) + θ_lm(T) + z(T-history)          [arcsec; positive torque → positive angle]

* θ_el — elastic twist: linear T·c (RV: one secant rigidity) or the Harmonic Drive K1/K2/K3 curve
  (θ = T/K1 up to T1, then (T−T1)/K2 up to T2, then (T−T2)/K3; odd in T).
* θ_lm — the lost-motion zone, a smooth step (L/2)·tanh(T/T_b) of full height L taken up over a few T_b around
  zero torque (the play of the gear teeth/pins as it closes under load). Odd in T and history-free, so it sits on
  the midline of the loop.
* z — friction hysteresis, a Dahl model in the torque domain: dz/dT = (−s·h − z)/T_z with s = sign(dT): friction
  opposes the motion, so the rising branch lies below the falling one and ∮T·dθ > 0 (energy is dissipated). It
  is rate-independent and has a closed form per monotonic stretch, z = −s·h + (z0 + s·h)·exp(−|T − T0|/T_z),
  evaluated here as an exact linear recurrence per sample (vectorised, state carried between batches). Between
  ±A it settles to a closed, symmetric loop: z at −A is +h·tanh(A/T_z), the branches are mirror images
  (z_↓(T) = −z_↑(−T)), so the loop width at zero torque is 2·h·[1 − (1 + tanh(A/T_z))·e^{−A/T_z}] and the
  hysteresis adds nothing to the midline at T = 0.

How the parameters map to the evaluated quantities (DESIGN §2) for a steady loop between ±A:

* backlash (loop width at T = 0) = the width formula above: only h and T_z. :func:`physics_from_spec` solves h so
  that it equals the catalogue entry's ``sim.backlash_arcsec`` exactly at A = rated torque (≈ 2h for A ≫ T_z).
* the hysteresis part of the midline m = (θ_↑ + θ_↓)/2 is m_z(T) = −h·(1 + tanh(A/T_z))·e^{−A/T_z}·sinh(T/T_z):
  zero at T = 0 and odd; at the loop tips ±A, where the two branches meet, it is ∓h·tanh(A/T_z). With the
  catalogue's T_z = 50 % of rated torque the loop is lens-shaped and m_z grows smoothly towards the tips.
* lost motion = m(+pT_r) − m(−pT_r) = 2·θ_el(pT_r) + L·tanh(pT_r/T_b) + 2·m_z(pT_r) (the last term is small:
  2·m_z = −0.55″ for the RV-110E entry at rated torque).
* rigidity (secant of the midline over [0.5A, A], both sides averaged): elastic part plus m_z, which matters
  towards the tips, so the secant rigidity depends on the test amplitude (as on a real reducer). For an RV
  reducer :func:`physics_from_spec` therefore sets the elastic compliance c so that the midline secant over the
  default interval of a rated-torque loop equals the catalogue rigidity exactly. For a Harmonic Drive the
  elastic curve is the catalogue K1/K2/K3 curve itself (the worked example HFUC-32-100 at 60 N·m gives
  7.15e-4 rad); the loop's K1/K2/K3 (least-squares lines on its midline) then differ from the catalogue's.

:func:`loop_truth` computes the exact (noise-free) backlash, lost motion and rigidity of the steady loop for any
amplitude from these same functions; that is the truth tests compare evaluations against.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, replace

import numpy as np

from tcms_daq.config.models import ReducerSpec
from tcms_daq.errors import ConfigError, DataFormatError
from tcms_daq.units import ARCSEC_PER_ARCMIN, ARCSEC_PER_RAD, nm_per_arcmin_to_arcsec_per_nm

# Chunk length of the hysteresis recurrence in units of T_z of travelled torque (keeps exp() finite).
_CHUNK_DECAY = 600.0


@dataclass(frozen=True)
class ReducerPhysics:
    """Parameters of the forward model (see the module docstring for their meaning).

    compliance_arcsec_per_nm: linear elastic compliance c (RV), or None for the Harmonic Drive curve.
    hd_breakpoints_nm (T1, T2) and hd_stiffness_nm_per_rad (K1, K2, K3): the Harmonic Drive curve.
    lost_motion_zone_arcsec L, lost_motion_zone_torque_nm T_b: the tanh zone.
    hysteresis_half_width_arcsec h, hysteresis_torque_nm T_z: the Dahl loop.
    """

    name: str = "reducer"
    compliance_arcsec_per_nm: float | None = nm_per_arcmin_to_arcsec_per_nm(294.0)
    hd_breakpoints_nm: tuple[float, float] | None = None
    hd_stiffness_nm_per_rad: tuple[float, float, float] | None = None
    lost_motion_zone_arcsec: float = 0.0
    lost_motion_zone_torque_nm: float = 1.0
    hysteresis_half_width_arcsec: float = 0.0
    hysteresis_torque_nm: float = 1.0

    def __post_init__(self) -> None:
        if self.compliance_arcsec_per_nm is None and (
            self.hd_breakpoints_nm is None or self.hd_stiffness_nm_per_rad is None
        ):
            raise ValueError("ReducerPhysics needs compliance_arcsec_per_nm or the Harmonic Drive curve")
        if self.compliance_arcsec_per_nm is not None and self.compliance_arcsec_per_nm <= 0:
            raise ValueError(f"compliance_arcsec_per_nm must be > 0 (got {self.compliance_arcsec_per_nm})")
        if self.lost_motion_zone_torque_nm <= 0 or self.hysteresis_torque_nm <= 0:
            raise ValueError("lost_motion_zone_torque_nm and hysteresis_torque_nm must be > 0")
        if self.lost_motion_zone_arcsec < 0 or self.hysteresis_half_width_arcsec < 0:
            raise ValueError("lost_motion_zone_arcsec and hysteresis_half_width_arcsec must be >= 0")

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass(frozen=True)
class TwistState:
    """History of the forward model: the last torque (N·m) and the hysteresis state z (arcsec)."""

    torque_nm: float = 0.0
    hysteresis_arcsec: float = 0.0


def elastic_twist_arcsec(torque_nm, params: ReducerPhysics) -> np.ndarray:
    """Elastic twist θ_el(T) in arcsec (odd in T): linear, or the Harmonic Drive K1/K2/K3 curve."""
    t = np.asarray(torque_nm, dtype=float)
    if params.compliance_arcsec_per_nm is not None:
        return t * params.compliance_arcsec_per_nm
    t1, t2 = params.hd_breakpoints_nm  # type: ignore[misc]
    k1, k2, k3 = params.hd_stiffness_nm_per_rad  # type: ignore[misc]
    a = np.abs(t)
    phi_rad = np.where(
        a <= t1,
        a / k1,
        np.where(a <= t2, t1 / k1 + (a - t1) / k2, t1 / k1 + (t2 - t1) / k2 + (a - t2) / k3),
    )
    return np.sign(t) * phi_rad * ARCSEC_PER_RAD


def lost_motion_zone_arcsec(torque_nm, params: ReducerPhysics) -> np.ndarray:
    """The lost-motion zone θ_lm(T) = (L/2)·tanh(T/T_b) in arcsec."""
    t = np.asarray(torque_nm, dtype=float)
    return 0.5 * params.lost_motion_zone_arcsec * np.tanh(t / params.lost_motion_zone_torque_nm)


def hysteresis_arcsec(torque_nm, params: ReducerPhysics, state: TwistState | None = None
                      ) -> tuple[np.ndarray, TwistState]:
    """Dahl friction hysteresis z (arcsec) along a torque trace, from ``state`` (None: virgin, at 0 N·m).

    Exact for a trace that is monotonic between consecutive samples: z_n = α_n·z_{n−1} − (1 − α_n)·s_n·h with
    α_n = exp(−|ΔT_n|/T_z). Evaluated in closed form as z_n = (z_0 + Σ w_k·E_k)/E_n, E = exp(Σ|ΔT|/T_z), in
    chunks so E stays finite. No Python loop per sample.
    """
    state = state or TwistState()
    t = np.asarray(torque_nm, dtype=float).ravel()
    n = t.size
    h, tz = params.hysteresis_half_width_arcsec, params.hysteresis_torque_nm
    if n == 0:
        return np.empty(0), state
    if h == 0.0:
        return np.zeros(n), TwistState(float(t[-1]), 0.0)
    dt = np.diff(t, prepend=state.torque_nm)
    x = np.abs(dt) / tz
    w = np.expm1(-x) * np.sign(dt) * h  # −(1 − α)·s·h
    cum = np.cumsum(x)
    z = np.empty(n)
    z_start, base, start = state.hysteresis_arcsec, 0.0, 0
    while start < n:
        end = int(np.searchsorted(cum, base + _CHUNK_DECAY, side="right"))
        if end <= start:  # a single step longer than the chunk: the state saturates
            z[start] = math.exp(-x[start]) * z_start + w[start]
            end = start + 1
        else:
            e = np.exp(cum[start:end] - base)
            z[start:end] = (z_start + np.cumsum(w[start:end] * e)) / e
        z_start, base, start = float(z[end - 1]), float(cum[end - 1]), end
    return z, TwistState(float(t[-1]), float(z[-1]))


def midline_twist_arcsec(torque_nm, params: ReducerPhysics) -> np.ndarray:
    """History-free part θ_el + θ_lm (the loop midline apart from the hysteresis tip term)."""
    return elastic_twist_arcsec(torque_nm, params) + lost_motion_zone_arcsec(torque_nm, params)


def twist_arcsec(torque_nm, params: ReducerPhysics, state: TwistState | None = None
                 ) -> tuple[np.ndarray, TwistState]:
    """Output twist angle (arcsec) of the reducer for a transmitted-torque trace (N·m).

    ``state`` carries the history between batches (None: a virgin reducer at zero torque). Returns the angles and
    the state after the last sample; feeding a trace in pieces gives the same result as in one piece.
    """
    t = np.asarray(torque_nm, dtype=float)
    z, new_state = hysteresis_arcsec(t.ravel(), params, state)
    return (midline_twist_arcsec(t, params) + z.reshape(t.shape)), new_state


# ------------------------------------------------------------------------------------------------- truth


def steady_loop_state(params: ReducerPhysics, amplitude_nm: float) -> TwistState:
    """State at −A at the start of a rising branch of the steady loop between ±A (closed form)."""
    a = float(amplitude_nm)
    z = params.hysteresis_half_width_arcsec * math.tanh(a / params.hysteresis_torque_nm)
    return TwistState(-a, z)


def loop_branches(params: ReducerPhysics, amplitude_nm: float, torque_levels_nm
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Exact angles of the rising (−A → +A) and falling (+A → −A) branches of the steady loop at given levels."""
    levels = np.asarray(torque_levels_nm, dtype=float)
    a = float(amplitude_nm)
    if np.any(np.abs(levels) > a * (1 + 1e-12)):
        raise ValueError("torque levels must lie within ±amplitude")
    order = np.argsort(levels)
    start = steady_loop_state(params, a)
    up_sorted, _ = twist_arcsec(levels[order], params, start)
    down_start = TwistState(a, -start.hysteresis_arcsec)
    down_sorted, _ = twist_arcsec(levels[order][::-1], params, down_start)
    up = np.empty_like(levels)
    down = np.empty_like(levels)
    up[order] = up_sorted
    down[order] = down_sorted[::-1]
    return up, down


@dataclass(frozen=True)
class LoopTruth:
    """The exact characteristics of the simulated reducer's steady loop (DESIGN §2 definitions)."""

    test_torque_nm: float
    rigidity_nm_per_arcmin: float
    rigidity_pos_nm_per_arcmin: float
    rigidity_neg_nm_per_arcmin: float
    backlash_arcsec: float
    lost_motion_arcsec: float
    lost_motion_torque_nm: float
    rigidity_interval: tuple[float, float]
    k1_nm_per_rad: float | None = None
    k2_nm_per_rad: float | None = None
    k3_nm_per_rad: float | None = None

    def to_dict(self) -> dict:
        d = asdict(self)
        d["rigidity_interval"] = list(self.rigidity_interval)
        return d


def _hd_truth(params: ReducerPhysics, amplitude_nm: float, points: int = 41) -> list[float | None]:
    """K1, K2, K3 (N·m/rad): least-squares lines on the exact steady midline over [0, T1], [T1, T2], [T2, A],
    both sides averaged (the Harmonic Drive definition applied to the simulated loop)."""
    t1, t2 = params.hd_breakpoints_nm  # type: ignore[misc]
    out: list[float | None] = []
    for lo, hi in ((0.0, t1), (t1, t2), (t2, amplitude_nm)):
        hi = min(hi, amplitude_nm)
        if hi <= lo:
            out.append(None)
            continue
        grid = np.linspace(lo, hi, points)
        ks = []
        for sign in (1.0, -1.0):
            up, down = loop_branches(params, amplitude_nm, sign * grid)
            mid = 0.5 * (up + down)
            x = sign * grid - np.mean(sign * grid)
            compliance = float(np.dot(x, mid - mid.mean()) / np.dot(x, x))
            ks.append(ARCSEC_PER_RAD / compliance)
        out.append(float(np.mean(ks)))
    return out


def loop_truth(params: ReducerPhysics, test_torque_nm: float, rated_torque_nm: float,
               lost_motion_pct: float = 3.0, rigidity_interval: tuple[float, float] = (0.5, 1.0)) -> LoopTruth:
    """Backlash, lost motion and midline secant rigidity of the steady loop between ±test torque."""
    a = float(test_torque_nm)
    p_t = lost_motion_pct / 100.0 * rated_torque_nm
    lo, hi = rigidity_interval[0] * a, rigidity_interval[1] * a
    levels = np.array([0.0, p_t, -p_t, lo, hi, -lo, -hi])
    up, down = loop_branches(params, a, levels)
    mid = 0.5 * (up + down)
    k_pos = (hi - lo) / (mid[4] - mid[3]) * ARCSEC_PER_ARCMIN
    k_neg = (hi - lo) / (mid[5] - mid[6]) * ARCSEC_PER_ARCMIN
    return LoopTruth(
        test_torque_nm=a,
        rigidity_nm_per_arcmin=0.5 * (k_pos + k_neg),
        rigidity_pos_nm_per_arcmin=k_pos,
        rigidity_neg_nm_per_arcmin=k_neg,
        backlash_arcsec=abs(down[0] - up[0]),
        lost_motion_arcsec=mid[1] - mid[2],
        lost_motion_torque_nm=p_t,
        rigidity_interval=(float(rigidity_interval[0]), float(rigidity_interval[1])),
        **(dict(zip(("k1_nm_per_rad", "k2_nm_per_rad", "k3_nm_per_rad"), _hd_truth(params, a), strict=True))
           if params.hd_breakpoints_nm is not None and params.compliance_arcsec_per_nm is None else {}),
    )


def _loop_width_factor(amplitude_nm: float, hysteresis_torque_nm: float) -> float:
    """Loop width at zero torque divided by 2h for a steady loop between ±A."""
    r = amplitude_nm / hysteresis_torque_nm
    return 1.0 - (1.0 + math.tanh(r)) * math.exp(-r)


def physics_from_spec(spec: ReducerSpec, rigidity_interval: tuple[float, float] = (0.5, 1.0)) -> ReducerPhysics:
    """Forward-model parameters of a catalogue reducer, calibrated at a loop between ±rated torque.

    h is solved so the loop width at zero torque is ``spec.sim.backlash_arcsec``; for an RV reducer the elastic
    compliance is solved so the midline secant over ``rigidity_interval`` equals the catalogue rigidity.
    """
    tr = spec.rated_torque_nm
    tz = spec.sim.friction_transition_pct / 100.0 * tr
    hd_stiffness: tuple[float, float, float] | None = None
    if spec.kind == "harmonic":
        k1, k2, k3 = spec.k1_nm_per_rad, spec.k2_nm_per_rad, spec.k3_nm_per_rad
        if k1 is None or k2 is None or k3 is None:  # the catalogue model refuses such an entry
            raise ConfigError(f"{spec.name}: a Harmonic Drive entry needs K1, K2 and K3")
        hd_stiffness = (k1, k2, k3)
    params = ReducerPhysics(
        name=spec.name,
        compliance_arcsec_per_nm=None if spec.kind == "harmonic" else 1.0,
        hd_breakpoints_nm=spec.hd_breakpoints_nm,
        hd_stiffness_nm_per_rad=hd_stiffness,
        lost_motion_zone_arcsec=spec.sim.lost_motion_zone_arcsec,
        lost_motion_zone_torque_nm=spec.sim.lost_motion_zone_pct / 100.0 * tr,
        hysteresis_half_width_arcsec=0.5 * spec.sim.backlash_arcsec / _loop_width_factor(tr, tz),
        hysteresis_torque_nm=tz,
    )
    if spec.kind == "harmonic":
        return params
    # Midline rise over the interval of everything but the elastic part, per unit of torque (same on both sides).
    lo, hi = rigidity_interval[0] * tr, rigidity_interval[1] * tr
    unit = loop_truth(params, tr, tr, spec.lost_motion_pct, rigidity_interval)
    rise_total = (hi - lo) / (unit.rigidity_pos_nm_per_arcmin / ARCSEC_PER_ARCMIN)
    rise_non_elastic = rise_total - (hi - lo) * 1.0
    target_compliance = nm_per_arcmin_to_arcsec_per_nm(float(spec.rigidity_nm_per_arcmin))  # type: ignore[arg-type]
    compliance = target_compliance - rise_non_elastic / (hi - lo)
    if compliance <= 0.0:
        raise ConfigError(
            f"reducers.{spec.name}.sim: hysteresis/lost-motion zone too large for rigidity "
            f"{spec.rigidity_nm_per_arcmin} N·m/arcmin (no positive elastic compliance fits)"
        )
    return replace(params, compliance_arcsec_per_nm=compliance)


# ------------------------------------------------------------------------------------------ forward model


@dataclass(frozen=True)
class ReducerTwistModel:
    """A reducer's forward model over a torque trace: what the discrepancy core takes as its model
    (``tcms_daq.discrepancy.stored.ForwardModel``). Angles in arcsec, torques in N·m."""

    params: ReducerPhysics

    @property
    def hysteresis_half_width_arcsec(self) -> float:
        return self.params.hysteresis_half_width_arcsec

    def twist_arcsec(self, torque_nm: np.ndarray, initial_hysteresis_arcsec: float = 0.0) -> np.ndarray:
        """Output twist along the trace from zero torque with hysteresis state ``initial_hysteresis_arcsec``."""
        return twist_arcsec(torque_nm, self.params, TwistState(0.0, float(initial_hysteresis_arcsec)))[0]


def catalogue_model(reducer_name: str) -> ReducerTwistModel:
    """The forward model of a reducer of the packaged catalogue; DataFormatError names an unknown reducer."""
    from tcms_daq.config import load_reducer_catalogue

    catalogue = load_reducer_catalogue()
    if reducer_name not in catalogue:
        raise DataFormatError(f"reducer {reducer_name!r} is not in the reducer catalogue")
    return ReducerTwistModel(physics_from_spec(catalogue[reducer_name]))
