"""Request and response bodies of the REST API (pydantic models; names carry units)."""

from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, StrictInt, model_validator

from tcms_daq.procedure.methods import Method
from tcms_daq.procedure.plan import MAX_POSITIONS, MAX_RATES, check_method_fields, check_plan_fields
from tcms_daq.runstate import RunState


def _invalid_string(value: Any, where: str = "") -> str | None:
    """Where in ``value`` (a parsed JSON body) a string is not valid Unicode text (a lone surrogate such as
    ``"\\ud800"``, which no store or log can encode), or None."""
    if isinstance(value, str):
        try:
            value.encode("utf-8")
        except UnicodeEncodeError:
            return where or "a string"
        return None
    if isinstance(value, dict):
        for key, item in value.items():
            found = _invalid_string(key, where or "a key") or _invalid_string(item, f"{where}.{key}" if where else
                                                                                str(key))
            if found:
                return found
    elif isinstance(value, list):
        for i, item in enumerate(value):
            found = _invalid_string(item, f"{where}[{i}]")
            if found:
                return found
    return None


class StrictBody(BaseModel):
    """A request body: unknown keys, NaN/infinity, coerced types (``true`` or ``"500"`` for a number) and invalid
    strings (lone surrogates) are a 422 naming the field."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, strict=True)

    @model_validator(mode="before")
    @classmethod
    def _valid_strings(cls, data: Any) -> Any:
        where = _invalid_string(data)
        if where is not None:
            raise ValueError(f"{where}: not valid Unicode text (a lone surrogate)")
        return data


class TestDocumentation(StrictBody):
    """What a test request states for the certificate beside the test itself: who it is for and the conditions.
    (Kept apart from the test's own fields; ``TestRequest`` inherits them.)"""

    customer: str | None = Field(default=None, max_length=120, description="the customer the unit is tested for")
    order_number: str | None = Field(default=None, max_length=64, description="the customer's order number")
    ambient_temperature_c: float | None = Field(
        default=None, ge=-40, le=80, description="ambient temperature during the test, °C (default: the bench "
        "configuration's [certificate] ambient_temperature_c)")


class TestRequest(TestDocumentation):
    """``POST /api/tests``: one torsional characteristic test.

    Continuous profiles ramp at ``rate_nm_per_s``; stepped profiles go in ``step_nm`` steps with ``dwell_s``
    at each step (the torque moves between steps at ``rate_nm_per_s``).
    """

    reducer: str = Field(min_length=1, max_length=64, description="reducer model from the catalogue, e.g. RV-110E")
    method: Method = Field(default="stiffness", description="the test: the stiffness test (default) or a turning test "
                           "of the input (GB/T 35089 §7–8: transmission-error, starting-torque, no-load-torque, "
                           "efficiency; a bench with its second axis)")
    max_torque_nm: float | None = Field(default=None, gt=0, description="test torque T (the profile runs between −T "
                                        "and +T), N·m; required by the stiffness test")
    cycles: int | None = Field(default=3, ge=1, le=50, description="evaluated hysteresis loops (stiffness)")
    profile: Literal["continuous", "stepped"] | None = "continuous"
    rate_nm_per_s: float | None = Field(default=None, gt=0, le=1e5, description="torque rate, N·m/s")
    step_nm: float | None = Field(default=None, gt=0, description="torque step of a stepped profile, N·m")
    dwell_s: float | None = Field(default=None, ge=0, le=600, description="dwell at each step, s")
    serial_number: str | None = Field(default=None, max_length=64)
    operator: str | None = Field(default=None, max_length=64)
    decision_rule: Literal["simple", "guarded"] | None = Field(
        default=None, description="ISO 14253-1 decision: 'guarded' (guard bands of U: pass / fail / undecided) or "
        "'simple' acceptance; default: the bench config's [bench] decision_rule")
    positions: StrictInt | list[float] | None = Field(
        default=None, description=f"test at several output positions (GB/T 40731): a count N (equally spaced over "
        f"360°, 1…{MAX_POSITIONS}) or a list of degrees in [0, 360)")
    rates: list[float] | None = Field(default=None, description=f"the same test at each loading rate, N·m/s "
                                      f"(1…{MAX_RATES} rates)")
    move_velocity_deg_per_s: float | None = Field(default=None, gt=0, le=360,
                                                  description="output speed of the moves between positions, °/s")
    # the turning tests' parameters (each optional; defaults in tcms_daq.procedure.methods)
    input_speed_rpm: float | None = Field(default=None, gt=0, le=20000, description="transmission-error, efficiency: "
                                          "the input's speed, rpm")
    load_torque_nm: float | None = Field(default=None, gt=0, description="transmission-error: the light braking "
                                         "load; efficiency: the braking torque (default the rated torque), N·m")
    revolutions: float | None = Field(default=None, ge=1, le=100, description="transmission-error: output "
                                      "revolutions per direction")
    ramps: int | None = Field(default=None, ge=1, le=20, description="starting-torque: breakaways per direction")
    creep_deg_per_s: float | None = Field(default=None, gt=0, le=10, description="starting-torque: the input's creep "
                                          "velocity while it sticks, deg/s")
    speeds_rpm: list[float] | None = Field(default=None, min_length=1, max_length=10,
                                           description="no-load-torque: the input speeds, rpm")

    @model_validator(mode="after")
    def _method_fields(self) -> TestRequest:
        if self.method != "stiffness":
            for name in ("cycles", "profile"):  # the stiffness test's defaults do not apply to a turning test
                if name in self.model_fields_set and getattr(self, name) is not None:
                    raise ValueError(f"{name} does not apply to method {self.method!r}")
                setattr(self, name, None)
        elif self.max_torque_nm is None:
            raise ValueError("max_torque_nm is required by the stiffness test")
        given = {k: v for k, v in self.model_dump(exclude_none=True).items() if k not in ("method", "reducer")}
        check_method_fields(self.method, given)
        return self

    @model_validator(mode="after")
    def _plan_fields(self) -> TestRequest:
        check_plan_fields(self.positions, self.rates, self.rate_nm_per_s, self.move_velocity_deg_per_s)
        return self

    @model_validator(mode="after")
    def _stepped_fields(self) -> TestRequest:
        if self.method != "stiffness":
            return self
        if self.profile == "continuous" and (self.step_nm is not None or self.dwell_s is not None):
            raise ValueError("step_nm and dwell_s apply only to profile 'stepped'")
        if self.step_nm is not None and self.max_torque_nm is not None and self.step_nm > self.max_torque_nm:
            raise ValueError(f"step_nm {self.step_nm} exceeds max_torque_nm {self.max_torque_nm}")
        return self


class TestAccepted(BaseModel):
    id: str
    status: str


class BudgetLineView(BaseModel):
    """One source of a result's uncertainty budget."""

    model_config = ConfigDict(extra="allow")

    source: str
    type: Literal["A", "B"]
    u_input: float = Field(description="standard uncertainty of the input, in its own unit (input_unit)")
    sensitivity: float = Field(description="result unit per input unit (1 for a Type A line)")
    contribution: float = Field(description="|sensitivity| × u_input, in the result's unit")


class UncertaintyEntry(BaseModel):
    """The GUM uncertainty of one result (JCGM 100): value ± U (k), the budget, the dominant contributor."""

    model_config = ConfigDict(extra="allow")

    value: float
    u: float = Field(description="combined standard uncertainty, in the result's unit")
    U: float = Field(description="expanded uncertainty k·u (95 % coverage), in the result's unit")
    k: float = Field(description="coverage factor (t-based, 95 %)")
    dof: float | None = Field(description="Welch–Satterthwaite effective degrees of freedom (null: infinite)")
    unit: str
    dominant: str | None = Field(description="the source with the largest contribution")
    budget: list[BudgetLineView]


class CheckView(BaseModel):
    """One limit of the verdict with its ISO 14253-1 decision."""

    model_config = ConfigDict(extra="allow")

    quantity: str | None = None
    value: float | None = None
    comparison: str | None = None
    limit: float | None = None
    passed: bool | None = None
    decision: Literal["pass", "fail", "undecided"] | None = None
    guard_band: float | None = Field(None, description="U under the guarded rule, 0 under simple acceptance")
    label: str | None = None


class VerdictView(BaseModel):
    """Pass / fail / undecided per ISO 14253-1; ``passed`` (kept for compatibility) is true only for "pass"."""

    model_config = ConfigDict(extra="allow")

    passed: bool
    decision: Literal["pass", "fail", "undecided"] | None = None
    rule: Literal["simple", "guarded"] | None = None
    checks: dict[str, CheckView] = Field(default_factory=dict)


class StageResultView(BaseModel):
    """One stage of a test at several output positions or loading rates: where it was and what it measured."""

    model_config = ConfigDict(extra="allow")

    position_deg: float | None = Field(None, description="output position of this stage, ° (positions tests)")
    rate_nm_per_s: float | None = Field(None, description="loading rate of this stage, N·m/s")
    rigidity_nm_per_arcmin: float | None = Field(None, description="torsional rigidity, N·m/arcmin")
    lost_motion_arcsec: float | None = Field(None, description="lost motion, arcsec")
    backlash_arcsec: float | None = Field(None, description="backlash (loop width at zero torque), arcsec")
    uncertainty: dict[str, UncertaintyEntry] = Field(default_factory=dict,
                                                     description="this stage's results with U (k), by result name")


class TestResults(BaseModel):
    """A run's evaluation (the keys of ``tcms analyze --json``). The headline results are declared with their
    unit; their expanded uncertainty U (with k and the budget) is ``uncertainty[<name>]``. A test at several
    positions or rates reports the worst stage (``summary_rule``) and each stage in ``positions`` / ``rates``.
    Every other key of the evaluation is kept as it is. Runs evaluated before uncertainty budgets have
    ``uncertainty`` empty; a result that could not be evaluated is null."""

    __test__ = False
    model_config = ConfigDict(extra="allow")

    rigidity_nm_per_arcmin: float | None = Field(
        None, description="torsional rigidity, N·m/arcmin (secant over the rigidity interval, mean of both sides); "
        "U: uncertainty.rigidity_nm_per_arcmin.U")
    lost_motion_arcsec: float | None = Field(
        None, description="lost motion, arcsec (midline at ± the lost-motion torque); U: uncertainty.lost_motion_arcsec.U")
    backlash_arcsec: float | None = Field(
        None, description="backlash, arcsec (loop width at zero torque); U: uncertainty.backlash_arcsec.U")
    loop_energy_j: float | None = Field(None, description="energy dissipated per loop (∮T dθ), J")
    loading_rate_nm_per_s: float | None = Field(None, description="measured loading rate, N·m/s")
    test_torque_nm: float | None = Field(None, description="test torque T the loops reached, N·m")
    rated_torque_nm: float | None = Field(None, description="the reducer's rated torque, N·m")
    n_loops: int | None = Field(None, description="evaluated loops")
    k1_nm_per_rad: float | None = Field(None, description="Harmonic Drive K1, N·m/rad")
    k2_nm_per_rad: float | None = Field(None, description="Harmonic Drive K2, N·m/rad")
    k3_nm_per_rad: float | None = Field(None, description="Harmonic Drive K3, N·m/rad")
    plan: Literal["positions", "rates"] | None = Field(None, description="a test of several stages: its kind")
    summary_rule: str | None = Field(None, description="how the stages are summarised (the worst of them)")
    positions: list[StageResultView] | None = Field(None, description="each output position's results")
    rates: list[StageResultView] | None = Field(None, description="each loading rate's results")
    uncertainty: dict[str, UncertaintyEntry] = Field(default_factory=dict)
    uncertainty_basis: str | None = None
    verdict: VerdictView | None = None
    warnings: list[str] = Field(default_factory=list)


class MeasuredValue(BaseModel):
    """One headline result as it leaves the bench: value, standard and expanded uncertainty (u, U = k·u), coverage
    factor k and unit."""

    label: str = Field(description="what it is, e.g. 'torsional rigidity'")
    value: float | None = Field(description="the result in ``unit`` (null: not evaluated)")
    u: float | None = Field(description="combined standard uncertainty in ``unit`` (null: not stated)")
    U: float | None = Field(description="expanded uncertainty (about 95 %) in ``unit`` (null: not stated)")
    k: float | None = Field(description="coverage factor of U")
    unit: str
    text: str = Field(description="'value ± U unit (k = …)' rounded to two significant digits of U")


class HeadlineResults(BaseModel):
    """The results a test is judged on, each with its unit and U: the stiffness test's three; a turning test's
    headline results (``tcms_daq.identity.METHOD_HEADLINES``, e.g. ``transmission_error_arcsec``) instead, under
    their names."""

    model_config = ConfigDict(extra="allow")

    rigidity_nm_per_arcmin: MeasuredValue | None = None
    lost_motion_arcsec: MeasuredValue | None = None
    backlash_arcsec: MeasuredValue | None = None


class TestSummary(BaseModel):
    __test__ = False

    id: str
    status: RunState  # one of the stored states: queued, running, completed, aborted, failed, interrupted
    created_at: str | None
    started_at: str | None
    finished_at: str | None
    request: TestRequest = Field(description="the request the test was started with")
    results: TestResults | None
    error: str | None
    sample_count: int
    channels: list[str]
    compensation_version: int | None = None  # the compensation version the run used (None: recorded before)
    compensation_sha256: str | None = None  # of the compensator TOML the run used (single-run view)
    bench_id: str | None = Field(None, description="the bench that ran it ([bench] id; None: recorded before fleets)")
    bench_name: str | None = None
    verdict: Literal["pass", "fail", "undecided"] | None = Field(
        None, description="the results' decision (ISO 14253-1 when stated; else pass/fail); None: no verdict")
    headline: dict[str, str] = Field(default_factory=dict, description=(
        "rigidity, lost motion and backlash as text: 'value ± U unit (k = …)', 'value unit (U not stated)' or '—'"))
    headline_results: HeadlineResults | None = Field(
        None, description="rigidity, lost motion and backlash with value, U, k and unit (null: no results)")
    user: str | None = Field(None, description="who started it (a user, or 'service' for the service token)")
    plan: PlanRef | None = Field(None, description="the saved plan version it ran (null: a free request)")


class PlanRef(BaseModel):
    """The saved plan version a run was started from."""

    id: int
    name: str
    version: int


#: what a run's stored request holds beside the request: who started it and from which plan (identity's hooks)
RUN_CONTEXT_KEYS = ("user", "plan")


def request_echo(stored: dict[str, Any]) -> TestRequest:
    """A stored request as the request model. One a later model would refuse (an older run's) is echoed as it
    was stored, its fields as they are (keys the model no longer has are left out)."""
    from pydantic import ValidationError

    try:
        return TestRequest.model_validate(stored)
    except ValidationError:
        return TestRequest.model_construct(**{k: v for k, v in stored.items() if k in TestRequest.model_fields})


def summary_view(summary: dict[str, Any]) -> TestSummary:
    """The API's view of :meth:`tcms_daq.store.StoredRun.summary`, its request echoed as the request model."""
    from tcms_daq.identity import headline_results

    results = summary.get("results")
    stored = summary.get("request") or {}
    echoed = request_echo({k: v for k, v in stored.items() if k not in RUN_CONTEXT_KEYS})
    view = TestSummary.model_validate({
        **summary, "request": _ECHO_PLACEHOLDER, **{key: stored.get(key) for key in RUN_CONTEXT_KEYS},
        "headline_results": headline_results(results) if results else None})
    view.request = echoed  # as echoed: the request model's checks ran when it was submitted (or refused it since)
    return view


#: what the summary is validated with before its echoed request takes its place (a request built by model_construct
#: would be checked again as a field: an older run's, which the model now refuses, answered 500)
_ECHO_PLACEHOLDER = TestRequest.model_construct(reducer="-", method="stiffness", max_torque_nm=1.0)


class LoopView(BaseModel):
    """``GET /api/tests/{id}/loop``: measured (torque, compensated angle) pairs for plotting."""

    id: str
    samples: int = Field(description="samples recorded (the pairs are a min/max selection of them)")
    torque_nm: list[float]
    angle_arcsec: list[float]


class Health(BaseModel):
    status: Literal["ok"]


class DiscrepancyRequest(StrictBody):
    """``POST /api/discrepancy``: a stored run against the bench model re-simulated on its torque trace."""

    run_id: str = Field(min_length=1, max_length=64, description="id of a stored test run")
    signal_period_arcsec: float = Field(
        default=72.0, gt=0, le=3600, description="encoder signal period, arcsec (72 for the RON 786)"
    )
    effects: list[str] | None = Field(
        default=None, min_length=1, description="restrict the candidate effects (default: the whole catalogue)"
    )

    @model_validator(mode="after")
    def _known_effects(self) -> DiscrepancyRequest:
        from tcms_daq.discrepancy.catalogue import EFFECT_NAMES, load_entry_point_effects

        load_entry_point_effects()

        unknown = [e for e in self.effects or () if e not in EFFECT_NAMES]
        if unknown:
            raise ValueError(f"unknown effect {unknown[0]!r} (known: {', '.join(EFFECT_NAMES)})")
        return self


# -- answers ------------------------------------------------------------------------------------------------
class ErrorBody(BaseModel):
    """Every error answer: one line saying what is wrong."""

    detail: str


class ValidationErrorBody(ErrorBody):
    """422: ``detail`` names the field in one line; ``errors`` are pydantic's, when the request did not parse."""

    errors: list[dict[str, Any]] = Field(default_factory=list)


class LoaderStatusView(BaseModel):
    state: str = Field(description="CiA 402 state, e.g. SWITCH ON DISABLED, OPERATION ENABLED, FAULT")
    torque_actual_nm: float
    fault: bool
    error_code: int = Field(description="0x603F error code (0: none)")
    position_deg: float | None = Field(default=None, description="the output's position (0x6064), deg")
    moving: bool = Field(default=False, description="a move between test positions is under way")
    age_s: float | None = Field(default=None, description="real seconds since this status was read")
    live: bool = Field(default=True, description="false: the loader's link is down or stale, this status is old")


class InputDriveStatusView(BaseModel):
    """The input drive's last status (the second axis: CiA 402 profile velocity)."""

    state: str = Field(description="CiA 402 state, e.g. SWITCH ON DISABLED, OPERATION ENABLED, FAULT")
    velocity_deg_per_s: float = Field(description="velocity actual 0x606C at the input shaft, deg/s")
    fault: bool
    error_code: int = Field(description="0x603F error code (0: none)")
    position_deg: float | None = Field(default=None, description="the input shaft's position (0x6064), deg")
    age_s: float | None = Field(default=None, description="real seconds since this status was read")
    live: bool = Field(default=True, description="false: the input drive's link is down or stale, this status is old")


class InstrumentView(BaseModel):
    """One instrument as configured (driver, url …) with its counters; the loader with its last status."""

    model_config = ConfigDict(extra="allow")

    instrument: str | None = None
    readings: int | None = None
    errors: int | None = None
    status: LoaderStatusView | InputDriveStatusView | None = None
    last_value: float | None = Field(default=None, description="the last reading (the channel's unit)")
    age_s: float | None = Field(default=None, description="real seconds since the last reading (None: none yet)")
    link: Literal["up", "stale", "down"] | None = Field(
        default=None, description="up; stale: no new reading for the watchdog time; down: the last request failed")
    last_error: str | None = Field(default=None, description="why the link is down")


class SafeStartView(BaseModel):
    """What the service found on the loader when it connected, and what it did (the safe start)."""

    found_state: str | None
    found_torque_nm: float | None
    found_error_code: int
    actions: list[str]
    safe: bool
    message: str
    safe_torque_nm: float
    final_state: str | None = None
    final_torque_nm: float | None = None


class InterlockView(BaseModel):
    interlock: str
    reason: str
    time_s: float


class ReducerView(BaseModel):
    name: str
    kind: str | None = None
    rated_torque_nm: float
    max_test_torque_nm: float | None = Field(None, description="the largest test torque accepted, N·m")


class TestBounds(BaseModel):
    """The bounds ``POST /api/tests`` keeps (the bench config's ``[bench]``)."""

    min_torque_nm: float | None = Field(None, description="the smallest test torque, N·m ([bench] min_test_torque_nm)")
    max_torque_nm: float
    min_rate_nm_per_s: float
    max_rate_nm_per_s: float
    min_step_nm: float
    max_test_duration_s: float
    max_segments: int


class LiveRates(BaseModel):
    acquisition_rate_samples_per_second: float
    frame_rate_hz: float
    clients: int


class AcquisitionStep(BaseModel):
    """One acquisition step: the interlocks judge each step's batch, so their response time is one step."""

    clock_s: float = Field(description="clock time per step (simulated seconds on a simulated bench)")
    real_s: float | None = Field(description="real seconds per step (None: an unpaced simulated clock)")


class BenchStatus(BaseModel):
    """``GET /api/bench``."""

    name: str
    display_name: str | None = Field(None, description="the name the pages show (the admin's setting; null: "
                                     "name)")
    id: str | None = Field(None, description="the bench's id ([bench] id): its runs are GET /api/tests?bench=<id>")
    config: str | None = None
    max_torque_nm: float
    clock: Literal["simulated", "monotonic"] | None = None
    sim_speed: float | None = None
    monotonic_at_clock_zero_s: float | None = None
    connected: bool | None = None
    compensation: str | None = None
    instruments: dict[str, InstrumentView]
    last_interlock: InterlockView | None = None
    samples_published: int = 0
    reducers: list[ReducerView]
    test_bounds: TestBounds | None = None
    acquisition_step: AcquisitionStep | None = None
    safe_start: SafeStartView | None = None
    input_safe_start: SafeStartView | None = Field(default=None, description="what the safe start found on the input "
                                                   "drive and did (the second axis; null: none)")
    methods: dict[str, str | None] = Field(default_factory=dict, description="each test method and why this bench "
                                           "cannot run it (null: it can)")
    not_ready: str | None = Field(default=None, description="why no test is accepted now (409), None: ready")
    active_test: str | None
    live: LiveRates


class CompensationVersion(BaseModel):
    version: int
    created_at: str | None
    note: str
    sha256: str
    rollback_of: int | None = None


class CompensationDryRun(BaseModel):
    """``PUT /api/compensation?dry_run=true``: what the upload would do; nothing is stored."""

    reference: str = Field(description="the record the change is judged on: the last completed run or a synthetic loop")
    rigidity_change_pct: float | None = Field(description="relative change of the reference's rigidity, % "
                                              "(+: stiffer; null: the upload leaves no usable slope)")
    refused: str | None = Field(description="why the upload would be refused without force=true (null: accepted)")


class DiscrepancyListItem(BaseModel):
    id: str
    run_id: str
    created_at: str | None
    report_url: str
    verdict: str | None = None
    model_version: int | None = None
    cv_rms_before_arcsec: float | None
    cv_rms_after_arcsec: float | None
    effects: list[str]


class SuggestedRun(BaseModel):
    """A run to add where one run cannot identify an effect (an alias group): what it separates and how."""

    names: list[str] = Field(description="the effects this run cannot tell apart")
    kind: Literal["second_rate", "tip_holds"] = Field(
        description="second_rate: the same test at a second loading rate; tip_holds: a stepped profile holding "
        "at each step, the torque tips included")
    why: str = Field(description="the experiment that separates them, in words")
    request: dict[str, Any] = Field(description="the POST /api/tests body that starts that run")


class DiscrepancyAnalysis(BaseModel):
    """One analysis (``tcms discrepancy --json`` plus its id, run and report); further keys as the CLI's."""

    model_config = ConfigDict(extra="allow")

    id: str
    run_id: str
    created_at: str | None
    options: dict[str, Any]
    report_url: str
    model_version: int | None = Field(None, description="the bench model version it was compared against")
    verdict: Literal["consistent", "explained", "partially_explained", "unexplained"] | None = Field(
        None, description="is what remains noise? (None: stored before verdicts existed)")
    verdict_words: str | None = None
    verdict_notices: list[dict[str, Any]] = Field(
        default_factory=list, description="verdict_words sentence by sentence as {code, params, text}: the pages "
        "translate each from notice.<code> of the message catalogue")
    noise_floor_arcsec: float | None = None
    names_provisional: bool | None = None
    unexplained: dict[str, Any] | None = Field(
        None, description="where the remaining structure is, how large and what shape (None when none remains)")
    effects: list[dict[str, Any]]
    rms_before_arcsec: float | None = None
    rms_after_arcsec: float | None = None
    cv_rms_before_arcsec: float | None = None
    cv_rms_after_arcsec: float | None = None
    suggested_runs: list[SuggestedRun] = Field(
        default_factory=list, description="the runs that would separate what this run cannot (an alias group), "
        "each with the POST /api/tests body that starts it")


class ApplyRequest(StrictBody):
    """``POST /api/discrepancy/{id}/apply``: add the analysis's named effects to the bench model."""

    accept_provisional: bool = Field(
        False, description="add them even when the verdict left their names provisional (structure remained)")


class BenchModelTerm(BaseModel):
    name: str
    parameters: dict[str, float]
    aliased_with: list[str]
    standard_uncertainty: dict[str, float] = Field(default_factory=dict, description="k = 1 (jackknife over loops)")
    uncertainty_dof: int | None = Field(None, description="degrees of freedom of the standard uncertainties: the "
                                        "jackknife's groups g − 1")
    coverage_factor: float | None = Field(None, description="k of the expanded uncertainty (Student's t, about 95 %)")
    expanded_uncertainty: dict[str, float] = Field(default_factory=dict, description="U = k·u, about 95 %")


class BenchModelVersionView(BaseModel):
    version: int
    created_at: str | None
    note: str
    sha256: str
    analysis_id: str | None
    run_id: str | None


class BenchModelView(BaseModel):
    """The bench model in use: the catalogue reducer's forward model plus the effects accepted into it."""

    version: int = Field(description="0: the catalogue model alone")
    terms: list[BenchModelTerm]
    toml: str | None = Field(description="the accepted effects as a discrepancy model file (None at version 0)")
    history: list[BenchModelVersionView] = Field(description="every version, newest first, with its provenance")


class LiveClientView(BaseModel):
    name: str
    sent: int
    dropped: int
    queued: int


class LiveStats(BaseModel):
    sequence: int
    frames_total: int
    dropped_total: int
    samples_decimated_total: int
    evicted_total: int
    clients: list[LiveClientView]


class SpcRun(BaseModel):
    id: str
    created_at: str | None
    bench_id: str | None
    serial_number: str | None
    value: float


class ImrChartView(BaseModel):
    """Individuals / moving-range chart (``tcms_daq.spc.individuals_chart``)."""

    values: list[float | None]
    moving_range: list[float | None] = Field(description="|x_i − x_(i−1)|; null for the first run")
    baseline_n: int = Field(description="the first baseline_n runs set the limits")
    center: float
    sigma: float = Field(description="MR̄/d₂ of the baseline")
    ucl: float
    lcl: float
    mr_center: float
    mr_ucl: float
    flags: list[list[str]] = Field(description="per run the rules it breaks: beyond_3_sigma, run_of_8")
    out_of_control: list[int]


class SpcChartView(BaseModel):
    """``GET /api/spc/chart``: one series (a reducer model, a test method, one bench or the fleet)."""

    quantity: str
    unit: str
    reducer: str
    bench: str | None
    method: str = Field(description="the series' test method: single, positions-N or rates-N")
    methods: dict[str, int] = Field(description="completed runs of this reducer (and bench) by test method")
    runs: list[SpcRun]
    baseline_n: int = Field(description="runs in the baseline that sets the limits")
    limits: Literal["none", "provisional", "established"] = Field(
        description="none: too few runs for limits (chart null); provisional: a baseline under 20 runs")
    note: str = Field(description="the baseline and the state of the limits in words")
    chart: ImrChartView | None


class BenchBiasRow(BaseModel):
    bench: str
    bias: float = Field(description="this bench's results minus the reference's, in the quantity's unit")
    u: float = Field(description="standard uncertainty")
    U: float = Field(description="expanded uncertainty, k·u")
    k: float
    runs: int
    units: int


class BenchBiasView(BaseModel):
    """``GET /api/spc/bias``: bench biases from reference units tested on several benches."""

    quantity: str
    unit: str
    reducer: str
    method: str = Field(description="the test method of the runs used: single, positions-N or rates-N")
    reference: str | None = Field(description="the bench whose bias is 0 (null: the benches' mean is 0)")
    dof: int
    residual_sd: float = Field(description="repeatability of one test, pooled")
    units: list[str] = Field(description="serial numbers of the reference units used")
    excluded_runs: int = Field(description="runs of units tested on one bench only")
    benches: list[BenchBiasRow]


# -- people: users, the audit trail, saved plans (routes/people.py, routes/plans.py) ------------------------------
Role = Literal["operator", "engineer", "admin"]


class Login(BaseModel):
    name: str = Field(min_length=1, max_length=64)
    password: str = Field(min_length=1, max_length=256)


class Me(BaseModel):
    """Who the request's credential names, and the role's rights."""

    name: str
    role: str
    via: str
    rights: list[str]


class UserView(BaseModel):
    name: str
    role: str
    disabled: bool
    created_at: str | None


class NewUser(BaseModel):
    name: str = Field(min_length=1, max_length=64, pattern=r"^[A-Za-z0-9][A-Za-z0-9._@-]*$")
    role: Role
    password: str = Field(min_length=8, max_length=256)


class NewToken(BaseModel):
    label: str = Field(default="", max_length=80, description="what the token is for (a script, a PC)")


class TokenIssued(BaseModel):
    user: str
    token: str = Field(description="the API token: shown this once, kept only as a hash")


class AuditView(BaseModel):
    """One change of state: when, who, what, and the version or hash before and after."""

    id: int
    at: str | None
    user: str
    role: str | None
    action: str
    target: str | None
    before: str | None
    after: str | None
    detail: str | None
    bench_id: str | None


class PlanBody(BaseModel):
    """``POST /api/plans``: the next version of plan ``name`` (version 1 when the name is new)."""

    model_config = ConfigDict(extra="forbid")

    name: str = Field(min_length=1, max_length=80, pattern=r"^[^\x00-\x1f]+$",
                      description="the plan's name, e.g. 'RV-110E incoming inspection'")
    note: str = Field(default="", max_length=200, description="what changed in this version")
    request: TestRequest = Field(description="the test it runs: reducer, profile, torque, rates or positions, "
                                 "loops, decision rule (the limits policy); the unit's serial number, customer "
                                 "and order are given at each start")


class PlanView(BaseModel):
    id: int = Field(description="this version's id (``plan_id`` of a start)")
    name: str
    version: int
    created_at: str | None
    created_by: str
    note: str
    request: dict[str, Any]
    sha256: str = Field(description="of the request as JSON with sorted keys")


class PlanStart(TestDocumentation):
    """``POST /api/tests/from-plan``: run version ``plan_id`` of a saved plan on one unit."""

    model_config = ConfigDict(extra="forbid")

    plan_id: int = Field(ge=1, le=2**31 - 1, description="the id of a plan version (GET /api/plans)")
    serial_number: str | None = Field(default=None, max_length=64)
    operator: str | None = Field(default=None, max_length=64)


class TeDiscrepancyRequest(StrictBody):
    """``POST /api/te-discrepancy``: a stored transmission-error run against its unit's TE model."""

    run_id: str = Field(min_length=1, max_length=64, description="id of a completed transmission-error run")


class TeDiscrepancyAnalysis(BaseModel):
    """A TE discrepancy analysis (``tcms_daq.transmission.te_model.TeComparison`` with its run and model)."""

    model_config = ConfigDict(extra="allow")

    id: str
    run_id: str
    reducer: str
    against_version: int = Field(description="the TE model version it was compared with (0: the catalogue's)")
    verdict: Literal["consistent", "explained", "partially_explained", "unexplained"]
    verdict_words: str
    findings: list[dict[str, Any]] = Field(description="each line of TE − model: order, amplitude_arcsec, phase_deg, "
                                           "component (null: no component), allowance_arcsec, significant, kind")
    named_orders: list[float]
    unexplained_orders: list[float]
    rms_residual_arcsec: float
    noise_amplitude_arcsec: float
    proposed_toml: str | None = Field(description="the model's next version if applied (null: nothing named)")


class TeModelView(BaseModel):
    """A reducer type's TE model in use and the store's TE model history."""

    model_config = ConfigDict(extra="allow")

    reducer: str
    version: int
    ratio: float
    harmonics: list[dict[str, Any]]
    toml: str
    history: list[dict[str, Any]]
