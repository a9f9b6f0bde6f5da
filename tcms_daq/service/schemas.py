"""Request and response bodies of the REST API (pydantic models; names carry units)."""

from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from tcms_daq.runstate import RunState


class TestRequest(BaseModel):
    """``POST /api/tests``: one torsional characteristic test.

    Continuous profiles ramp at ``rate_nm_per_s``; stepped profiles go in ``step_nm`` steps with ``dwell_s``
    at each step (the torque moves between steps at ``rate_nm_per_s``).
    """

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    reducer: str = Field(min_length=1, max_length=64, description="reducer model from the catalogue, e.g. RV-110E")
    max_torque_nm: float = Field(gt=0, description="test torque T (the profile runs between −T and +T), N·m")
    cycles: int = Field(default=3, ge=1, le=50, description="evaluated hysteresis loops")
    profile: Literal["continuous", "stepped"] = "continuous"
    rate_nm_per_s: float | None = Field(default=None, gt=0, le=1e5, description="torque rate, N·m/s")
    step_nm: float | None = Field(default=None, gt=0, description="torque step of a stepped profile, N·m")
    dwell_s: float | None = Field(default=None, ge=0, le=600, description="dwell at each step, s")
    serial_number: str | None = Field(default=None, max_length=64)
    operator: str | None = Field(default=None, max_length=64)

    @model_validator(mode="after")
    def _stepped_fields(self) -> TestRequest:
        if self.profile == "continuous" and (self.step_nm is not None or self.dwell_s is not None):
            raise ValueError("step_nm and dwell_s apply only to profile 'stepped'")
        if self.step_nm is not None and self.step_nm > self.max_torque_nm:
            raise ValueError(f"step_nm {self.step_nm} exceeds max_torque_nm {self.max_torque_nm}")
        return self


class TestAccepted(BaseModel):
    id: str
    status: str


class TestSummary(BaseModel):
    id: str
    status: RunState  # one of the stored states: queued, running, completed, aborted, failed, interrupted
    created_at: str | None
    started_at: str | None
    finished_at: str | None
    request: dict[str, Any]
    results: dict[str, Any] | None
    error: str | None
    sample_count: int
    channels: list[str]
    compensation_version: int | None = None  # the accepted compensation upload the run used (None: config file)
    compensation_sha256: str | None = None  # of the compensator TOML the run used (single-run view)
    bench_id: str | None = Field(None, description="the bench that ran it ([bench] id; None: recorded before fleets)")
    bench_name: str | None = None
    verdict: Literal["pass", "fail", "undecided"] | None = Field(
        None, description="the results' decision (ISO 14253-1 when stated; else pass/fail); None: no verdict")
    headline: dict[str, str] = Field(default_factory=dict, description=(
        "rigidity, lost motion and backlash as text: 'value ± U unit (k = …)', 'value unit (U not stated)' or '—'"))


class LoopView(BaseModel):
    """``GET /api/tests/{id}/loop``: measured (torque, compensated angle) pairs for plotting."""

    id: str
    samples: int = Field(description="samples recorded (the pairs are a min/max selection of them)")
    torque_nm: list[float]
    angle_arcsec: list[float]


class Health(BaseModel):
    status: Literal["ok"]


class DiscrepancyRequest(BaseModel):
    """``POST /api/discrepancy``: a stored run against the bench model re-simulated on its torque trace."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

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


class InstrumentView(BaseModel):
    """One instrument as configured (driver, url …) with its counters; the loader with its last status."""

    model_config = ConfigDict(extra="allow")

    instrument: str | None = None
    readings: int | None = None
    errors: int | None = None
    status: LoaderStatusView | None = None


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
    active_test: str | None
    live: LiveRates


class CompensationVersion(BaseModel):
    version: int
    created_at: str | None
    note: str
    sha256: str
    rollback_of: int | None = None


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
    noise_floor_arcsec: float | None = None
    names_provisional: bool | None = None
    unexplained: dict[str, Any] | None = Field(
        None, description="where the remaining structure is, how large and what shape (None when none remains)")
    effects: list[dict[str, Any]]
    rms_before_arcsec: float | None = None
    rms_after_arcsec: float | None = None
    cv_rms_before_arcsec: float | None = None
    cv_rms_after_arcsec: float | None = None


class ApplyRequest(BaseModel):
    """``POST /api/discrepancy/{id}/apply``: add the analysis's named effects to the bench model."""

    model_config = ConfigDict(extra="forbid")

    accept_provisional: bool = Field(
        False, description="add them even when the verdict left their names provisional (structure remained)")


class BenchModelTerm(BaseModel):
    name: str
    parameters: dict[str, float]
    aliased_with: list[str]
    standard_uncertainty: dict[str, float] = Field(default_factory=dict, description="k = 1 (jackknife over loops)")


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
    """``GET /api/spc/chart``."""

    quantity: str
    unit: str
    reducer: str
    bench: str | None
    runs: list[SpcRun]
    chart: ImrChartView


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
    reference: str | None = Field(description="the bench whose bias is 0 (null: the benches' mean is 0)")
    dof: int
    residual_sd: float = Field(description="repeatability of one test, pooled")
    units: list[str] = Field(description="serial numbers of the reference units used")
    excluded_runs: int = Field(description="runs of units tested on one bench only")
    benches: list[BenchBiasRow]
