"""A measured run against a reducer model re-simulated on its own torque trace (``tcms discrepancy --run ID``).

Pure: the model is injected (:class:`ForwardModel`); reading the run from the store is the shell's
(``tcms_daq.store.discrepancy``).
"""

from __future__ import annotations

from typing import Any, Protocol

import numpy as np
from scipy.signal import savgol_coeffs, savgol_filter

from tcms_daq.samples import Samples

TORQUE_SMOOTHING_S = 0.05
MIN_SMOOTHING_SAMPLES = 5
COARSE_STEP_NOISE = 0.2  # a trace whose noise is below this share of its typical step is used as it is
SMOOTHING_ORDER = 2  # local quadratic fits: the tips of the loops keep their torque


def applied_torque_estimate(time_s: np.ndarray, torque_nm: np.ndarray,
                            window_s: float = TORQUE_SMOOTHING_S) -> np.ndarray:
    """The torque the reducer felt, estimated from the sensor reading (N·m).

    The forward model is hysteretic: fed the raw reading, sensor noise makes tiny load reversals that walk
    the model along minor loops, enough to name a spurious ``scale_error`` on a run without any effect (±500 N·m
    loops on the default simulated bench: 0.5″ RMS against the true twist; 0.06″ with this estimate, see
    tests/discrepancy/test_discrepancy_stored.py). A centred (zero-phase) local quadratic fit over ``window_s``
    (Savitzky–Golay) takes out most of the noise; a play operator of three times the remaining noise then removes
    the reversals the noise still makes. Quadratic, not a moving average: a moving average rounds each tip (a
    ramp into a hold and out of it) by a share of the window — 0.15 N·m RMS over a 13.75 kHz run, whose model loop
    then turned early, 0.03″ of coloured structure the verdict rightly found (0.03 N·m with the quadratic fit).
    A trace whose typical step is more than five times the noise is used as it is.
    """
    torque = np.asarray(torque_nm, dtype=float)
    if len(torque) >= 5:
        # sampled coarsely against the noise (each step of the trace more than five times the noise), the noise
        # reverses fewer than 1 in 4000 steps, and smoothing would only round the real reversals off. (At twice
        # the noise it reversed 8 % of them, and the model walked along those minor loops: the trial programme at
        # 1375 Hz, nothing hidden, was not consistent.)
        d2 = torque[2:] - 2.0 * torque[1:-1] + torque[:-2]
        noise_nm = 1.4826 * float(np.median(np.abs(d2 - np.median(d2)))) / np.sqrt(6.0)
        if noise_nm < COARSE_STEP_NOISE * float(np.median(np.abs(np.diff(torque)))):
            return torque
    dt = np.diff(time_s)
    dt = dt[np.isfinite(dt) & (dt > 0)]
    n = int(round(window_s / float(np.median(dt)))) | 1 if len(dt) and window_s > 0 else 1
    if n < MIN_SMOOTHING_SAMPLES or len(torque) < 2 * n:
        return torque  # sampled too slowly to smooth without rounding the reversals off (and noise matters less)
    smooth = savgol_filter(torque, n, SMOOTHING_ORDER, mode="interp")
    noise_nm = 1.4826 * float(np.median(np.abs(torque - smooth)))
    gain = float(np.sqrt(np.sum(savgol_coeffs(n, SMOOTHING_ORDER) ** 2)))  # the noise left: noise · gain
    return _play(smooth, 3.0 * noise_nm * gain)


def _play(x: np.ndarray, half_width: float) -> np.ndarray:
    """Play (backlash) operator without its lag on the branches: the output moves only once x has moved
    ``half_width`` past it, and once it has followed x for ``half_width`` it is x itself.

    A plain play lags x by ``half_width`` on every branch; fed to the forward model, that lag is a loop narrower
    by 2·half_width·compliance (0.065–0.069″ on the default simulated bench, named as a small backlash or lag on
    runs with neither). Here a correction within ±half_width follows each move of the play (continuous: the
    output never jumps, and in a dwell it moves only by twice what the play moves), so on a branch the output is
    x, and within 4·half_width after a turning point it catches up with x."""
    if half_width <= 0:
        return x
    out = np.empty_like(x)
    y = float(x[0])
    correction = 0.0
    for i, v in enumerate(x.tolist()):  # sequential by nature; about 0.4 µs a sample, once per analysis
        before = y
        if v - half_width > y:
            y = v - half_width
        elif v + half_width < y:
            y = v + half_width
        correction = min(half_width, max(-half_width, correction + (y - before)))
        out[i] = y + correction
    return out


class ForwardModel(Protocol):
    """A reducer's forward model, injected by the composition root (e.g. ``sim.physics.catalogue_model``)."""

    @property
    def hysteresis_half_width_arcsec(self) -> float:
        """The friction hysteresis half-width h (arcsec): the range of the unknown initial state."""
        ...

    def twist_arcsec(self, torque_nm: np.ndarray, initial_hysteresis_arcsec: float = 0.0) -> np.ndarray:
        """Output twist (arcsec) along a torque trace (N·m) from zero torque and the given hysteresis state;
        linear in that state."""
        ...


