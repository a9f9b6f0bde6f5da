"""The validation families (issue 23 item 2): each a kind of reducer, friction law, lost-motion zone, profile,
sampling and noise; a run draws its reducer's parameters, its chain's gain errors and its noise, and returns the
readings with the truth of the dense noise-free path (``benchmarks.coverage.physics``)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from benchmarks.coverage.physics import Profile, Record, Reducer, dense_path, true_twist, truth

# the declared chain (standard uncertainties, k = 1) the gain errors are drawn from, as `tcms analyze --uncertainty`
# reads it
TORQUE_GAIN_U_REL = 0.001
ANGLE_GAIN_U_REL = 0.0005
CHAIN_TOML = f"""# the measuring chain of the validation runs (standard uncertainties, k = 1)
[torque]
u_rel = {TORQUE_GAIN_U_REL}
[angle]
u_rel = {ANGLE_GAIN_U_REL}
"""
# the declared noise (1×): torque 0.03 % of rated (0.32 N·m on an RV-110E), angle 0.15″
TORQUE_NOISE_REL = 3e-4
ANGLE_NOISE_ARCSEC = 0.15
LOST_MOTION_PCT = 3.0


@dataclass(frozen=True)
class Family:
    name: str
    size: str  # "RV" | "HD"
    friction: str  # "dahl" | "play" | "bouc-wen" | "lugre"
    zone: str  # "soft" | "hard"
    asymmetric: bool
    sample_rate_hz: float
    tip_hold_s: float
    stepped: bool
    noise: tuple[float, float]  # × the declared noise, drawn uniformly in this range

    def describe(self) -> str:
        profile = "stepped" if self.stepped else "continuous"
        hold = f"{self.tip_hold_s:g} s tip hold" if self.tip_hold_s > 0 else "no tip hold"
        lo, hi = self.noise
        noise = f"noise {lo:g}×" if lo == hi else f"noise {lo:g}–{hi:g}×"
        asym = ", asymmetric stiffness" if self.asymmetric else ""
        return (f"{self.size}, {self.friction}, {self.zone} zone{asym}, {profile}, {hold}, "
                f"{self.sample_rate_hz:g} Hz, {noise}")


FAMILIES: tuple[Family, ...] = (
    Family("rv-dahl-soft-50hz", "RV", "dahl", "soft", False, 50.0, 0.0, False, (1.0, 1.0)),
    Family("rv-dahl-soft-50hz-3x", "RV", "dahl", "soft", True, 50.0, 0.0, False, (3.0, 3.0)),
    Family("rv-play-hard-1khz", "RV", "play", "hard", True, 1000.0, 0.0, False, (0.0, 3.0)),
    Family("rv-boucwen-soft-stepped-200hz", "RV", "bouc-wen", "soft", False, 200.0, 1.0, True, (1.0, 1.0)),
    Family("rv-lugre-soft-10khz", "RV", "lugre", "soft", True, 10_000.0, 0.0, False, (0.0, 3.0)),
    Family("rv-play-hard-200hz-noiseless", "RV", "play", "hard", False, 200.0, 1.0, False, (0.0, 0.0)),
    Family("hd-dahl-hard-1khz-hold", "HD", "dahl", "hard", True, 1000.0, 1.0, False, (1.0, 1.0)),
    Family("hd-boucwen-soft-50hz", "HD", "bouc-wen", "soft", False, 50.0, 0.0, False, (0.0, 3.0)),
    Family("hd-play-soft-stepped-1khz", "HD", "play", "soft", True, 1000.0, 0.0, True, (3.0, 3.0)),
)

# branch duration (s) drawn per sampling rate: enough samples per branch, records of at most some 10⁵ samples
BRANCH_S = {50.0: (8.0, 20.0), 200.0: (4.0, 10.0), 1000.0: (2.0, 6.0), 10_000.0: (1.0, 2.0)}


def draw_rated_torque_nm(family: Family, rng: np.random.Generator) -> float:
    return float(rng.uniform(400.0, 1800.0) if family.size == "RV" else rng.uniform(50.0, 300.0))


def draw_reducer(family: Family, rng: np.random.Generator, rated: float, rate_nm_per_s: float) -> Reducer:
    u = rng.uniform
    if family.size == "RV":
        k = rated * u(0.2, 0.55)
        zone_width, friction_width = u(6.0, 16.0), u(10.0, 35.0)
        soft_torque, soft_ratio = 0.0, 1.0
    else:
        k = rated * u(0.2, 0.35)
        zone_width, friction_width = u(3.0, 12.0), u(10.0, 30.0)
        soft_torque, soft_ratio = rated * u(0.1, 0.25), u(0.5, 0.8)
    k_neg = k * u(0.85, 1.15) if family.asymmetric else k
    # friction saturates over T_z; it must not turn the angle back after a reversal (B/T_z below the compliance)
    friction_torque = max(rated * u(0.05, 0.2), 1.5 * friction_width * max(k, k_neg) / 60.0)
    lugre = family.friction == "lugre"
    return Reducer(
        rated_torque_nm=rated, rigidity_pos_nm_per_arcmin=k, rigidity_neg_nm_per_arcmin=k_neg,
        zone=family.zone, zone_width_arcsec=zone_width, zone_torque_nm=rated * u(0.005, 0.015),
        friction=family.friction, friction_width_arcsec=friction_width, friction_torque_nm=friction_torque,
        bouc_wen_n=u(1.0, 3.0), bouc_wen_beta_share=u(0.5, 0.9),
        viscous_arcsec_s_per_nm=u(0.1, 0.5) / rate_nm_per_s if lugre else 0.0,
        stribeck_gain=u(0.1, 0.4) if lugre else 0.0, stribeck_rate_nm_per_s=u(0.3, 1.0) * rate_nm_per_s,
        soft_region_torque_nm=soft_torque, soft_region_ratio=soft_ratio)


@dataclass(frozen=True)
class Draw:
    """What one run drew: the reducer, its true path at the sample times, the chain's gain errors and the noise.
    ``readings(sign)`` makes the record; sign −1 is the run's antithetic twin (the same reducer and profile with
    the gain errors and the noise negated), whose errors cancel the first-order part of the run's own."""

    reducer: Reducer
    time_s: np.ndarray
    torque_nm: np.ndarray  # true, at the sample times
    theta_arcsec: np.ndarray  # true twist, at the sample times
    truth: dict[str, float]
    torque_gain: float  # relative error of the torque chain
    angle_gain: float
    torque_noise_nm: np.ndarray
    angle_noise_arcsec: np.ndarray
    angle_offset_arcsec: float

    def readings(self, sign: float = 1.0) -> Record:
        torque_read = self.torque_nm * (1.0 + sign * self.torque_gain) + sign * self.torque_noise_nm
        angle_read = ((self.theta_arcsec + self.angle_offset_arcsec) * (1.0 + sign * self.angle_gain)
                      + sign * self.angle_noise_arcsec)
        return Record(self.time_s, torque_read, angle_read, self.truth)


