"""The turning tests' procedures as data (pure): what the input drive and the loader do, step by step.

GB/T 35089-2018 measures, on the unit the stiffness test measures with its input locked, what it does when its input
turns (§7 torque and efficiency, §8 transmission precision). Each method is a list of steps the procedure
(``tcms_daq.acquisition.methodrun``) works through, the input drive in profile velocity, the loader in profile
torque:

- ``transmission-error``: ``revolutions`` output revolutions forward at ``input_speed_rpm`` against a light braking
  load (``load_torque_nm``, default 2 % of the rated torque), a pause, as many in reverse (load reversed);
- ``starting-torque``: ``ramps`` creeps per direction: the input commanded at ``creep_deg_per_s`` while it sticks,
  so that the drive's torque rises slowly (its velocity loop winds up) until the input breaks away; each creep stops
  once the input has turned ``CREEP_TURN_DEG`` (or after ``CREEP_TIMEOUT_S``), then a pause at rest;
- ``no-load-torque``: each of ``speeds_rpm`` held ``dwell_s`` forward, a pause, as long in reverse, no load;
- ``efficiency``: the loader's braking torque (``load_torque_nm``, default the rated torque) applied at rest, the
  input at ``input_speed_rpm`` (default the catalogue's rated input speed) for ``dwell_s``, stopped, unloaded; then
  the reverse.

Conventions: speeds in rpm of the input shaft (signed: the direction), velocities in deg/s at the input, torques in
N·m (the loader's: a braking load on a forward rotation is negative), times in clock seconds. A request becomes a
method plan in :func:`build_method_plan` (called by ``tcms_daq.procedure.plan.plan_from_request`` only), which holds
it to the bench: the input drive's speed limit, the bench's and the reducer's torque limits, the bench's longest test.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from typing import Any, Literal

from tcms_daq.config.models import BenchConfig, ReducerSpec

Method = Literal["stiffness", "transmission-error", "starting-torque", "no-load-torque", "efficiency"]
METHODS: tuple[str, ...] = ("stiffness", "transmission-error", "starting-torque", "no-load-torque", "efficiency")
TURNING_METHODS: tuple[str, ...] = METHODS[1:]
#: the request fields of the turning methods (each refused with the stiffness test, and with a method not its own)
METHOD_FIELDS: dict[str, tuple[str, ...]] = {
    "transmission-error": ("input_speed_rpm", "load_torque_nm", "revolutions"),
    "starting-torque": ("ramps", "creep_deg_per_s"),
    "no-load-torque": ("speeds_rpm", "dwell_s"),
    "efficiency": ("input_speed_rpm", "load_torque_nm", "dwell_s"),
}
#: what each method needs of the bench (kind of [instruments.<kind>], in words)
NEEDS: dict[str, tuple[tuple[str, str], ...]] = {
    "transmission-error": (("input_drive", "the input drive"), ("input_angle", "the input and output angle pair")),
    "starting-torque": (("input_drive", "the input drive"), ("input_angle", "the input and output angle pair"),
                        ("input_torque", "the input torque channel")),
    "no-load-torque": (("input_drive", "the input drive"), ("input_angle", "the input and output angle pair"),
                       ("input_torque", "the input torque channel")),
    "efficiency": (("input_drive", "the input drive"), ("input_angle", "the input and output angle pair"),
                   ("input_torque", "the input torque channel")),
}

DEFAULT_TE_SPEED_RPM = 2000.0
DEFAULT_TE_REVOLUTIONS = 1.15
DEFAULT_TE_LOAD_SHARE = 0.02  # of the rated torque: the light load of the transmission-error test
DEFAULT_RAMPS = 3
DEFAULT_CREEP_DEG_PER_S = 0.05
CREEP_TURN_DEG = 0.05  # a creep stops once the input has turned this far from where it stuck
CREEP_TIMEOUT_S = 60.0  # … or after this long (the drive's torque may not reach the breakaway)
DEFAULT_NO_LOAD_SHARES = (0.25, 0.5, 1.0)  # of the rated input speed
DEFAULT_NO_LOAD_DWELL_S = 1.5
DEFAULT_EFFICIENCY_DWELL_S = 2.0
PAUSE_S = 0.5
SETTLE_S = 0.3  # after a change of speed or load, before the stretch a step is for
SPEED_LIMIT_SHARE = 0.95  # of the input drive's limit: the highest speed a plan commands
LOAD_RAMP_S = 1.0  # the loader ramps its torque at the rated torque per this many seconds


@dataclass(frozen=True)
class SpeedStep:
    """Hold the input at ``input_speed_rpm`` for ``duration_s`` (after reaching it) while the loader holds
    ``load_torque_nm`` (reached before the input starts when it changes). ``phase`` names it for progress."""

    phase: str
    input_speed_rpm: float
    duration_s: float
    load_torque_nm: float = 0.0

    @property
    def velocity_deg_per_s(self) -> float:
        return self.input_speed_rpm * 6.0


@dataclass(frozen=True)
class CreepStep:
    """Command ``creep_deg_per_s`` until the input has turned ``turn_deg`` from where it was (or ``timeout_s``),
    then stop: one breakaway (starting torque)."""

    phase: str
    creep_deg_per_s: float
    turn_deg: float = CREEP_TURN_DEG
    timeout_s: float = CREEP_TIMEOUT_S


MethodStep = SpeedStep | CreepStep


@dataclass(frozen=True)
class MethodPlan:
    """A turning test: its method, its steps, the parameters it was made of, the loader's torque slope (N·m/s) and
    the input drive's acceleration (deg/s², for the duration estimate)."""

    method: str
    steps: tuple[MethodStep, ...]
    parameters: dict[str, Any] = field(default_factory=dict)
    load_slope_nm_per_s: float = 100.0
    acceleration_deg_per_s2: float = 36000.0
    expected_creep_s: float = 5.0  # the estimate of one creep's length (the drive's stiffness is not known)

    def step_durations_s(self) -> list[float]:
        """Planned clock time of each step: its load change, its speed ramp, its duration (a creep: its estimate)."""
        out: list[float] = []
        load, speed = 0.0, 0.0
        for step in self.steps:
            if isinstance(step, CreepStep):
                out.append(self.expected_creep_s + PAUSE_S)
                continue
            ramp_load = abs(step.load_torque_nm - load) / self.load_slope_nm_per_s
            ramp_speed = abs(step.velocity_deg_per_s - speed * 6.0) / self.acceleration_deg_per_s2
            out.append(ramp_load + ramp_speed + step.duration_s)
            load, speed = step.load_torque_nm, step.input_speed_rpm
        return out

    def duration_s(self) -> float:
        return float(sum(self.step_durations_s()))

    @property
    def peak_load_nm(self) -> float:
        return max((abs(s.load_torque_nm) for s in self.steps if isinstance(s, SpeedStep)), default=0.0)

    @property
    def max_speed_rpm(self) -> float:
        return max((abs(s.input_speed_rpm) for s in self.steps if isinstance(s, SpeedStep)), default=0.0)

    def to_dict(self) -> dict[str, Any]:
        return {"method": self.method, "parameters": dict(self.parameters),
                "steps": [{"kind": "creep" if isinstance(s, CreepStep) else "speed", **asdict(s)} for s in self.steps],
                "load_slope_nm_per_s": self.load_slope_nm_per_s, "plan_duration_s": self.duration_s()}


