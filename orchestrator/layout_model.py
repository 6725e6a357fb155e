"""The line-layout file as pydantic models: what a layout may contain, field by field.

Every physical value is a number (SI) or a string with a unit (see
``orchestrator.units``) and is stored here in SI. The models check single
fields (dimension, sign); relations between fields and sections (a roll
bigger than its core, a load cell inside its tension zone) are checked by
``orchestrator.layout``, which knows where each value came from.
docs/layout.md describes the format; docs/layout.schema.json is generated
from these models (``webline validate --schema``).
"""
import functools
import math
import re
from typing import Annotated, Any, Literal, Optional, Union

from pydantic import (AfterValidator, BaseModel, BeforeValidator, ConfigDict, Discriminator, Field, PrivateAttr, Tag,
                      ValidationInfo, WithJsonSchema)

from webline.orchestrator.units import DIMENSIONS, QuantityError, dimension_of, parse, quantity

N_HARMONICS = 8  # Fourier terms per eccentric end (Span FMU: up.C[1..8])
MAX_PROFILE_POINTS = 32  # Profile FMU table size
ELEMENT_TYPES = ("unwind", "rewind", "idle_roller", "load_cell_roller", "driven_roller")
ROLL_TYPES = ("unwind", "rewind")
DRIVEN_TYPES = ("unwind", "rewind", "driven_roller")
# pydantic puts these tags (discriminated unions) into error locations; they are not keys.
UNION_TAGS = frozenset(ELEMENT_TYPES) | {"span-length", "span-mapping", "profile-value", "profile-table"}

NAME_RE = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")
GAIN_UNIT_FACTOR = 0.3048 / 60.0 / 4.4482216152605  # 1 (ft/min)/lbf in (m/s)/N


class Strict(BaseModel):
    """Unknown keys are errors (a misspelt optional key must not be silently ignored)."""
    model_config = ConfigDict(extra="forbid", populate_by_name=False)


# ---- value types ------------------------------------------------------------------------------
def _name(value):
    if not isinstance(value, str) or not NAME_RE.match(value):
        raise ValueError(f"must be a name of letters, digits and '_', not starting with a digit (got {value!r})")
    return value


Name = Annotated[str, AfterValidator(_name), WithJsonSchema({"type": "string", "pattern": NAME_RE.pattern})]


def Q(dimension, *, gt=None, ge=None, le=None, unit_required=False, note=""):
    """A quantity field type: number (SI) or string with a unit, of ``dimension``, stored as SI float."""
    dims, si_unit, example = DIMENSIONS[dimension]

    def validate(value, info: ValidationInfo):
        if unit_required:
            if isinstance(value, (int, float)) and not isinstance(value, bool) or \
                    isinstance(value, str) and _unitless(value):
                raise ValueError(f"needs an explicit unit, e.g. '{example}' ({note})")
        width = (info.context or {}).get("width")
        try:
            x = quantity(value, dimension, width=width)
        except QuantityError as exc:
            raise ValueError(str(exc)) from None
        shown = value if isinstance(value, str) else f"{value} {si_unit}"
        if gt is not None and not x > gt:
            raise ValueError(f"must be > {gt:g} (got {shown})")
        if ge is not None and not x >= ge:
            raise ValueError(f"must be >= {ge:g} (got {shown})")
        if le is not None and not x <= le:
            raise ValueError(f"must be <= {le:g} {si_unit} (got {shown})")
        return x

    text = f"{dimension.replace('_', ' ')}: a number in {si_unit} or a string with a unit, e.g. '{example}'"
    if unit_required:
        text = f"{dimension.replace('_', ' ')}: a string with an explicit unit, e.g. '{example}'"
    schema = ({"type": "string", "description": text, "examples": [example.split("'")[0]]} if unit_required else
              {"anyOf": [{"type": "number"}, {"type": "string"}], "description": text,
               "examples": [example.split("'")[0]]})
    return Annotated[float, BeforeValidator(validate), WithJsonSchema(schema)]


@functools.lru_cache(maxsize=4096)   # the same strings in every layout a diagnosis builds
def _unitless(text):
    try:
        return parse(text).unitless
    except QuantityError:
        return False


