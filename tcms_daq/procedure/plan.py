"""A test plan as data (pure): the stages of a test at several output positions or several loading rates.

GB/T 40731-2021 measures lost motion at several output positions (catalogues state the maximum over 4), and
results depend on the loading rate. A plan is a list of stages; each stage is a whole profile (approach,
conditioning, evaluated loops, return to zero) at one output position or one rate. A stage at a position
starts with a :class:`Move` of the output, made at zero torque by the loader's profile position mode.

- single: one stage where the output is (the classic test);
- positions: ``positions`` = N (N equally spaced over 360°, from 0°) or a list of degrees in [0, 360);
- rates: ``rates`` = a list of loading rates (N·m/s), the same test at each, where the output is.

A request becomes a plan in one place, :func:`plan_from_request` (the CLI, the service and saved plans call it);
a turning test's (``method`` other than ``stiffness``) is made there too, by ``tcms_daq.procedure.methods``.
Its limit policy, checked there once:

- the test torque T (the request's, else ``[procedure] max_torque_nm``, else the reducer's rated torque) must lie
  between the bench's ``[bench] min_test_torque_nm`` and ``max_torque_nm`` and not exceed the catalogue's rated
  torque of the reducer under test (a stiffness test never loads a reducer beyond its rating);
- the loading rate, step, segments and duration keep the bench's bounds (:func:`check_test_bounds`, per stage,
  then the whole plan against ``max_segments`` and ``max_test_duration_s``);
- at run time the measured torque is watched by the torque interlock at the bench limit and at
  ``REDUCER_TORQUE_HEADROOM`` × the rated torque (overshoot of the torque loop), and the loader's drive refuses a
  setpoint beyond its own ``max_torque_nm`` (the last guard; the bench limit when the loader names none).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, StrictInt, ValidationError, model_validator

from tcms_daq.config.models import BenchConfig, BenchSection, DecisionRule, ReducerSpec, TestProfile
from tcms_daq.errors import TcmsError
from tcms_daq.procedure.methods import METHOD_FIELDS, Method, MethodPlan, MethodRejected, build_method_plan
from tcms_daq.procedure.profiles import Profile, Segment, build_profile, check_test_bounds

MAX_POSITIONS = 36
MAX_RATES = 10
DEFAULT_MOVE_VELOCITY_DEG_PER_S = 30.0  # output speed of a move between positions
MOVE_SETTLE_S = 0.5  # allowance per move beyond its travel time (acceleration, target window)

PlanKind = Literal["single", "positions", "rates"]


@dataclass(frozen=True)
class Move:
    """Turn the output to ``position_deg`` at ``velocity_deg_per_s`` (zero torque; profile position mode)."""

    position_deg: float
    velocity_deg_per_s: float


@dataclass(frozen=True)
class Stage:
    """One whole profile of the plan: at output position ``position_deg`` (None: where the output is)."""

    index: int
    profile: Profile
    position_deg: float | None = None

    @property
    def rate_nm_per_s(self) -> float:
        return self.profile.rate_nm_per_s


@dataclass(frozen=True)
class Plan:
    """The stages of a test, in order, and how the output moves between them."""

    kind: PlanKind
    stages: tuple[Stage, ...]
    move_velocity_deg_per_s: float = DEFAULT_MOVE_VELOCITY_DEG_PER_S
    start_position_deg: float = 0.0  # where the output is assumed to start (for the duration estimate only)
    extra: dict[str, Any] = field(default_factory=dict)

    def steps(self) -> list[tuple[int, Move | Segment]]:
        """(stage index, step) in order: a Move before each positioned stage, then its segments."""
        out: list[tuple[int, Move | Segment]] = []
        for stage in self.stages:
            if stage.position_deg is not None:
                out.append((stage.index, Move(stage.position_deg, self.move_velocity_deg_per_s)))
            out.extend((stage.index, seg) for seg in stage.profile.segments)
        return out

    def step_durations_s(self) -> list[float]:
        """Planned clock time of each step of :meth:`steps` (moves: travel + MOVE_SETTLE_S)."""
        out: list[float] = []
        position, level = self.start_position_deg, 0.0
        for _, step in self.steps():
            if isinstance(step, Move):
                out.append(abs(step.position_deg - position) / step.velocity_deg_per_s + MOVE_SETTLE_S)
                position = step.position_deg
            else:
                out.append(step.duration_s(level))
                level = step.target_nm
        return out

    def duration_s(self) -> float:
        return float(sum(self.step_durations_s()))

    @property
    def segments(self) -> list[Segment]:
        """Every torque segment of the plan (for limits and validation)."""
        return [step for _, step in self.steps() if isinstance(step, Segment)]

    @property
    def first(self) -> Profile:
        return self.stages[0].profile

    def to_dict(self) -> dict[str, Any]:
        return {
            "plan": self.kind,
            "stages": [{"index": s.index, "position_deg": s.position_deg, "rate_nm_per_s": s.rate_nm_per_s,
                        "duration_s": s.profile.duration_s()} for s in self.stages],
            "move_velocity_deg_per_s": self.move_velocity_deg_per_s,
            "plan_duration_s": self.duration_s(),
            **({"positions_deg": [s.position_deg for s in self.stages]} if self.kind == "positions" else {}),
            **({"rates_nm_per_s": [s.rate_nm_per_s for s in self.stages]} if self.kind == "rates" else {}),
        }


def positions_from(spec: int | Sequence[float]) -> list[float]:
    """Output positions (deg) of ``spec``: N → N equally spaced over 360° from 0°; a list → those positions.
    ValueError (one line) for a count outside 1…MAX_POSITIONS, a non-finite, out-of-range or repeated angle."""
    if isinstance(spec, bool):
        raise ValueError("positions must be a count or a list of degrees")
    if isinstance(spec, int):
        if not 1 <= spec <= MAX_POSITIONS:
            raise ValueError(f"positions must be 1…{MAX_POSITIONS}, got {spec}")
        return [360.0 * i / spec for i in range(spec)]
    values = [float(v) for v in spec]
    if not 1 <= len(values) <= MAX_POSITIONS:
        raise ValueError(f"positions: 1…{MAX_POSITIONS} angles, got {len(values)}")
    for v in values:
        if not (math.isfinite(v) and 0.0 <= v < 360.0):
            raise ValueError(f"positions: each angle must be a finite number of degrees in [0, 360), got {v:g}")
    if len({round(v, 6) for v in values}) != len(values):
        raise ValueError("positions: an angle is repeated")
    return values


def rates_from(spec: Sequence[float]) -> list[float]:
    """Loading rates (N·m/s) of ``spec``; ValueError for fewer than 1 or more than MAX_RATES, a rate that is not
    a finite positive number, or a repeated rate (the bench bounds are checked by :func:`build_plan`)."""
    values = [float(v) for v in spec]
    if not 1 <= len(values) <= MAX_RATES:
        raise ValueError(f"rates: 1…{MAX_RATES} loading rates, got {len(values)}")
    for v in values:
        if not (math.isfinite(v) and v > 0):
            raise ValueError(f"rates: each rate must be a finite number > 0 N·m/s, got {v:g}")
    if len(set(values)) != len(values):
        raise ValueError("rates: a rate is repeated")
    return values


def build_plan(test: TestProfile, reducer: ReducerSpec | None, bench: BenchSection, *,
               positions: int | Sequence[float] | None = None, rates: Sequence[float] | None = None,
               move_velocity_deg_per_s: float = DEFAULT_MOVE_VELOCITY_DEG_PER_S) -> Plan:
    """The plan of a test: ``check_test_bounds`` for each stage, then the whole plan against the bench's longest
    test and most segments. ValueError (one line naming the field) for anything out of bounds."""
    if positions is not None and rates is not None:
        raise ValueError("positions and rates cannot be combined in one test (run one plan after the other)")
    if not (math.isfinite(move_velocity_deg_per_s) and move_velocity_deg_per_s > 0):
        raise ValueError(f"move velocity must be a finite number > 0 deg/s, got {move_velocity_deg_per_s:g}")
    torque = test.max_torque_nm if test.max_torque_nm is not None else (reducer.rated_torque_nm if reducer else None)
    if torque is None:
        raise ValueError("max_torque_nm is needed when no reducer is given")
    stage_tests: list[tuple[TestProfile, float | None]]
    if rates is not None:
        stage_tests = [(test.model_copy(update={"rate_nm_per_s": r}), None) for r in rates_from(rates)]
        kind: PlanKind = "rates"
    elif positions is not None:
        stage_tests = [(test, p) for p in positions_from(positions)]
        kind = "positions"
    else:
        stage_tests = [(test, None)]
        kind = "single"
    stages = []
    for i, (stage_test, position) in enumerate(stage_tests):
        check_test_bounds(stage_test, torque, bench)
        stages.append(Stage(i, build_profile(stage_test, reducer), position))
    plan = Plan(kind, tuple(stages), move_velocity_deg_per_s)
    n_segments = len(plan.segments)
    if n_segments > bench.max_segments:
        raise ValueError(f"the plan has {n_segments} segments; the bench takes at most {bench.max_segments}")
    duration_s = plan.duration_s()
    if duration_s > bench.max_test_duration_s:
        raise ValueError(f"the plan would take {duration_s / 3600:.3g} h; the bench's longest test is "
                         f"{bench.max_test_duration_s / 3600:.3g} h")
    return plan


def single_plan(profile: Profile) -> Plan:
    """The plan of one profile where the output is (no move)."""
    return Plan("single", (Stage(0, profile, None),))


# ------------------------------------------------------------------------------------------ request -> plan

#: the torque interlock's reducer limit, as a multiple of the rated torque: room for the torque loop's overshoot
#: above a test torque at the rated torque (the request itself may not exceed the rated torque)
REDUCER_TORQUE_HEADROOM = 1.1


class PlanRejected(TcmsError):
    """A test request the bench cannot run (unknown reducer, a torque or a bound exceeded): one line naming the
    field and the limit."""


def check_plan_fields(positions: int | list[float] | None, rates: list[float] | None, rate_nm_per_s: float | None,
                      move_velocity_deg_per_s: float | None) -> None:
    """Raise ValueError when a request's positions, rates, rate and move velocity do not make one test (the check
    every request model runs: the service's TestRequest and the procedure's PlanRequest)."""
    if positions is not None and rates is not None:
        raise ValueError("positions and rates cannot be combined in one test")
    if positions is not None:
        positions_from(positions)
    if rates is not None:
        rates_from(rates)
        if rate_nm_per_s is not None:
            raise ValueError("rate_nm_per_s and rates exclude each other")
    if move_velocity_deg_per_s is not None and positions is None:
        raise ValueError("move_velocity_deg_per_s applies to a test with positions only")


#: the stiffness test's request fields (refused with a turning method)
STIFFNESS_FIELDS = ("max_torque_nm", "profile", "cycles", "conditioning_loops", "rate_nm_per_s", "step_nm", "positions",
                    "rates", "move_velocity_deg_per_s", "decision_rule")


def check_method_fields(method: str, given: Mapping[str, Any]) -> None:
    """Raise ValueError when a request's fields do not belong to its method: a turning method's parameters with
    another method (the stiffness test's included), the stiffness test's fields with a turning method
    (``dwell_s`` is the stepped profile's and the no-load and efficiency tests')."""
    own = set(METHOD_FIELDS.get(method, ()))
    turning = {f for fields in METHOD_FIELDS.values() for f in fields} - {"dwell_s"}
    foreign = sorted(f for f in given if f in turning and f not in own)
    if method != "stiffness":
        foreign += sorted(f for f in given if f in STIFFNESS_FIELDS)
        if "dwell_s" in given and "dwell_s" not in own:
            foreign.append("dwell_s")
    if foreign:
        takes = ", ".join(METHOD_FIELDS.get(method, ())) or "the stiffness test's fields"
        raise ValueError(f"{', '.join(foreign)} do(es) not apply to method {method!r} (it takes {takes})")


class PlanRequest(BaseModel):
    """What a test request asks for (the CLI's options, the service's ``POST /api/tests``, a saved plan). A field
    left None takes the bench config's ``[procedure]`` value (the test torque: the reducer's rated torque)."""

    __test__ = False  # not a pytest test class
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    reducer: str = Field(min_length=1, max_length=64)
    max_torque_nm: float | None = Field(None, gt=0.0)
    profile: Literal["continuous", "stepped"] | None = None
    cycles: int | None = Field(None, ge=1)
    conditioning_loops: int | None = Field(None, ge=1)
    rate_nm_per_s: float | None = Field(None, gt=0.0)
    step_nm: float | None = Field(None, gt=0.0)
    dwell_s: float | None = Field(None, ge=0.0)
    positions: StrictInt | list[float] | None = None
    rates: list[float] | None = None
    move_velocity_deg_per_s: float | None = Field(None, gt=0.0)
    decision_rule: DecisionRule | None = None
    # the turning tests (tcms_daq.procedure.methods): the method and its parameters
    method: Method = "stiffness"
    input_speed_rpm: float | None = Field(None, gt=0.0)
    load_torque_nm: float | None = Field(None, gt=0.0)
    revolutions: float | None = Field(None, ge=1.0, le=100.0)
    ramps: int | None = Field(None, ge=1, le=20)
    creep_deg_per_s: float | None = Field(None, gt=0.0, le=10.0)
    speeds_rpm: list[float] | None = Field(None, min_length=1, max_length=10)

    @model_validator(mode="after")
    def _plan_fields(self) -> PlanRequest:
        check_plan_fields(self.positions, self.rates, self.rate_nm_per_s, self.move_velocity_deg_per_s)
        check_method_fields(self.method, self.model_dump(exclude_none=True, exclude={"method"}))
        return self


@dataclass(frozen=True)
class TestPlan:
    """A request the bench can run: the reducer under test, the plan of its stages and the decision rule."""

    __test__ = False  # not a pytest test class

    request: PlanRequest
    reducer: ReducerSpec
    plan: Plan
    decision_rule: DecisionRule

    @property
    def profile(self) -> Profile:
        """The first stage's profile (a single test's only one)."""
        return self.plan.first

    @property
    def reducer_torque_limit_nm(self) -> float:
        """The torque interlock's limit for the reducer under test (measured torque, N·m)."""
        return REDUCER_TORQUE_HEADROOM * self.reducer.rated_torque_nm

    def summary(self) -> dict[str, Any]:
        """The profile, the reducer and the plan's stages as a run records them."""
        return {**self.profile.to_dict(), "reducer": self.reducer.name,
                "rated_torque_nm": self.reducer.rated_torque_nm, "segments": len(self.plan.segments),
                "decision_rule": self.decision_rule,
                **(self.plan.to_dict() if self.plan.kind != "single" else {})}