class MethodRejected(ValueError):
    """A turning test the bench cannot run: one line naming what is missing or out of bounds."""


#: angle sources that carry no input angle beside the output's (not an angle pair for the methods)
NOT_A_PAIR = ("nd287-coupled",)


def missing_for(method: str, bench: BenchConfig) -> list[str]:
    """What ``method`` needs that the bench config has not, in words (empty: nothing)."""
    out = []
    for kind, words in NEEDS.get(method, ()):
        instrument = getattr(bench.instruments, kind)
        if instrument is None:
            out.append(f"[instruments.{kind}] ({words})")
        elif kind == "input_angle" and instrument.driver in NOT_A_PAIR:
            out.append(f"[instruments.{kind}] as an angle pair source such as counter-2axis (the {instrument.driver} "
                       "driver reads the coupled display, no input angle)")
    return out


def input_speed_limit_rpm(bench: BenchConfig) -> float | None:
    """The input drive's speed limit (rpm of the input) as its options state it (None: not stated)."""
    drive = bench.instruments.input_drive
    limit = getattr(drive.options, "max_velocity_deg_per_s", None) if drive is not None else None
    return None if limit is None else float(limit) / 6.0


def _positive(name: str, value: float | None, default: float) -> float:
    v = default if value is None else float(value)
    if not (math.isfinite(v) and v > 0):
        raise MethodRejected(f"{name} must be a finite number > 0, got {v:g}")
    return v