def _unit_of(dimension):
    def validate(value):
        if not isinstance(value, str):
            raise ValueError(f"must be a unit such as '{DIMENSIONS[dimension][2].split()[-1]}'")
        try:
            dim = dimension_of(value)
        except QuantityError as exc:
            raise ValueError(str(exc)) from None
        if dim is None or DIMENSIONS[dim][0] != DIMENSIONS[dimension][0]:
            raise ValueError(f"{value!r} is not a unit of {dimension}")
        return value
    return Annotated[str, AfterValidator(validate),
                     WithJsonSchema({"type": "string", "description": f"a unit of {dimension}"})]


Length = Q("length")
PositiveLength = Q("length", gt=0)
NonNegLength = Q("length", ge=0)
Time = Q("time")
PositiveTime = Q("time", gt=0)
NonNegTime = Q("time", ge=0)
Speed = Q("speed", ge=0)
PositiveSpeed = Q("speed", gt=0)
Acceleration = Q("acceleration", gt=0)
Tension = Q("tension", ge=0)
TensionRate = Q("tension_rate", gt=0)
TensionGain = Q("tension_gain", gt=0, unit_required=True,
                note="a bare number would be read as (m/s)/N, 875 times 1 (ft/min)/lbf")
PositiveMass = Q("mass", gt=0)
PositiveInertia = Q("inertia", gt=0)
NonNegInertia = Q("inertia", ge=0)
Density = Q("density", gt=0)
Modulus = Q("modulus", gt=0)
AxialStiffness = Q("stiffness_axial", gt=0)
PositiveRate = Q("rate", gt=0)
NonNegRate = Q("rate", ge=0)
Frequency = Q("frequency", gt=0)
Angle = Q("angle")
WrapAngle = Q("angle", ge=0, le=2 * math.pi)
NonNegAngle = Q("angle", ge=0)
PositiveTorque = Q("torque", gt=0)
NonNegTorque = Q("torque", ge=0)
Friction = Q("rot_damping", ge=0)
RotStiffness = Q("rot_stiffness", gt=0)


def _doc(text, **kw):
    return Field(description=text, **kw)


# ---- web --------------------------------------------------------------------------------------
class Web(Strict):
    """The web material. Give E (modulus) or EA (axial stiffness), not both."""
    material: Optional[str] = _doc("Free text, e.g. 'Tyvek'", default=None)
    width: PositiveLength = _doc("Web width w_w")
    thickness: PositiveLength = _doc("Web thickness t_w (radius change per roll revolution, {5})")
    E: Optional[Modulus] = _doc("Young's modulus; EA = E * width * thickness", default=None)
    EA: Optional[AxialStiffness] = _doc("Axial stiffness E*A (N), instead of E", default=None)
    density: Density = _doc("Web density rho_w (wound-roll inertia {4})")
    damping: NonNegTime = _doc("Kelvin-Voigt damping time of the web: each span's tension is T_e + damping "
                               "dT_e/dt, T_e of {20} (0: elastic web)", default=0.0)


# ---- eccentricity and spans ----------------------------------------------------------------
class Eccentricity(Strict):
    """Span-length change sum_j C_j sin(j theta + psi_j), j = 1..8, theta the element angle ({28})."""
    C: list[Length] = _doc("Amplitudes C_1, C_2, ... of harmonics 1..8 (lengths)", max_length=N_HARMONICS)
    psi: list[Angle] = _doc("Phases psi_1, psi_2, ... (default 0); as many as C", default_factory=list,
                            max_length=N_HARMONICS)


class Span(Strict):
    """The free span from this element to the next one on the path."""
    length: PositiveLength = _doc("Nominal span length L0")
    name: Optional[Name] = _doc("Component name (default span<k>, k = 1 after the first element)", default=None)
    up: Optional[Eccentricity] = _doc("Length change caused by the upstream element (this one); "
                                      "overrides the one derived from its eccentricity", default=None)
    down: Optional[Eccentricity] = _doc("Length change caused by the downstream element; overrides the "
                                        "one derived from its eccentricity", default=None)
    fixed_frequency: Optional[Frequency] = _doc(
        "Paper's {32}: drive the upstream series at this fixed frequency instead of the element angle",
        default=None)


def _span_tag(value):
    return "span-mapping" if isinstance(value, dict) else "span-length"


SpanField = Annotated[Union[Annotated[Span, Tag("span-mapping")], Annotated[PositiveLength, Tag("span-length")]],
                      Discriminator(_span_tag)]