def _find_reducer(catalogue: Mapping[str, ReducerSpec], name: str) -> ReducerSpec:
    spec = catalogue.get(name)
    if spec is None:
        folded = {k.casefold(): v for k, v in catalogue.items()}
        spec = folded.get(name.casefold())
    if spec is None:
        raise PlanRejected(f"unknown reducer {name!r} (known: {', '.join(catalogue)})")
    return spec


def _one_line(exc: ValidationError) -> str:
    err = exc.errors()[0]
    where = ".".join(str(part) for part in err["loc"])
    return f"{where}: {err['msg']}" if where else str(err["msg"])


@dataclass(frozen=True)
class MethodTestPlan:
    """A turning test the bench can run (``tcms_daq.procedure.methods``): the request, the unit and its plan."""

    __test__ = False  # not a pytest test class

    request: PlanRequest
    reducer: ReducerSpec
    method_plan: MethodPlan

    @property
    def method(self) -> str:
        return self.method_plan.method

    @property
    def reducer_torque_limit_nm(self) -> float:
        """The torque interlock's limit for the unit under test (measured loader torque, N·m)."""
        return REDUCER_TORQUE_HEADROOM * self.reducer.rated_torque_nm

    def summary(self) -> dict[str, Any]:
        """What a run records of its plan: the method, the unit and the plan's steps and parameters."""
        return {"method": self.method, "reducer": self.reducer.name, "ratio": self.reducer.ratio,
                "rated_torque_nm": self.reducer.rated_torque_nm, **self.method_plan.to_dict()}


