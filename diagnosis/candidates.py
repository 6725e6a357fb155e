"""Candidate unmodelled effects, generated from the line itself.

Every rotating element can be eccentric (a roller) or out of round (a
material roll): its harmonic family is locked to that element's angle, the
column ``<component>.theta`` of a simulation. Every driven element can have
backlash or a compliant shaft between motor and element. Every load cell can
have its own dynamics (a first-order lag). Global parameters can be wrong:
web stiffness EA, friction, inertia, controller gains.

A :class:`Candidate` names the layout element, its FMU component and what it
needs for screening; it knows nothing of the data.
"""
from dataclasses import dataclass, field

ROTATING_MODELS = {"UnwindRoll": "out_of_round", "RewindRoll": "out_of_round",
                   "IdleRoller": "eccentricity", "DrivenRoller": "eccentricity"}
DRIVEN_MODELS = ("UnwindRoll", "RewindRoll", "DrivenRoller")
KINDS = ("eccentricity", "out_of_round", "backlash", "compliance", "sensor", "parameter")

# global parameter candidates: name -> (component models, FMI parameter names)
PARAMETERS = {
    "EA": (("Span", "DampedSpan"), ("EA",)),
    "friction": (("UnwindRoll", "RewindRoll", "IdleRoller", "DrivenRoller"), ("b",)),
    "inertia": (("UnwindRoll", "RewindRoll", "IdleRoller", "DrivenRoller"), ("J", "J_core")),
    "tension_gain": (("TensionPI",), ("K",)),
    "speed_gain": (("SpeedPI",), ("K_ref",)),
}


@dataclass
class Candidate:
    kind: str                 # one of KINDS
    element: str              # layout element name (or parameter name for kind 'parameter')
    component: str = ""       # FMU component carrying the effect / the angle
    model: str = ""           # its FMU model
    radius: float = 0.0       # m, for rotating elements (initial radius of a roll)
    theta: str = ""           # result column of the element angle
    omega: str = ""           # result column of the element speed
    info: dict = field(default_factory=dict)

    @property
    def key(self):
        return f"{self.kind}:{self.element}"


def _element_name(comp):
    return comp.element or comp.name


def rotating(system):
    """Eccentricity / out-of-roundness candidates, one per rotating element."""
    out = []
    for c in system.components:
        kind = ROTATING_MODELS.get(c.model)
        if kind is None:
            continue
        p = c.parameters
        R = float(p.get("R", p.get("R0", 0.0)) or 0.0)
        out.append(Candidate(kind, _element_name(c), c.name, c.model, R, f"{c.name}.theta",
                             f"{c.name}.omega"))
    return out


def driven(system):
    """Backlash and compliance candidates, one each per driven element."""
    out = []
    for c in system.components:
        if c.model in DRIVEN_MODELS:
            for kind in ("backlash", "compliance"):
                out.append(Candidate(kind, _element_name(c), c.name, c.model,
                                     float(c.parameters.get("R", c.parameters.get("R0", 0.0)) or 0.0),
                                     f"{c.name}.theta", f"{c.name}.omega"))
    return out


def sensors(system):
    """Load-cell names (components of model LoadCell)."""
    return [c.name for c in system.components if c.model == "LoadCell"]


def sensor_candidates(system):
    return [Candidate("sensor", _element_name(c), c.name, c.model) for c in system.components
            if c.model == "LoadCell"]


def parameter_candidates(system):
    out = []
    for name, (models, params) in PARAMETERS.items():
        comps = [c for c in system.components if c.model in models
                 and any(p in c.parameters for p in params)]
        if comps or any(c.model in models for c in system.components):
            out.append(Candidate("parameter", name, info={"models": models, "params": params}))
    return out


def all_candidates(system):
    return rotating(system) + driven(system) + sensor_candidates(system) + parameter_candidates(system)


def line_speed_column(system, result_columns):
    """A result column that carries the line speed: the speed master's ``v`` if
    the meta names it, else the ``v`` of the first driven roller, else of any
    rotating element."""
    meta = getattr(system, "meta", {}) or {}
    col = meta.get("line_speed")
    if isinstance(col, str) and col in result_columns:
        return col
    for key in ("speed_master", "line_speed_element", "master"):
        name = meta.get(key)
        if isinstance(name, str):
            comp = next((c for c in system.components if name in (c.name, c.element)), None)
            if comp is not None and f"{comp.name}.v" in result_columns:
                return f"{comp.name}.v"
    order = ("DrivenRoller", "IdleRoller", "UnwindRoll", "RewindRoll")
    for model in order:
        for c in system.components:
            if c.model == model and f"{c.name}.v" in result_columns:
                return f"{c.name}.v"
    return None