def build_method_plan(method: str, reducer: ReducerSpec, bench: BenchConfig, *,
                      input_speed_rpm: float | None = None, load_torque_nm: float | None = None,
                      revolutions: float | None = None, ramps: int | None = None,
                      creep_deg_per_s: float | None = None, speeds_rpm: Sequence[float] | None = None,
                      dwell_s: float | None = None) -> MethodPlan:
    """The plan of a turning test of ``reducer`` on ``bench`` (module docstring); MethodRejected (one line naming
    the field and the limit) for what the bench cannot run or a parameter out of bounds."""
    if method not in TURNING_METHODS:
        raise MethodRejected(f"unknown method {method!r} (known: {', '.join(METHODS)})")
    missing = missing_for(method, bench)
    if missing:
        raise MethodRejected(f"{method} needs {' and '.join(missing)}: the bench config has none")
    limit_rpm = input_speed_limit_rpm(bench)
    top_rpm = SPEED_LIMIT_SHARE * limit_rpm if limit_rpm is not None else math.inf
    sim = reducer.sim.transmission if reducer.sim is not None else None
    rated_speed = sim.rated_input_speed_rpm if sim is not None else None
    drive = bench.instruments.input_drive
    accel = float(getattr(drive.options, "acceleration_deg_per_s2", 36000.0)) if drive is not None else 36000.0

    def speed(name: str, value: float) -> float:
        if value > top_rpm:
            raise MethodRejected(f"{name} {value:g} rpm exceeds the input drive's limit ({top_rpm:g} rpm: "
                                 f"{SPEED_LIMIT_SHARE:.0%} of [instruments.input_drive] max_velocity_deg_per_s)")
        return value

    def load(value: float) -> float:
        limit = min(reducer.rated_torque_nm, bench.bench.max_torque_nm)
        if value > limit + 1e-9:
            raise MethodRejected(f"load_torque_nm {value:g} N·m exceeds the rated torque {reducer.rated_torque_nm:g} "
                                 f"N·m of {reducer.name} or the bench limit {bench.bench.max_torque_nm:g} N·m")
        return value

    slope = max(reducer.rated_torque_nm / LOAD_RAMP_S, bench.bench.min_rate_nm_per_s)
    params: dict[str, Any] = {}
    steps: list[MethodStep] = []
    if method == "transmission-error":
        if reducer.ratio is None or not reducer.ratio > 0:
            raise MethodRejected(f"transmission-error needs the ratio of {reducer.name} (the catalogue has none)")
        n = speed("input_speed_rpm", _positive("input_speed_rpm", input_speed_rpm,
                                                min(DEFAULT_TE_SPEED_RPM, top_rpm)))
        revs = _positive("revolutions", revolutions, DEFAULT_TE_REVOLUTIONS)
        if revs < 1.0:
            raise MethodRejected(f"revolutions must be at least 1 output revolution per direction, got {revs:g}")
        light = load(_positive("load_torque_nm", load_torque_nm, DEFAULT_TE_LOAD_SHARE * reducer.rated_torque_nm))
        duration = revs * reducer.ratio * 60.0 / n + SETTLE_S
        steps = [SpeedStep("forward", n, duration, -light), SpeedStep("pause", 0.0, PAUSE_S, 0.0),
                 SpeedStep("reverse", -n, duration, light), SpeedStep("pause", 0.0, PAUSE_S, 0.0)]
        params = {"input_speed_rpm": n, "revolutions": revs, "load_torque_nm": light}
    elif method == "starting-torque":
        count = DEFAULT_RAMPS if ramps is None else int(ramps)
        if not 1 <= count <= 20:
            raise MethodRejected(f"ramps must be 1…20 per direction, got {count}")
        creep = _positive("creep_deg_per_s", creep_deg_per_s, DEFAULT_CREEP_DEG_PER_S)
        if creep > 10.0:
            raise MethodRejected(f"creep_deg_per_s {creep:g} deg/s is not a creep (at most 10 deg/s)")
        for sign, name in ((1.0, "forward"), (-1.0, "reverse")):
            for k in range(count):
                steps += [CreepStep(f"{name} {k + 1}/{count}", sign * creep),
                          SpeedStep("pause", 0.0, PAUSE_S, 0.0)]
        params = {"ramps": count, "creep_deg_per_s": creep, "turn_deg": CREEP_TURN_DEG}
    elif method == "no-load-torque":
        base: float = rated_speed if rated_speed is not None else (limit_rpm or 1000.0)
        defaults = [float(round(min(share * float(base), top_rpm))) for share in DEFAULT_NO_LOAD_SHARES]
        listed = [float(v) for v in (speeds_rpm if speeds_rpm is not None else defaults)]
        if not 1 <= len(listed) <= 10 or len(set(listed)) != len(listed):
            raise MethodRejected(f"speeds_rpm: 1…10 different speeds, got {listed}")
        dwell = _positive("dwell_s", dwell_s, DEFAULT_NO_LOAD_DWELL_S)
        for n in listed:
            n = speed("speeds_rpm", _positive("speeds_rpm", n, 1.0))
            steps += [SpeedStep(f"{n:g} rpm forward", n, dwell + SETTLE_S), SpeedStep("pause", 0.0, PAUSE_S),
                      SpeedStep(f"{n:g} rpm reverse", -n, dwell + SETTLE_S), SpeedStep("pause", 0.0, PAUSE_S)]
        params = {"speeds_rpm": listed, "dwell_s": dwell}
    else:  # efficiency
        default_speed = min(rated_speed if rated_speed is not None else DEFAULT_TE_SPEED_RPM, top_rpm)
        n = speed("input_speed_rpm", _positive("input_speed_rpm", input_speed_rpm, default_speed))
        torque = load(_positive("load_torque_nm", load_torque_nm, reducer.rated_torque_nm))
        dwell = _positive("dwell_s", dwell_s, DEFAULT_EFFICIENCY_DWELL_S)
        for sign, name in ((1.0, "forward"), (-1.0, "reverse")):
            steps += [SpeedStep("load", 0.0, SETTLE_S, -sign * torque),
                      SpeedStep(name, sign * n, dwell + 2 * SETTLE_S, -sign * torque),
                      SpeedStep("stop", 0.0, SETTLE_S, -sign * torque), SpeedStep("unload", 0.0, PAUSE_S, 0.0)]
        params = {"input_speed_rpm": n, "load_torque_nm": torque, "dwell_s": dwell}
    plan = MethodPlan(method, tuple(steps), params, slope, accel)
    longest = bench.bench.max_test_duration_s
    if plan.duration_s() > longest:
        raise MethodRejected(f"the {method} test would take {plan.duration_s() / 3600:.3g} h; the bench's longest "
                             f"test is {longest / 3600:.3g} h")
    return plan