# ---- path elements --------------------------------------------------------------------------
class _Element(Strict):
    name: Name = _doc("Element name; also its component name in results")
    description: Optional[str] = _doc("Free text", default=None)
    span: Optional[SpanField] = _doc("The span to the next element: a length ('1.2 m') or a mapping "
                                     "(length, name, up, down); every element but the last has one",
                                     default=None)
    eccentricity: Optional[Eccentricity] = _doc(
        "Out-of-round / eccentric shape as the length change it causes in the span leaving the element "
        "(the rewind: the span entering it); the entering span gets the opposite change delayed by the wrap "
        "(docs/layout.md)", default=None)


class _Roll(_Element):
    radius: PositiveLength = _doc("Roll radius at the start, above the core (a rewind may start on its bare "
                                  "core); experiment.roll_radius overrides it")
    core_radius: PositiveLength = _doc("Core radius R_c ({4})")
    core_inertia: NonNegInertia = _doc("J_0 of {3}: core, shaft, coupling and motor (ideal drive)")
    friction: Friction = _doc("Viscous friction b", default=0.0)


class Unwind(_Roll):
    """Unwinding material roll ({7}); the first element of the path."""
    type: Literal["unwind"]


class Rewind(_Roll):
    """Winding material roll ({8}); the last element of the path."""
    type: Literal["rewind"]


class _Roller(_Element):
    radius: PositiveLength = _doc("Roller radius")
    inertia: Optional[PositiveInertia] = _doc("Moment of inertia J (give inertia or mass)", default=None)
    mass: Optional[PositiveMass] = _doc("Roller mass; J = m (R^2 + r_i^2)/2 with r_i = inner_radius",
                                        default=None)
    inner_radius: NonNegLength = _doc("Inner radius of a tube roller (with mass; 0 = solid)", default=0.0)
    friction: Friction = _doc("Viscous bearing friction b", default=0.0)
    wrap: WrapAngle = _doc("Wrap angle of the web on the roller (eccentricity phase of the entering span)",
                           default=math.pi / 2)


class IdleRoller(_Roller):
    """Free roller turned by the web ({22}, tau = 0)."""
    type: Literal["idle_roller"]


class LoadCellRoller(_Roller):
    """Idle roller mounted on load cells (see sensors)."""
    type: Literal["load_cell_roller"]


class DrivenRoller(_Roller):
    """Motor-driven roller ({22}) under a speed loop; inertia includes the motor (ideal drive)."""
    type: Literal["driven_roller"]


Element = Annotated[Union[Unwind, Rewind, IdleRoller, LoadCellRoller, DrivenRoller], Field(discriminator="type")]


# ---- drives -------------------------------------------------------------------------------------
class NonIdealDrive(Strict):
    """Motor inertia and a compliant shaft with backlash between motor and element."""
    motor_inertia: PositiveInertia = _doc("Motor-side inertia")
    stiffness: RotStiffness = _doc("Torsional stiffness of shaft/coupling")
    damping: Friction = _doc("Torsional damping of shaft/coupling", default=0.0)
    backlash: NonNegAngle = _doc("Total backlash (dead-zone width)", default=0.0)


FEEDFORWARD_MODES = ("measured", "reference", "none")


def _feedforward(value):
    """``measured``, ``reference`` or ``none``; true/false as before (true = measured, false = none)."""
    if value is True:
        return "measured"
    if value is False:
        return "none"
    if isinstance(value, str) and value in FEEDFORWARD_MODES:
        return value
    raise ValueError(f"must be one of {', '.join(FEEDFORWARD_MODES)} (or true = measured, false = none) "
                     f"(got {value!r})")


Feedforward = Annotated[str, BeforeValidator(_feedforward), WithJsonSchema(
    {"anyOf": [{"type": "string", "enum": list(FEEDFORWARD_MODES)}, {"type": "boolean"}],
     "description": "measured | reference | none (true = measured, false = none)"})]


