"""Pydantic models of the configuration: the bench, the reducer catalogue and test profiles.

Units are in the field names (``_nm``, ``_arcsec``, ``_s``, ``_hz``). Sign convention everywhere: positive torque
twists the reducer output towards positive angle.
"""

from __future__ import annotations

from datetime import date
from typing import TYPE_CHECKING, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, SerializeAsAny, model_validator

from tcms_daq.units import ARCSEC_PER_ARCMIN, ARCSEC_PER_RAD

if TYPE_CHECKING:
    from tcms_daq.analysis.gaps import GapLimits
    from tcms_daq.transmission.kinematics import Teeth

# ------------------------------------------------------------------------------------------------- reducers


class ReducerSimSpec(BaseModel):
    """True characteristics the simulated bench gives this reducer (not catalogue limits).

    backlash_arcsec: loop width at zero torque (Nabtesco "backlash" = hysteresis loss) of a loop between ±rated
        torque. Produced by the friction hysteresis (a symmetric Dahl loop), so the midline is unaffected at 0.
    lost_motion_zone_arcsec: full height of the smooth lost-motion zone (L/2)·tanh(T/T_b) on the midline.
    lost_motion_zone_pct: T_b in % of the rated torque (the torque over which the zone is taken up).
    friction_transition_pct: T_z of the Dahl loop in % of the rated torque (how fast a branch saturates after a
        torque reversal; 3·T_z ≈ 95 % of the width is built up). Large values (≈ 50 %) give a lens-shaped loop
        whose branches converge smoothly at the tips, small ones a parallelogram with sharp corners.
    """

    model_config = ConfigDict(extra="forbid")

    backlash_arcsec: float = Field(25.0, ge=0.0)
    lost_motion_zone_arcsec: float = Field(12.0, ge=0.0)
    lost_motion_zone_pct: float = Field(1.0, gt=0.0, le=50.0)
    friction_transition_pct: float = Field(50.0, gt=0.0, le=200.0)
    transmission: TransmissionSimSpec | None = None  # the turning unit (sim/transmission.py); None: not simulated