def plan_from_request(request: PlanRequest, bench: BenchConfig, catalogue: Mapping[str, ReducerSpec]
                      ) -> TestPlan | MethodTestPlan:
    """The plan of ``request`` on the bench ``bench`` configures, for a reducer of ``catalogue``: the request's
    fields over the config's ``[procedure]``, checked against the limit policy of this module (once); a turning
    method's (``request.method``) by ``tcms_daq.procedure.methods.build_method_plan``. PlanRejected (one line naming
    the field and the limit, or what the bench lacks) when the bench cannot run it."""
    reducer = _find_reducer(catalogue, request.reducer)
    if request.method != "stiffness":
        try:
            method_plan = build_method_plan(
                request.method, reducer, bench, input_speed_rpm=request.input_speed_rpm,
                load_torque_nm=request.load_torque_nm, revolutions=request.revolutions, ramps=request.ramps,
                creep_deg_per_s=request.creep_deg_per_s, speeds_rpm=request.speeds_rpm, dwell_s=request.dwell_s)
        except MethodRejected as exc:
            raise PlanRejected(str(exc)) from None
        return MethodTestPlan(request, reducer, method_plan)
    defaults = bench.procedure
    torque_nm = request.max_torque_nm or defaults.max_torque_nm or reducer.rated_torque_nm
    smallest = bench.bench.min_test_torque_nm
    if torque_nm < smallest:
        raise PlanRejected(f"max_torque_nm {torque_nm:g} N·m is below the bench's minimum test torque "
                           f"{smallest:g} N·m ([bench] min_test_torque_nm)")
    if torque_nm > bench.bench.max_torque_nm:
        raise PlanRejected(f"max_torque_nm {torque_nm:g} N·m exceeds the bench limit "
                           f"{bench.bench.max_torque_nm:g} N·m")
    if torque_nm > reducer.rated_torque_nm:
        raise PlanRejected(f"max_torque_nm {torque_nm:g} N·m exceeds the rated torque "
                           f"{reducer.rated_torque_nm:g} N·m of {reducer.name}")
    asked = {"kind": request.profile, "cycles": request.cycles, "conditioning_loops": request.conditioning_loops,
             "rate_nm_per_s": request.rate_nm_per_s, "step_nm": request.step_nm, "dwell_s": request.dwell_s}
    try:
        test = defaults.model_copy(update={"max_torque_nm": torque_nm,
                                           **{k: v for k, v in asked.items() if v is not None}})
        test = TestProfile.model_validate(test.model_dump())
    except ValidationError as exc:
        raise PlanRejected(_one_line(exc)) from None
    try:
        plan = build_plan(test, reducer, bench.bench, positions=request.positions, rates=request.rates,
                          **({"move_velocity_deg_per_s": request.move_velocity_deg_per_s}
                             if request.move_velocity_deg_per_s is not None else {}))
    except ValueError as exc:
        raise PlanRejected(str(exc).splitlines()[0]) from None
    return TestPlan(request, reducer, plan, request.decision_rule or bench.bench.decision_rule)