class SpeedLoop(Strict):
    """Speed PI of {24}: K_p = J K_ref, w_ld = K_ref/(4 zeta^2)."""
    K_ref: PositiveRate = _doc("Reference gain K_ref (1/s)")
    zeta: float = _doc("Damping ratio zeta", default=1.1, gt=0)
    w_ld: Optional[PositiveRate] = _doc("Integral corner frequency (default K_ref/(4 zeta^2))", default=None)
    feedforward: Feedforward = _doc(
        "Tension feed-forward R (T_in - T_out) + b omega: 'measured' from the adjacent spans' tensions, "
        "'reference' from the zones' tension set points (the operating-point tension where a zone has no "
        "tension loop), 'none'; true = measured, false = none", default="measured")
    acceleration_feedforward: bool = _doc("Add J dω_ref/dt = J a_ref/R, a_ref the slope of the speed reference",
                                          default=False)
    current_lag: NonNegTime = _doc("Time constant of the drive's current loop: a first-order lag on the torque "
                                   "(0: none)", default=0.0)
    torque_limit: Optional[PositiveTorque] = _doc("Symmetric motor torque limit (default none)", default=None)
    torque_noise: NonNegTorque = _doc("RMS of the drive's broadband torque ripple (current ripple, PWM), white "
                                      "and held between communication points (0: none)", default=0.0)
    noise_seed: Optional[int] = _doc("Seed of the torque ripple (default: from the loop's position)", default=None)
    drive: Optional[NonIdealDrive] = _doc("Non-ideal drive (default ideal, rigid)", default=None)


class TensionLoop(Strict):
    """Tension PI of {25}: a speed trim K (e + w_i int e) on a driven element at one end of the zone."""
    element: Name = _doc("The driven element whose speed the loop trims (an end of the zone)")
    load_cell: Name = _doc("Sensor (or load_cell_roller) giving the feedback; inside the zone")
    K: TensionGain = _doc("Gain with explicit unit, e.g. '2 (ft/min)/lbf'")
    w_i: NonNegRate = _doc("Integral corner frequency w_t (1/s)", default=10.0)
    trim_limit: Optional[PositiveSpeed] = _doc("Symmetric speed-trim limit (default none)", default=None)


class Drives(Strict):
    master: Name = _doc("Speed master element: its speed reference is the line speed")
    speed_loops: dict[Name, SpeedLoop] = _doc("Speed loop per driven element (every driven element has one)")
    tension_loops: dict[Name, TensionLoop] = _doc("Tension loop per zone name", default_factory=dict)


# ---- sensors ------------------------------------------------------------------------------------
class LoadCellSensor(Strict):
    """Load cell on a load_cell_roller: w_in T_in + w_out T_out, weights cos(angle)/(sum)."""
    roller: Name = _doc("The load_cell_roller it sits on")
    angle_in: Angle = _doc("Angle of the entering web to the measuring axis (0: along it)", default=0.0)
    angle_out: Angle = _doc("Angle of the leaving web to the measuring axis (0: along it)", default=0.0)
    filter: NonNegTime = _doc("Filter time constant tau (0: none); second order: w_c = 1/tau", default=0.0)
    filter_order: Literal[1, 2] = _doc("1: first-order lag; 2: second-order low pass (needs filter > 0)",
                                       default=1)
    filter_damping: float = _doc("Damping ratio of the second-order filter", default=0.707, gt=0)
    noise: Tension = _doc("Standard deviation of Gaussian measurement noise", default=0.0)
    seed: Optional[int] = _doc("Noise seed (default: from the sensor's position)", default=None)


# ---- experiment ----------------------------------------------------------------------------------
class _Segment(Strict):
    hold: Optional[NonNegTime] = _doc("Hold the value for this long", default=None)
    duration: Optional[PositiveTime] = _doc("Ramp duration (with ramp_to)", default=None)

    def kind(self):
        given = [k for k in ("hold", "ramp_to", "step_to") if getattr(self, k) is not None]
        return given


class SpeedSegment(_Segment):
    """One of: {hold: T}, {ramp_to: V, duration: T}, {ramp_to: V, rate: A}, {step_to: V}."""
    ramp_to: Optional[Speed] = _doc("Ramp linearly to this speed (with duration or rate)", default=None)
    rate: Optional[Acceleration] = _doc("Ramp rate, e.g. '40 (ft/min)/s' (with ramp_to)", default=None)
    step_to: Optional[Speed] = _doc("Jump to this speed", default=None)


class TensionSegment(_Segment):
    """One of: {hold: T}, {ramp_to: F, duration: T}, {ramp_to: F, rate: F/s}, {step_to: F}."""
    ramp_to: Optional[Tension] = _doc("Ramp linearly to this tension (with duration or rate)", default=None)
    rate: Optional[TensionRate] = _doc("Ramp rate, e.g. '5 lbf/s' (with ramp_to)", default=None)
    step_to: Optional[Tension] = _doc("Jump to this tension", default=None)