def draw(family: Family, rng: np.random.Generator) -> Draw:
    """One run of a family: the reducer, the profile, the chain's gain errors, the noise."""
    lo, hi = BRANCH_S[family.sample_rate_hz]
    branch_s = rng.uniform(lo, hi)
    rated = draw_rated_torque_nm(family, rng)
    amplitude = rated * rng.uniform(0.985, 1.0)  # a test torque snapped to rated (within 2 %) but not quite reached
    rate = 2.0 * amplitude / branch_s
    reducer = draw_reducer(family, rng, rated, rate)
    steps = 40 if family.stepped else 0
    profile = Profile(amplitude, int(rng.integers(3, 5)), rate, family.tip_hold_s, steps, 0.3 if steps else 0.0)
    t_dense, q_dense = dense_path(profile, amplitude * 1e-4)
    theta_dense = true_twist(t_dense, q_dense, reducer, profile)
    true = truth(t_dense, q_dense, theta_dense, profile, rated, rated, LOST_MOTION_PCT)
    time_s = np.arange(0.0, t_dense[-1], 1.0 / family.sample_rate_hz)
    torque = np.interp(time_s, t_dense, q_dense)
    theta = np.interp(time_s, t_dense, theta_dense)
    noise = rng.uniform(*family.noise)
    torque_gain = rng.normal(0.0, TORQUE_GAIN_U_REL)
    torque_noise = noise * TORQUE_NOISE_REL * rated * rng.standard_normal(time_s.size)
    offset = rng.uniform(-3600.0, 3600.0)
    angle_gain = rng.normal(0.0, ANGLE_GAIN_U_REL)
    angle_noise = noise * ANGLE_NOISE_ARCSEC * rng.standard_normal(time_s.size)
    return Draw(reducer, time_s, torque, theta, true, torque_gain, angle_gain, torque_noise, angle_noise, offset)


def draw_run(family: Family, rng: np.random.Generator) -> tuple[Record, Reducer]:
    """One run of a family: its readings and truth, and the reducer."""
    drawn = draw(family, rng)
    return drawn.readings(), drawn.reducer