def resimulate(measured: Samples, model: ForwardModel) -> Samples:
    """The reducer's forward model on the measured torque trace: the "simulated" side of a stored run.

    The torque is smoothed (:func:`applied_torque_estimate`). The reducer's friction (hysteresis) state at the
    start of a stored run is unknown: it depends on the tests run before it, and after a larger test it takes
    several loops to settle (a model started virgin is off by arcseconds for the whole run). The model's angle is
    linear in that state, so the state is fitted by least squares (one number within the physical ±hysteresis
    half-width; its influence decays over the first load reversals), beside nuisance terms in time, torque and
    angle that keep a drift, a torsion or a scale error out of it. The returned torque column is the measured
    one.
    """
    torque = applied_torque_estimate(measured.time_s, measured.torque_nm)
    virgin = model.twist_arcsec(torque)
    # response to a unit initial hysteresis state (the model is linear in it)
    unit = model.twist_arcsec(torque, 1.0) - virgin
    half_width = model.hysteresis_half_width_arcsec
    angle = virgin
    if half_width > 0 and np.any(unit):
        # with nuisance columns beside it — time (a thermal drift), torque (a torsion of the chain) and the
        # model's own angle (a scale error) — so an effect the workflow is to find is not taken for the
        # settling state (it would leave a decaying transition after the reversals instead of a clean term)
        t = measured.time_s - float(np.mean(measured.time_s))
        design = np.column_stack([unit, np.ones_like(unit), t, torque, virgin])
        z0 = float(np.linalg.lstsq(design, measured.angle_arcsec - virgin, rcond=None)[0][0])
        angle = virgin + float(np.clip(z0, -half_width, half_width)) * unit
    return Samples(measured.time_s, measured.torque_nm, angle)


def first_branch_end(torque_nm: np.ndarray) -> int:
    """The first row to compare of a stored run: its first load reversal (0 when it has none). Before it the
    reducer's friction loop and the side of its play are where the previous run, the conditioning or the tare
    left them, while the model is re-simulated from rest: that branch compares two different states (on the
    simulated bench a 2″ backlash came out 8 % small with structure left in the first 8 s)."""
    from tcms_daq.discrepancy.design import load_direction, reversals

    turns = reversals(load_direction(np.asarray(torque_nm, dtype=float)))
    return int(turns[0]) if len(turns) else 0


# The request fields a separating run keeps from the run it follows (who and what is tested, not how).
_KEPT_REQUEST_FIELDS = ("cycles", "serial_number", "operator", "decision_rule", "customer",
                        "order_number", "ambient_temperature_c")
RATE_FACTOR = 3.0  # a second rate this many times the first (a skew's lag grows with it, backlash does not)
TIP_STEPS = 4  # a tip-hold run steps to ±T in this many steps, holding TIP_DWELL_S at each (the tips included)
TIP_DWELL_S = 2.0


def separating_request(kind: str, request: dict[str, Any], *, reducer: str, max_torque_nm: float,
                       rate_nm_per_s: float, max_rate_nm_per_s: float) -> dict[str, Any] | None:
    """The ``POST /api/tests`` body of the run that separates an alias group of the run made with ``request``
    (its stored request; the run went to ±``max_torque_nm`` at ``rate_nm_per_s``, the bench allows up to
    ``max_rate_nm_per_s``):
    ``effects.SECOND_RATE`` the same test at its rate and another (RATE_FACTOR × it, or ÷ when the bench cannot);
    ``effects.TIP_HOLDS`` a stepped profile holding at each step. None when the run already did that (two rates)."""
    from tcms_daq.discrepancy.effects import SECOND_RATE, TIP_HOLDS

    body: dict[str, Any] = {"reducer": reducer, "max_torque_nm": max_torque_nm,
                            **{k: request[k] for k in _KEPT_REQUEST_FIELDS if k in request}}
    if kind == SECOND_RATE:
        if len(request.get("rates") or ()) >= 2:
            return None
        other = rate_nm_per_s * RATE_FACTOR
        if other > max_rate_nm_per_s:
            other = rate_nm_per_s / RATE_FACTOR
        return {**body, "profile": "continuous", "rates": [round(rate_nm_per_s, 6), round(other, 6)]}
    if kind == TIP_HOLDS:
        if request.get("profile") == "stepped" and (request.get("dwell_s") or 0) > 0:
            return None
        return {**body, "profile": "stepped", "step_nm": round(max_torque_nm / TIP_STEPS, 6), "dwell_s": TIP_DWELL_S,
                "rate_nm_per_s": round(rate_nm_per_s, 6)}
    return None