class SpeedProfile(Strict):
    """A speed from ``initial`` through ramps and holds, held after the last segment."""
    initial: Speed = _doc("Value at the start")
    segments: list[SpeedSegment] = _doc("Ramps, holds and steps in order", default_factory=list)


class TensionProfile(Strict):
    """A tension reference from ``initial`` through steps, ramps and holds."""
    initial: Tension = _doc("Value at the start")
    segments: list[TensionSegment] = _doc("Steps, ramps and holds in order", default_factory=list)


def _profile_tag(value):
    return "profile-table" if isinstance(value, dict) else "profile-value"


SpeedProfileField = Annotated[Union[Annotated[SpeedProfile, Tag("profile-table")],
                                    Annotated[Speed, Tag("profile-value")]], Discriminator(_profile_tag)]
TensionProfileField = Annotated[Union[Annotated[TensionProfile, Tag("profile-table")],
                                      Annotated[Tension, Tag("profile-value")]], Discriminator(_profile_tag)]


class Experiment(Strict):
    duration: PositiveTime = _doc("Simulated time")
    start: Time = _doc("Start time", default=0.0)
    step: PositiveTime = _doc("Macro (communication) step of the master", default=1.0e-3)
    algorithm: Literal["jacobi", "gauss-seidel"] = _doc(
        "Master algorithm. Gauss-Seidel is the default: Jacobi's held inputs make the undamped span-roller "
        "modes (tens of Hz) grow at a 1 ms step", default="gauss-seidel")
    coupling: Literal["extrapolate", "hold"] = _doc(
        "How FMUs see the web coupling inside a macro step: 'extrapolate' advances span tensions and "
        "roller speeds linearly with their rates (tension rate dT, web acceleration a; second order), "
        "'hold' keeps them constant (first order)", default="extrapolate")
    output_interval: NonNegTime = _doc("Recording interval (0: every macro step)", default=0.0)
    max_substep: Optional[PositiveTime] = _doc("Longest RK4 sub-step inside every FMU (default: the macro step)",
                                               default=None)
    line_speed: SpeedProfileField = _doc("Speed of the speed master: a constant or {initial, segments}")
    tension: dict[Name, TensionProfileField] = _doc("Reference per tension zone (drives.tension_loops): a "
                                                    "constant or {initial, segments}", default_factory=dict)
    roll_radius: dict[Name, PositiveLength] = _doc("Start radius per roll, overriding its radius",
                                                   default_factory=dict)


SpeedUnit, ForceUnit, LengthUnit, TorqueUnit = (_unit_of(d) for d in ("speed", "force", "length", "torque"))


class DisplayUnits(Strict):
    """Units in which reports and plots show values (the model runs in SI)."""
    speed: Optional[SpeedUnit] = _doc("e.g. 'ft/min'", default=None)
    tension: Optional[ForceUnit] = _doc("e.g. 'lbf'", default=None)
    length: Optional[LengthUnit] = _doc("e.g. 'in'", default=None)
    torque: Optional[TorqueUnit] = _doc("e.g. 'lbf*ft'", default=None)


class Layout(Strict):
    """A roll-to-roll line: web, path of elements, drives, sensors and one experiment."""
    name: Optional[str] = _doc("Line name", default=None)
    description: Optional[str] = _doc("Free text", default=None)
    base: Optional[str] = _doc("Layout this one derives from (path relative to this file); this file's "
                               "mappings are merged onto it (null deletes a key, lists replace)", default=None)
    set_: Optional[dict[str, Any]] = Field(None, alias="set", description=(
        "Dotted-key overrides applied after the merge, e.g. 'path.unwind.radius: 5.75 in'"))
    units: DisplayUnits = _doc("Display units for reports", default_factory=DisplayUnits)
    web: Web
    path: list[Element] = _doc("Elements in web-flow order: an unwind first, a rewind last", min_length=2)
    drives: Drives
    sensors: dict[Name, LoadCellSensor] = _doc("Load cells by name", default_factory=dict)
    experiment: Experiment
    _data: Any = PrivateAttr(default=None)  # the located YAML data (orchestrator.layout_source)
    _file: str = PrivateAttr(default="")
    _checked: bool = PrivateAttr(default=False)


def json_schema():
    """JSON schema of a layout file (for editors), as written to docs/layout.schema.json."""
    schema = Layout.model_json_schema(by_alias=True)
    schema["$schema"] = "https://json-schema.org/draft/2020-12/schema"
    schema["title"] = "webline line layout"
    return schema