class TeHarmonicSpec(BaseModel):
    """One harmonic of a simulated unit's transmission error at ``harmonic`` × the order of ``component``
    (``tcms_daq.transmission.kinematics``): TE += amplitude·sin(order·φ + phase), φ the output angle (rad)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    component: str = Field(min_length=1)
    harmonic: int = Field(1, ge=1, le=10)
    amplitude_arcsec: float = Field(ge=0.0, le=3600.0)
    phase_deg: float = 0.0


class TransmissionSimSpec(BaseModel):
    """[reducers.<NAME>.sim.transmission]: what the simulated unit does when it turns (sim/transmission.py).

    harmonics: its transmission error, per component of its kinematics. Friction at the input shaft (N·m):
    breakaway_torque_nm (static: the starting torque), coulomb_torque_nm (running), viscous_nm_per_krpm (per
    1000 rpm of input speed at reference_temperature_c; × exp(−viscous_temperature_coefficient_per_k·ΔT) at
    other temperatures); direction_asymmetry_pct: the negative direction's friction is larger by this share, the
    positive's smaller. The meshes lose a share of the transmitted torque that is solved so that the efficiency
    at rated output torque and rated_input_speed_rpm is rated_efficiency_pct (at the reference temperature).
    input_inertia_kg_m2: what the input drive accelerates (its rotor and the reducer's input side).
    """

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    harmonics: list[TeHarmonicSpec] = Field(default_factory=list)
    breakaway_torque_nm: float = Field(gt=0.0)
    coulomb_torque_nm: float = Field(gt=0.0)
    viscous_nm_per_krpm: float = Field(0.0, ge=0.0)
    viscous_temperature_coefficient_per_k: float = Field(0.03, ge=0.0, le=0.5)
    reference_temperature_c: float = Field(25.0, ge=-40.0, le=150.0)
    direction_asymmetry_pct: float = Field(0.0, ge=0.0, lt=50.0)
    rated_efficiency_pct: float = Field(gt=0.0, lt=100.0)
    rated_input_speed_rpm: float = Field(gt=0.0)
    input_inertia_kg_m2: float = Field(5e-4, gt=0.0)

    @model_validator(mode="after")
    def _breakaway(self) -> TransmissionSimSpec:
        if self.breakaway_torque_nm < self.coulomb_torque_nm:
            raise ValueError(f"breakaway_torque_nm ({self.breakaway_torque_nm}) must be at least "
                             f"coulomb_torque_nm ({self.coulomb_torque_nm})")
        return self


class ReducerKinematics(BaseModel):
    """[reducers.<NAME>.kinematics]: the tooth numbers the orders of the transmission error come from
    (``tcms_daq.transmission.kinematics``; docs/transmission.md derives the orders). RV: input_gear_teeth (Z1, the
    pinion on the input shaft), spur_gear_teeth (Z2, on each crankshaft), crankshafts, cycloid_teeth, pins;
    Harmonic Drive: flexspline_teeth, circular_spline_teeth. ``sources`` and ``assumed`` as the entry's own."""

    model_config = ConfigDict(extra="forbid")

    input_gear_teeth: int | None = Field(None, ge=1, le=1000)
    spur_gear_teeth: int | None = Field(None, ge=1, le=1000)
    crankshafts: int | None = Field(None, ge=1, le=12)
    cycloid_teeth: int | None = Field(None, ge=1, le=1000)
    pins: int | None = Field(None, ge=2, le=1000)
    flexspline_teeth: int | None = Field(None, ge=2, le=5000)
    circular_spline_teeth: int | None = Field(None, ge=2, le=5000)
    sources: dict[str, str] = Field(default_factory=dict)
    assumed: list[str] = Field(default_factory=list)

    def teeth(self, kind: str) -> Teeth:
        """The core's form (checks the numbers fit the kind: ValueError naming the problem)."""
        from tcms_daq.transmission.kinematics import Teeth

        return Teeth(kind=kind, input_gear=self.input_gear_teeth, spur_gear=self.spur_gear_teeth,  # type: ignore[arg-type]
                     crankshafts=self.crankshafts, cycloid=self.cycloid_teeth, pins=self.pins,
                     flexspline=self.flexspline_teeth, circular_spline=self.circular_spline_teeth)


# How far a measured rigidity may lie from the catalogue's before the verdict fails, per reducer family (%):
# catalogue rigidities are typical values, not guaranteed minima.
RIGIDITY_TOLERANCE_PCT = {"rv": 20.0, "harmonic": 30.0}
# How far the ratio of an entry's tooth numbers may lie from its printed ratio: catalogues print ratios to two
# decimals (a ratio 1 + 40·61/14 = 175.2857… is printed 175.28).
RATIO_TOLERANCE = 0.005


class ReducerSpec(BaseModel):
    """One catalogue entry.

    kind "rv": a single catalogue torsional rigidity (secant, N·m/arcmin). kind "harmonic": Harmonic Drive piecewise
    stiffness K1 (0…T1), K2 (T1…T2), K3 (>T2) in N·m/rad. Limits are pass/fail limits for the evaluation.
    ``sources`` maps a field name to where its value comes from; ``assumed`` lists fields whose values are
    assumptions (not confirmed in a primary source).
    """

    model_config = ConfigDict(extra="forbid")

    name: str
    kind: Literal["rv", "harmonic"]
    rated_torque_nm: float = Field(gt=0.0)
    ratio: float | None = Field(None, gt=0.0)
    rigidity_nm_per_arcmin: float | None = Field(None, gt=0.0)
    t1_nm: float | None = Field(None, gt=0.0)
    t2_nm: float | None = Field(None, gt=0.0)
    k1_nm_per_rad: float | None = Field(None, gt=0.0)
    k2_nm_per_rad: float | None = Field(None, gt=0.0)
    k3_nm_per_rad: float | None = Field(None, gt=0.0)
    backlash_limit_arcsec: float = Field(60.0, gt=0.0)
    lost_motion_limit_arcsec: float = Field(60.0, gt=0.0)
    lost_motion_pct: float = Field(3.0, gt=0.0, le=50.0)
    rigidity_min_nm_per_arcmin: float | None = Field(None, gt=0.0)
    rigidity_tolerance_pct: float | None = Field(None, gt=0.0, lt=100.0)  # None: the family's default
    sim: ReducerSimSpec = Field(default_factory=ReducerSimSpec)
    kinematics: ReducerKinematics | None = None
    sources: dict[str, str] = Field(default_factory=dict)
    assumed: list[str] = Field(default_factory=list)

    @model_validator(mode="after")
    def _check_kind(self) -> ReducerSpec:
        if self.kind == "rv" and self.rigidity_nm_per_arcmin is None:
            raise ValueError("kind 'rv' needs rigidity_nm_per_arcmin")
        if self.kind == "harmonic":
            missing = [
                k
                for k in ("t1_nm", "t2_nm", "k1_nm_per_rad", "k2_nm_per_rad", "k3_nm_per_rad")
                if getattr(self, k) is None
            ]
            if missing:
                raise ValueError(f"kind 'harmonic' needs {', '.join(missing)}")
            if self.t2_nm <= self.t1_nm:  # type: ignore[operator]
                raise ValueError(f"t2_nm ({self.t2_nm}) must be greater than t1_nm ({self.t1_nm})")
        known = set(type(self).model_fields)
        for key in list(self.sources) + list(self.assumed):
            if key not in known:
                raise ValueError(f"sources/assumed name unknown field {key!r}")
        self._check_kinematics()
        return self

    def _check_kinematics(self) -> None:
        """The tooth numbers fit the kind, give the catalogue's ratio, and every simulated harmonic names one of
        the kind's components."""
        from tcms_daq.transmission.kinematics import COMPONENTS, ratio

        if self.kinematics is not None:
            known = set(ReducerKinematics.model_fields) - {"sources", "assumed"}
            for key in list(self.kinematics.sources) + list(self.kinematics.assumed):
                if key not in known:
                    raise ValueError(f"kinematics.sources/assumed name unknown field {key!r}")
            teeth = self.kinematics.teeth(self.kind)
            if self.ratio is None:
                raise ValueError("kinematics need the entry's ratio (the catalogue's, to check them against)")
            if abs(ratio(teeth) - self.ratio) > RATIO_TOLERANCE:
                raise ValueError(f"kinematics give ratio {ratio(teeth):.6g}, the entry says {self.ratio:g}")
        transmission = self.sim.transmission
        if transmission is not None:
            if self.kinematics is None:
                raise ValueError("sim.transmission needs the entry's kinematics (its orders come from them)")
            for h in transmission.harmonics:
                if h.component not in COMPONENTS[self.kind]:
                    raise ValueError(f"sim.transmission: unknown {self.kind} component {h.component!r} "
                                     f"(components: {', '.join(COMPONENTS[self.kind])})")

    @property
    def hd_breakpoints_nm(self) -> tuple[float, float] | None:
        if self.kind != "harmonic":
            return None
        return (float(self.t1_nm), float(self.t2_nm))  # type: ignore[arg-type]

    @property
    def rigidity_tolerance(self) -> float:
        """Allowed relative deviation of the measured rigidity from the catalogue's (the entry's, else its
        family's default)."""
        pct = self.rigidity_tolerance_pct
        return (pct if pct is not None else RIGIDITY_TOLERANCE_PCT[self.kind]) / 100.0

    def expected_rigidity_nm_per_arcmin(self, test_torque_nm: float,
                                        interval: tuple[float, float] = (0.5, 1.0)) -> float:
        """The catalogue's secant rigidity over [lo, hi]·T_test (N·m/arcmin): the RV value, or for a Harmonic
        Drive the secant of its K1/K2/K3 curve over the same interval the evaluation uses."""
        if self.kind == "rv":
            return float(self.rigidity_nm_per_arcmin)  # type: ignore[arg-type]
        lo, hi = interval[0] * test_torque_nm, interval[1] * test_torque_nm
        twist = hd_twist_arcsec(hi, self) - hd_twist_arcsec(lo, self)
        return (hi - lo) / twist * ARCSEC_PER_ARCMIN

    def limits(self, test_torque_nm: float | None = None) -> dict[str, float]:
        """Pass/fail limits (keyword arguments of ``tcms_daq.analysis.Limits``): maxima for backlash and lost
        motion; the rigidity within ± the tolerance of the catalogue's for a test at ``test_torque_nm`` (default
        the rated torque), or at least ``rigidity_min_nm_per_arcmin`` when the entry sets one."""
        out = {
            "backlash_max_arcsec": self.backlash_limit_arcsec,
            "lost_motion_max_arcsec": self.lost_motion_limit_arcsec,
        }
        expected = self.expected_rigidity_nm_per_arcmin(test_torque_nm or self.rated_torque_nm)
        out["rigidity_min_nm_per_arcmin"] = expected * (1.0 - self.rigidity_tolerance)
        out["rigidity_max_nm_per_arcmin"] = expected * (1.0 + self.rigidity_tolerance)
        if self.rigidity_min_nm_per_arcmin is not None:
            out["rigidity_min_nm_per_arcmin"] = self.rigidity_min_nm_per_arcmin
        return out


def hd_twist_arcsec(torque_nm: float, spec: ReducerSpec) -> float:
    """Harmonic Drive catalogue twist (one direction, from zero torque) in arcsec; odd in the torque."""
    # imported here: the analysis package pulls in scipy, which loading a config does not need
    from tcms_daq.analysis.harmonic import hd_torsion_angle_rad

    t1, t2, k1, k2, k3 = spec.t1_nm, spec.t2_nm, spec.k1_nm_per_rad, spec.k2_nm_per_rad, spec.k3_nm_per_rad
    if t1 is None or t2 is None or k1 is None or k2 is None or k3 is None:
        raise ValueError(f"{spec.name}: not a Harmonic Drive entry (no T1/T2, K1/K2/K3)")
    return hd_torsion_angle_rad(float(torque_nm), t1, t2, k1, k2, k3) * ARCSEC_PER_RAD


# ------------------------------------------------------------------------------------------------- profiles


class TestProfile(BaseModel):
    """A stiffness test profile (DESIGN §2): GB-style sequence −T → 0 → +T → 0 → −T (or mirrored).

    kind "continuous": constant torque rate ``rate_nm_per_s``; "stepped": equal steps of ``step_nm`` with
    ``dwell_s`` at each level (transitions at ``rate_nm_per_s``). ``max_torque_nm`` None = the reducer's rated
    torque; ``rate_nm_per_s`` None = a quarter of the test torque per second. ``conditioning_loops`` loops are run
    (and recorded, marked) before the ``cycles`` evaluated loops. ``tip_dwell_s``: hold at ±T before reversing.
    """

    __test__ = False  # not a pytest test class
    model_config = ConfigDict(extra="forbid")

    kind: Literal["continuous", "stepped"] = "continuous"
    max_torque_nm: float | None = Field(None, gt=0.0)
    rate_nm_per_s: float | None = Field(None, gt=0.0)
    cycles: int = Field(3, ge=1, le=1000)
    conditioning_loops: int = Field(1, ge=1, le=100)
    step_nm: float = Field(50.0, gt=0.0)
    dwell_s: float = Field(1.0, ge=0.0)
    tip_dwell_s: float = Field(0.2, ge=0.0)
    start: Literal["negative", "positive"] = "negative"


# ------------------------------------------------------------------------------------------------- uncertainty
# Declared standard uncertainties (k = 1) of the measuring chain: `tcms analyze --uncertainty FILE.toml` and the
# bench config ([instruments.torque.uncertainty], [instruments.angle.uncertainty], [uncertainty]). Every input is
# an error of the reading with estimate 0; tcms_daq.uncertainty propagates it through the evaluation.


class _Declared(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    def declared(self) -> bool:
        """Whether any uncertainty of this section is nonzero."""
        return any(isinstance(v, float) and v > 0.0 and k.startswith("u_") for k, v in self)


class TorqueUncertainty(_Declared):
    """The torque reading: scale (class or calibration certificate, relative) and zero (N·m)."""

    u_rel: float = Field(0.0, ge=0.0, lt=0.5)
    u_zero_nm: float = Field(0.0, ge=0.0)


class AngleUncertainty(_Declared):
    """The angle reading: scale (relative; the local slope of the graduation error), absolute (a common offset,
    arcsec), and the interpolation error over one signal period (RMS over the period, arcsec)."""

    u_rel: float = Field(0.0, ge=0.0, lt=0.5)
    u_arcsec: float = Field(0.0, ge=0.0)
    u_interpolation_arcsec: float = Field(0.0, ge=0.0)
    signal_period_arcsec: float = Field(72.0, gt=0.0)


class CompensationUncertainty(_Declared):
    """What the compensation model leaves after its calibration: a scale (relative) and a torsion term (arcsec
    per 1000 N·m)."""

    u_rel: float = Field(0.0, ge=0.0, lt=0.5)
    u_torsion_arcsec_per_knm: float = Field(0.0, ge=0.0)


class ReferenceUncertainty(_Declared):
    """The reference instrument of a calibration (autocollimator): a common offset (arcsec) and its scale
    (relative)."""

    u_arcsec: float = Field(0.0, ge=0.0)
    u_rel: float = Field(0.0, ge=0.0, lt=0.5)


class TemperatureUncertainty(_Declared):
    """Temperature off its reference (standard uncertainty in K) and what it does to the readings per K."""

    u_k: float = Field(0.0, ge=0.0)
    torque_tc_rel_per_k: float = 0.0
    torque_zero_tc_nm_per_k: float = 0.0
    angle_tc_rel_per_k: float = 0.0

    def declared(self) -> bool:
        return self.u_k > 0.0 and any(
            c != 0.0 for c in (self.torque_tc_rel_per_k, self.torque_zero_tc_nm_per_k, self.angle_tc_rel_per_k))


class ChainUncertainty(_Declared):
    """The declared uncertainties of a measuring chain (an ``--uncertainty`` file, or assembled from a bench
    config). ``source`` says where they were declared."""

    torque: TorqueUncertainty = Field(default_factory=TorqueUncertainty)
    angle: AngleUncertainty = Field(default_factory=AngleUncertainty)
    compensation: CompensationUncertainty = Field(default_factory=CompensationUncertainty)
    reference: ReferenceUncertainty = Field(default_factory=ReferenceUncertainty)
    temperature: TemperatureUncertainty = Field(default_factory=TemperatureUncertainty)
    source: str | None = Field(None, exclude=True)

    def declared(self) -> bool:
        return any(getattr(self, k).declared() for k in ("torque", "angle", "compensation", "reference",
                                                         "temperature"))


DecisionRule = Literal["simple", "guarded"]


class StationUncertainty(_Declared):
    """[uncertainty.station]: the declared standard uncertainties (k = 1) of the turning tests' chain
    (``tcms_daq.uncertainty.station``). output_encoder_u_arcsec: the output encoder's error over a revolution (RMS;
    graduation and mounting, at low orders), output_encoder_high_order_u_arcsec: its error at higher orders (RMS of
    the interpolation error); input_encoder_u_arcsec: the input encoder's error in input arcsec (RMS over an input
    revolution; it reaches the transmission error divided by the ratio, at the input's order); sync_skew_u_s: the
    skew between the two angle readings; the input and output torque channels (scale, zero)."""

    output_encoder_u_arcsec: float = Field(0.0, ge=0.0)
    output_encoder_high_order_u_arcsec: float = Field(0.0, ge=0.0)
    input_encoder_u_arcsec: float = Field(0.0, ge=0.0)
    sync_skew_u_s: float = Field(0.0, ge=0.0)
    input_torque: TorqueUncertainty = Field(default_factory=TorqueUncertainty)
    output_torque: TorqueUncertainty = Field(default_factory=TorqueUncertainty)

    def declared(self) -> bool:
        return super().declared() or self.input_torque.declared() or self.output_torque.declared()


class BenchUncertainty(_Declared):
    """[uncertainty] of a bench config: what is not one instrument's (the compensation model, temperature), and the
    turning tests' chain ([uncertainty.station])."""

    compensation: CompensationUncertainty = Field(default_factory=CompensationUncertainty)
    temperature: TemperatureUncertainty = Field(default_factory=TemperatureUncertainty)
    station: StationUncertainty = Field(default_factory=StationUncertainty)


# ------------------------------------------------------------------------------------------------- bench


class InstrumentCalibration(BaseModel):
    """[instruments.<kind>.calibration]: the instrument's calibration as its certificate states it (printed on
    the test certificate; not passed to the driver)."""

    model_config = ConfigDict(extra="forbid")

    device: str | None = Field(None, max_length=200, description="make, model and serial number of the device")
    certificate: str | None = Field(None, max_length=200, description="calibration certificate number")
    laboratory: str | None = Field(None, max_length=200)
    calibrated_on: date | None = None
    due: date | None = None
    uncertainty: str | None = Field(None, max_length=200,
                                    description="as the certificate states it, e.g. '0.05 % of reading (k = 2)'")


class DriverOptions(BaseModel):
    """What a driver is built with from its ``[instruments.<kind>]`` table: the base of every driver's options
    model (``options_model`` on the driver class: ``drivers/options.py``, ``sim/virtual.py``). Validated once, when
    the bench config is read; a key the driver does not take is an error naming it and the keys it takes."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    url: str = Field(min_length=1, description="where the instrument is: a transport URL or a device path")


#: the keys of an [instruments.<kind>] table that are not the driver's options
INSTRUMENT_KEYS = frozenset({"driver", "calibration", "uncertainty"})


class InstrumentConfig(BaseModel):
    """One instrument: a driver name from the registry and that driver's options (the other keys of the table,
    checked against the driver's options model); its calibration (for the certificate) in ``calibration``."""

    model_config = ConfigDict(extra="forbid")

    driver: str = "virtual"
    calibration: InstrumentCalibration | None = None
    options: SerializeAsAny[DriverOptions]

    @model_validator(mode="before")
    @classmethod
    def _gather_options(cls, data: object) -> object:
        """The table is flat in the file: every key but ``driver``, ``calibration`` and ``uncertainty`` is an
        option of the driver, validated against its options model."""
        if not isinstance(data, dict):
            return data
        if isinstance(data.get("options"), DriverOptions):
            return data
        data = dict(data)
        driver = data.setdefault("driver", "virtual")
        raw = data.pop("options", None)
        table = {k: v for k, v in data.items() if k not in INSTRUMENT_KEYS}
        if isinstance(raw, dict):
            table = {**raw, **table}
        out = {k: v for k, v in data.items() if k in INSTRUMENT_KEYS}
        if isinstance(driver, str):
            from tcms_daq.config.drivers import validate_driver_options

            out["options"] = validate_driver_options(driver, table)
        return out

    @property
    def url(self) -> str:
        return self.options.url


class TorqueInstrumentConfig(InstrumentConfig):
    """[instruments.torque]: also the declared uncertainty of its reading ([instruments.torque.uncertainty])."""

    uncertainty: TorqueUncertainty | None = None


class AngleInstrumentConfig(InstrumentConfig):
    """[instruments.angle]: also the declared uncertainty of its reading ([instruments.angle.uncertainty])."""

    uncertainty: AngleUncertainty | None = None


DEFAULT_COMM_TIMEOUT_MS = 1000  # Modbus: the drive reacts after this much silence of its master (the driver's
# default: 1 s, so a host held up a few hundred ms on a loaded machine does not fault the drive mid-test)


class LoaderInstrumentConfig(InstrumentConfig):
    """[instruments.loader]: the loader's driver and its options, among them the drive's own communication
    watchdog the driver arms on connect (docs/hardware.md): over Modbus ``comm_timeout_ms`` and
    ``abort_connection_option``, over CANopen ``master_heartbeat_ms`` and ``drive_consumer_timeout_ms``
    (``drivers/options.py``)."""


class InstrumentsConfig(BaseModel):
    """[instruments]: the angle source, the torque source and the loader; optionally the second axis (a bench
    without it runs the stiffness test as before): ``input_drive`` (CiA 402 profile velocity), ``input_torque`` (a
    second torque amplifier between the input drive and the reducer) and ``input_angle`` (the ND 287 in coupled
    mode, or the two-axis counter)."""

    model_config = ConfigDict(extra="forbid")

    angle: AngleInstrumentConfig = Field(default_factory=lambda: AngleInstrumentConfig.model_validate({}))
    torque: TorqueInstrumentConfig = Field(default_factory=lambda: TorqueInstrumentConfig.model_validate({}))
    loader: LoaderInstrumentConfig = Field(default_factory=lambda: LoaderInstrumentConfig.model_validate({}))
    input_drive: InstrumentConfig | None = None
    input_torque: InstrumentConfig | None = None
    input_angle: InstrumentConfig | None = None


class InterlocksSection(BaseModel):
    """[interlocks]: replaces a run's interlock limits (``tcms_daq.acquisition.interlocks.InterlockLimits``, whose
    fields these are; a key left out keeps the run's default). Torques in N·m, angles in arcsec, times in s."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    bench_torque_limit_nm: float | None = Field(None, gt=0.0)
    reducer_torque_limit_nm: float | None = Field(None, gt=0.0)
    angle_min_arcsec: float | None = None
    angle_max_arcsec: float | None = None
    torque_rate_limit_nm_per_s: float | None = Field(None, gt=0.0)
    rate_window_s: float | None = Field(None, gt=0.0)
    stale_timeout_s: float | None = Field(None, gt=0.0)
    max_consecutive_errors: int | None = Field(None, ge=1)

    def replacements(self) -> dict[str, float | int | None]:
        """The limits this table sets (the keys the file names)."""
        return {k: getattr(self, k) for k in self.model_fields_set}


class BenchSection(BaseModel):
    """[bench]: id and name, torque limit, compensation and catalogue files, and the bounds a test request must keep
    (``tcms_daq.procedure.profiles.check_test_bounds``): loading rates, the smallest step, the longest test.

    ``id`` names the bench in a run store shared by a plant's benches: every run records it, the bench's
    compensations and bench model versions are kept under it, and a restarting service marks only its own
    bench's runs as interrupted. None: derived from ``name`` (``bench_id``)."""

    model_config = ConfigDict(extra="forbid")

    id: str | None = Field(None, pattern=r"^[A-Za-z0-9][A-Za-z0-9._-]{0,63}$",
                           description="letters, digits, '.', '_', '-' (at most 64)")
    name: str = Field("bench", min_length=1, max_length=200)
    max_torque_nm: float = Field(2000.0, gt=0.0)
    compensation: str | None = None
    reducers: str = "reducers.toml"
    min_rate_nm_per_s: float = Field(0.05, gt=0.0)
    max_rate_nm_per_s: float | None = Field(None, gt=0.0)  # None: max_torque_nm per second
    min_step_nm: float = Field(0.1, gt=0.0)
    min_test_torque_nm: float = Field(1.0, gt=0.0)  # a test request below this torque is refused
    max_test_duration_s: float = Field(4 * 3600.0, gt=0.0)
    max_segments: int = Field(20_000, ge=1)
    decision_rule: DecisionRule = "guarded"  # ISO 14253-1: "guarded" (guard bands of U) or "simple" acceptance
    # the bench as a machine (OPC 40001-1 Identification over OPC UA, the certificate): its nameplate
    manufacturer: str | None = Field(None, max_length=200, description="who built the bench")
    model: str | None = Field(None, max_length=200, description="the bench's model name")
    serial_number: str | None = Field(None, max_length=64, description="the bench's serial number")
    product_instance_uri: str | None = Field(
        None, max_length=400, description="globally unique URI of this bench (default urn:tcms-daq:bench:<id>)")
    location: str | None = Field(None, max_length=200, description="where the bench stands, in the plant's scheme")

    @property
    def rate_limit_nm_per_s(self) -> float:
        return self.max_rate_nm_per_s if self.max_rate_nm_per_s is not None else self.max_torque_nm

    @property
    def bench_id(self) -> str:
        """``id``, or one made from ``name`` (lower case, runs of other characters as '-')."""
        if self.id is not None:
            return self.id
        return bench_id_from_name(self.name)


def bench_id_from_name(name: str) -> str:
    """A bench id from a bench name: ``"Loopback bench (ND 287)"`` → ``"loopback-bench-nd-287"``."""
    import re

    slug = re.sub(r"[^a-z0-9]+", "-", name.lower()).strip("-")[:64].rstrip("-")
    return slug or "bench"


class CertificateSection(BaseModel):
    """[certificate]: what the test certificate states beside the measurement: the issuing laboratory, the test
    method of each kind of test (a reference a customer can look up), the ambient temperature when the request
    gives none, and the traceability statement."""

    model_config = ConfigDict(extra="forbid")

    laboratory: str | None = Field(None, max_length=300, description="the issuing laboratory: name and address")
    method_single: str | None = Field(None, max_length=300, description=(
        "the test method of a test at one output position (default: the certificate catalogue's, GB/T 35089)"))
    method_positions: str | None = Field(None, max_length=300, description=(
        "the test method of a test at several output positions (default: the catalogue's, GB/T 40731)"))
    method_rates: str | None = Field(None, max_length=300,
                                     description="the test method of a test at several loading rates")
    ambient_temperature_c: float | None = Field(None, ge=-40.0, le=80.0,
                                                description="ambient temperature of the test room, °C")
    traceability: str | None = Field(None, max_length=1000, description=(
        "the traceability statement (default: the certificate catalogue's)"))

    def method(self, kind: str) -> str | None:
        """The configured method reference of a test of ``kind`` (``single``, ``positions``, ``rates``); None:
        the certificate's default for that kind."""
        return {"positions": self.method_positions, "rates": self.method_rates}.get(kind, self.method_single)


OpcUaSecurityMode = Literal["SignAndEncrypt", "Sign", "None"]
SECURE_MODES: tuple[OpcUaSecurityMode, ...] = ("SignAndEncrypt", "Sign")


class OpcUaSection(BaseModel):
    """[opcua]: the OPC UA server for the plant's MES (``tcms serve --opcua-port``): where it listens, its security
    (Basic256Sha256 with Sign / SignAndEncrypt; "None" only when listed), and who may connect: named users with
    password hashes (``tcms opcua-user NAME`` makes one), anonymous clients only when ``anonymous = true``."""

    model_config = ConfigDict(extra="forbid")

    port: int | None = Field(None, ge=0, le=65535, description="listen port (None: off unless --opcua-port)")
    host: str = Field("127.0.0.1", min_length=1, max_length=253, description="bind address (loopback by default)")
    security_modes: list[OpcUaSecurityMode] = Field(
        default_factory=lambda: list(SECURE_MODES), min_length=1,
        description="Basic256Sha256 message security modes offered; 'None' (no security) only when listed")
    anonymous: bool = Field(False, description="accept clients without a user name")
    users: dict[str, str] = Field(default_factory=dict, description="user name -> password hash (scrypt$…)")

    @model_validator(mode="after")
    def _users(self) -> OpcUaSection:
        for name, hashed in self.users.items():
            if not name or len(name) > 64:
                raise ValueError("opcua.users: a user name must have 1…64 characters")
            if not hashed.startswith("scrypt$") or hashed.count("$") != 5:
                raise ValueError(f"opcua.users.{name}: not a password hash (make one with `tcms opcua-user {name}`)")
        if len(set(self.security_modes)) != len(self.security_modes):
            raise ValueError("opcua.security_modes: a mode is repeated")
        return self


class StoreSection(BaseModel):
    """[store]: where the runs are kept. ``url``: ``postgresql://user@host:port/db`` (a plant's benches share one
    database) or ``sqlite:///path``; None: the SQLite file in the data directory. ``tcms serve --store`` and
    ``TCMS_STORE_URL`` take precedence."""

    model_config = ConfigDict(extra="forbid")

    url: str | None = Field(None, min_length=1)


class CompensationChecks(BaseModel):
    """[compensation_checks]: what an uploaded compensator must keep (``tcms_daq.compensation.plausibility``).

    Bands per term type: |scale coefficient| ≤ max_scale (dimensionless); |torsion| ≤ max_torsion_arcsec_per_nm
    (a real shaft between the measuring planes is a few ″/kN·m); |offset| and any other angle parameter ≤
    max_offset_arcsec; a periodic term's amplitude √(sin² + cos²) ≤ max_periodic_amplitude_arcsec and its
    period within [min_period_arcsec, one revolution]; at most max_terms terms. max_rigidity_change_pct: an upload
    that changes the rigidity of the reference record (the last completed run, else a synthetic linear loop of
    synthetic_rigidity_nm_per_arcmin up to the bench's max torque) by more is refused unless forced."""

    model_config = ConfigDict(extra="forbid")

    max_terms: int = Field(64, ge=1, le=10_000)
    max_scale: float = Field(0.10, gt=0.0, lt=1.0)
    max_torsion_arcsec_per_nm: float = Field(0.1, gt=0.0)
    max_offset_arcsec: float = Field(3600.0, gt=0.0)
    max_periodic_amplitude_arcsec: float = Field(60.0, gt=0.0)
    min_period_arcsec: float = Field(1.0, gt=0.0)
    max_rigidity_change_pct: float = Field(5.0, gt=0.0)
    synthetic_rigidity_nm_per_arcmin: float = Field(300.0, gt=0.0)


class GapSettings(BaseModel):
    """[gaps]: what a gap in the data is (``tcms_daq.analysis.gaps``). limit_s: the longest stretch without readings
    of a channel that is not a gap (s, clock time); None: ``limit_periods`` of the channel's median reading period,
    at least ``min_limit_s`` (a loaded machine delays a poll now and then). min_loops: the fewest evaluated loops
    (per stage) a run must keep, once the loops with a gap are left out, to complete."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    limit_s: float | None = Field(None, gt=0.0)
    limit_periods: float = Field(5.0, gt=0.0)
    min_limit_s: float = Field(0.2, ge=0.0)
    min_loops: int = Field(1, ge=1)

    def limits(self) -> GapLimits:
        """The analysis's form of these settings."""
        # imported here: the analysis package pulls in scipy, which loading a config does not need
        from tcms_daq.analysis.gaps import GapLimits

        return GapLimits(limit_s=self.limit_s, limit_periods=self.limit_periods, min_limit_s=self.min_limit_s,
                         min_loops=self.min_loops)


class RichReducerConfig(BaseModel):
    """[sim.rich]: the richer reducer model of the simulated bench (``sim/reducer_model.py``), used when
    ``[sim] model = "rich"``. Variations over the output position φ are a once-per-revolution term and a term
    with the pin count (cycloid/pin meshing): x(φ) = x₀·[1 + a₁·cos(φ − φ₁) + a_z·cos(z·φ − φ_z)].

    stiffness_*_pct: elastic stiffness variation; lost_motion_*_pct: lost-motion zone variation;
    asymmetry_pct: the positive direction is stiffer by this share, the negative softer by as much;
    creep_share: compliance of a Kelvin–Voigt creep element as a share of the elastic compliance, with the
    time constant creep_time_s (creep under a held torque, recovery at zero; loops are stiffer when fast);
    viscous_arcsec_per_nm_per_s: the viscous part of the friction (the loop widens with the torque rate).
    """

    model_config = ConfigDict(extra="forbid")

    pins: int = Field(40, ge=1, le=400)
    stiffness_rev_pct: float = Field(3.0, ge=0.0, le=30.0)
    stiffness_rev_phase_deg: float = 30.0
    stiffness_pin_pct: float = Field(1.5, ge=0.0, le=30.0)
    stiffness_pin_phase_deg: float = 0.0
    lost_motion_rev_pct: float = Field(15.0, ge=0.0, le=90.0)
    lost_motion_rev_phase_deg: float = 60.0
    lost_motion_pin_pct: float = Field(5.0, ge=0.0, le=90.0)
    lost_motion_pin_phase_deg: float = 45.0
    asymmetry_pct: float = Field(4.0, ge=0.0, le=50.0)
    creep_share: float = Field(0.05, ge=0.0, le=1.0)
    creep_time_s: float = Field(2.0, gt=0.0)
    viscous_arcsec_per_nm_per_s: float = Field(5e-4, ge=0.0)


class ExtraOrder(BaseModel):
    """A hidden harmonic of the simulated unit's transmission error that its model does not have: TE +=
    amplitude·sin(order·φ + phase), φ the output angle (rad), order per output revolution (any order: one of the
    kinematics' or one that belongs to no component)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    order: float = Field(gt=0.0, le=100_000.0)
    amplitude_arcsec: float = Field(ge=0.0, le=3600.0)
    phase_deg: float = 0.0


class SimTransmission(BaseModel):
    """[sim.transmission]: the simulated bench's second axis (sim/transmission.py): the unit turns, driven at its
    input. Off by default: the stiffness bench is unchanged without it. The unit's harmonics and friction come from
    the catalogue entry ([reducers.<NAME>.sim.transmission]); ``extra`` adds hidden orders.

    input_encoder_counts_per_rev: the input encoder's resolution; input_encoder_error_arcsec: the amplitude of its
    once-per-input-revolution error (input arcsec); sync_skew_s: how much later the input angle is latched than the
    output angle; speed_ripple_pct, speed_ripple_per_input_rev: the input drive's speed ripple (amplitude in % of
    the speed, its order per input revolution); input_torque_noise_nm: the input torque reading's noise;
    temperature_c: the unit's (oil) temperature. The input drive in profile velocity against the input's breakaway
    (sim.instruments.drivetrain.UnitDriveTrain): while the input sticks, its velocity loop winds up like a spring of
    holding_stiffness_nm_per_deg (N·m per degree of the commanded angle the shaft lags; a creep command ramps the
    torque at stiffness × velocity), and the shaft catches the commanded angle up in catch_up_time_constant_s
    (critically damped) once it breaks away.
    """

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    enabled: bool = False
    extra: list[ExtraOrder] = Field(default_factory=list)
    input_encoder_counts_per_rev: int = Field(2**20, ge=4)
    input_encoder_error_arcsec: float = Field(0.0, ge=0.0)
    sync_skew_s: float = Field(0.0, ge=-1.0, le=1.0)
    speed_ripple_pct: float = Field(0.0, ge=0.0, lt=50.0)
    speed_ripple_per_input_rev: float = Field(1.0, gt=0.0)
    input_torque_noise_nm: float = Field(0.002, ge=0.0)
    temperature_c: float = Field(25.0, ge=-40.0, le=150.0)
    holding_stiffness_nm_per_deg: float = Field(5.0, gt=0.0)
    catch_up_time_constant_s: float = Field(0.02, gt=0.0, le=10.0)


class SimConfig(BaseModel):
    """The simulated bench (sim/): clock, drive, sensors; ``effects`` is the [sim.effects] table (sim/effects.py).

    torque_loop_time_constant_s: first-order lag of the drive's torque loop behind its profile-torque ramp.
    torque_gain: sensor reading = gain·applied + offset + noise. encoder_resolution_arcsec: quantisation step.
    encoder_interpolation_error_arcsec: amplitude of the sinusoidal interpolation error over one signal period.
    geometry: measuring-chain geometry file (relative to the config file), read by the compensation module.
    """

    model_config = ConfigDict(extra="forbid")

    seed: int = Field(0, ge=0)
    sample_rate_hz: float = Field(500.0, gt=0.0, le=1.0e6)
    reducer: str = "RV-110E"
    torque_loop_time_constant_s: float = Field(0.005, ge=0.0)
    torque_noise_nm: float = Field(0.3, ge=0.0)
    torque_gain: float = Field(1.0, gt=0.0)
    torque_offset_nm: float = 0.0
    encoder_noise_arcsec: float = Field(0.2, ge=0.0)
    encoder_resolution_arcsec: float = Field(0.1, ge=0.0)
    encoder_signal_period_arcsec: float = Field(72.0, gt=0.0)
    encoder_interpolation_error_arcsec: float = Field(0.0, ge=0.0)
    geometry: str | None = None
    effects: dict[str, Any] = Field(default_factory=dict)
    model: Literal["simple", "rich"] = "simple"  # the reducer model: see RichReducerConfig
    rich: RichReducerConfig = Field(default_factory=RichReducerConfig)
    transmission: SimTransmission = Field(default_factory=SimTransmission)


class ServiceSection(BaseModel):
    """[service]: the service's settings that belong to the bench (``tcms serve``)."""

    model_config = ConfigDict(extra="forbid")

    api_token: str | None = Field(None, min_length=1, description=(
        "the API token of changes (TCMS_API_TOKEN wins; none: one is made and printed at start)"))


class SimulatorsSection(BaseModel):
    """[simulators]: the protocol simulators ``tcms sim serve`` starts for this bench
    (``sim.instruments.serve.SimulatorOptions``, whose defaults a key left out keeps). Ports by instrument
    (``nd287``, ``aed``, ``modbus``, ``socketcand``, ``modbus_rtu``; 0 = a free one)."""

    model_config = ConfigDict(extra="forbid")

    host: str | None = Field(None, min_length=1)
    ports: dict[str, int] | None = None
    instruments: list[Literal["nd287", "aed", "modbus", "canopen", "modbus_rtu", "input_drive", "input_aed",
                              "nd287_coupled", "counter"]] | None = None
    nd287_unit: str | None = None
    nd287_decimals: int | None = Field(None, ge=0, le=9)
    nd287_reply_delay_s: float | None = Field(None, ge=0.0)
    aed_nominal_torque_nm: float | None = Field(None, gt=0.0)
    aed_reply_delay_s: float | None = Field(None, ge=0.0)
    node_id: int | None = Field(None, ge=1, le=127)
    can_channel: str | None = Field(None, min_length=1)
    can_interface: Literal["socketcand", "virtual"] | None = None
    rated_torque_nm: float | None = Field(None, gt=0.0)
    max_torque_permille: int | None = Field(None, gt=0, le=32767)
    counts_per_rev: int | None = Field(None, gt=0)
    heartbeat_ms: int | None = Field(None, gt=0)
    modbus_map: str | None = None
    modbus_comm_timeout_s: float | None = Field(None, ge=0.0)
    abort_connection_option: Literal[0, 1, 2, 3] | None = None
    # the second axis (instruments input_drive, input_aed, nd287_coupled, counter): sim.instruments.serve
    input_ratio: float | None = Field(None, gt=0.0)
    input_friction_nm: float | None = Field(None, ge=0.0)
    input_viscous_nm_per_deg_per_s: float | None = Field(None, ge=0.0)
    input_node_id: int | None = Field(None, ge=1, le=127)
    input_rated_torque_nm: float | None = Field(None, gt=0.0)
    input_counts_per_rev: int | None = Field(None, gt=0)
    input_modbus_map: str | None = None
    input_aed_nominal_torque_nm: float | None = Field(None, gt=0.0)
    counter_rate_hz: int | None = Field(None, ge=1, le=20_000)
    counter_counts_per_rev_output: int | None = Field(None, gt=0)
    counter_counts_per_rev_input: int | None = Field(None, gt=0)

    def settings(self) -> dict[str, object]:
        """The keys this table sets."""
        return {k: v for k, v in self.model_dump().items() if v is not None}


class BenchConfig(BaseModel):
    """A bench configuration file (config/bench-*.toml). An unknown table or key is an error naming it."""

    model_config = ConfigDict(extra="forbid")

    bench: BenchSection = Field(default_factory=BenchSection)
    store: StoreSection = Field(default_factory=StoreSection)
    instruments: InstrumentsConfig = Field(default_factory=InstrumentsConfig)
    sim: SimConfig = Field(default_factory=SimConfig)
    procedure: TestProfile = Field(default_factory=TestProfile)
    uncertainty: BenchUncertainty = Field(default_factory=BenchUncertainty)
    interlocks: InterlocksSection = Field(default_factory=InterlocksSection)
    certificate: CertificateSection = Field(default_factory=CertificateSection)
    opcua: OpcUaSection = Field(default_factory=OpcUaSection)
    compensation_checks: CompensationChecks = Field(default_factory=CompensationChecks)
    gaps: GapSettings = Field(default_factory=GapSettings)
    service: ServiceSection = Field(default_factory=ServiceSection)
    simulators: SimulatorsSection = Field(default_factory=SimulatorsSection)
    source_path: str | None = Field(None, exclude=True)

    def chain_uncertainty(self) -> ChainUncertainty | None:
        """The declared uncertainties of this bench's measuring chain (instruments and [uncertainty]), or None
        when nothing is declared."""
        chain = ChainUncertainty(
            torque=self.instruments.torque.uncertainty or TorqueUncertainty(),
            angle=self.instruments.angle.uncertainty or AngleUncertainty(),
            compensation=self.uncertainty.compensation,
            temperature=self.uncertainty.temperature,
            source=f"bench config {self.source_path or '(defaults)'}",
        )
        return chain if chain.declared() else None

    def resolve(self, relative: str) -> str:
        """A path named in this file, resolved relative to the file's directory."""
        from pathlib import Path

        p = Path(relative)
        if p.is_absolute() or self.source_path is None:
            return str(p)
        return str(Path(self.source_path).parent / p)
