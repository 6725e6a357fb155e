"""Line layout (YAML) -> validated :class:`Layout` -> :class:`orchestrator.system.System`.

Public API::

    load_layout(path, overrides=None) -> Layout     # validated; LayoutError names file:line: field
    build_system(layout) -> System                  # components, connections, experiment, meta
    load_system(path, overrides=None) -> System     # both

``overrides`` maps dotted keys to values as written on a command line
(``{"experiment.line_speed": "300 ft/min", "unwind.radius": "5.75 in"}``);
they are applied to the file's data before validation. The format is in
docs/layout.md; the field-by-field models in ``orchestrator.layout_model``.

Everything is checked before anything runs: unknown keys, missing fields,
wrong dimensions, impossible geometry, references to unknown elements,
tension zones not bounded by driven elements. Every problem found is
reported, each as ``file:line: field: reason``.

The System has one component per path element, one ``Span`` per pair of
consecutive elements, a ``SpeedPI`` per driven element, a ``TensionPI`` per
tension zone, a ``LoadCell`` per sensor and ``Profile`` components for the
speed and tension references; connections follow from the path. Start values
put the line in its steady state (``orchestrator.operating_point``).
"""
import difflib
import functools
import math
import re
import typing
from pathlib import Path

from pydantic import BaseModel, ValidationError

from webline.orchestrator import layout_model as lm
from webline.orchestrator import operating_point as opm
from webline.orchestrator.layout_source import Issue, LayoutError, Location, load_located, locate, plain, with_location
from webline.orchestrator.system import Component, Connection, Experiment, System
from webline.orchestrator.units import QuantityError, convert, parse, quantity, si_factor

Layout = lm.Layout
__all__ = ["Layout", "LayoutError", "load_layout", "build_system", "load_system", "json_schema"]
json_schema = lm.json_schema

MODEL_OF = {"unwind": "UnwindRoll", "rewind": "RewindRoll", "idle_roller": "IdleRoller",
            "load_cell_roller": "IdleRoller", "driven_roller": "DrivenRoller"}
SI_UNITS = {"T": "N", "v": "m/s", "omega": "rad/s", "omega_motor": "rad/s", "theta": "rad", "R": "m",
            "J": "kg.m2", "tau": "N.m", "L": "m", "dL": "m/s", "v_trim": "m/s", "omega_ref": "rad/s"}


# ---- loading and validation ------------------------------------------------------------------
def load_layout(path, overrides=None):
    """Read, merge (``base``), override and validate a layout file; returns a :class:`Layout`.

    Raises :class:`LayoutError` listing every problem as ``file:line: field: reason``."""
    data = load_located(path, overrides)
    width = _width_hint(data)
    try:
        layout = Layout.model_validate(plain(data), context={"width": width})
    except ValidationError as exc:
        raise LayoutError(_sorted(_pydantic_issues(exc, data))) from None
    layout._data = data
    layout._file = str(path)
    _check(layout)
    return layout


def _check(layout):
    """Cross-field checks (once per layout); LayoutError listing every problem."""
    if getattr(layout, "_checked", False):
        return
    if layout._data is None:  # made in code: locate problems in its own data, as "<layout>"
        layout._data = with_location(layout.model_dump(by_alias=True), Location("<layout>"))
        layout._file = layout._file or "<layout>"
    issues = _Checker(layout, layout._data).run()
    if issues:
        raise LayoutError(_sorted(issues))
    layout._checked = True


def load_system(path, overrides=None):
    """``build_system(load_layout(path, overrides))``."""
    return build_system(load_layout(path, overrides))


def _sorted(issues):
    seen, out = set(), []
    for i in issues:
        if str(i) not in seen:
            seen.add(str(i))
            out.append(i)
    return sorted(out, key=lambda i: (i.location.file, i.location.origin, i.location.line))


def _width_hint(data):
    """The web width (m) for tensions given per width (PLI), if it reads; else None."""
    try:
        return quantity(data["web"]["width"], "length")
    except (KeyError, TypeError, QuantityError):
        return None


def _pydantic_issues(exc, data):
    issues = []
    for e in exc.errors(include_url=False):
        loc, kind, msg = list(e["loc"]), e["type"], e["msg"]
        value = e.get("input")
        if kind == "extra_forbidden":
            allowed = _allowed_keys(loc[:-1])
            close = difflib.get_close_matches(str(loc[-1]), allowed, n=1)
            hint = f"; did you mean {close[0]!r}?" if close else ""
            reason = f"unknown key{hint} (allowed: {', '.join(allowed)})" if allowed else "unknown key"
        elif kind == "missing":
            reason = "required field missing"
        elif kind == "union_tag_invalid":
            loc.append("type")
            reason = f"unknown element type {value.get('type')!r} (one of: {', '.join(lm.ELEMENT_TYPES)})"
        elif kind == "union_tag_not_found":
            loc.append("type")
            reason = f"required field missing (one of: {', '.join(lm.ELEMENT_TYPES)})"
        elif kind == "value_error":
            reason = msg.removeprefix("Value error, ")
        elif kind in ("model_type", "model_attributes_type", "dict_type"):
            reason = f"must be a mapping (got {value!r})"
        elif kind == "list_type":
            reason = f"must be a list (got {value!r})"
        elif kind == "literal_error":
            reason = msg.replace("Input should be", "must be") + f" (got {value!r})"
        else:
            reason = msg.replace("Input should", "must").replace("List should", "must")
        where, field = locate(data, loc)
        issues.append(Issue(where, field, reason))
    return issues


def _allowed_keys(loc):
    """Field names of the model at pydantic location ``loc`` (empty if not a model)."""
    tp = Layout
    for part in loc:
        tp = _unwrap(tp)
        if isinstance(part, str) and part in lm.UNION_TAGS:
            tp = _union_member(tp, part)
            continue
        if isinstance(tp, type) and issubclass(tp, BaseModel):
            f = tp.model_fields.get(part) or next((f for f in tp.model_fields.values() if f.alias == part), None)
            if f is None:
                return []
            tp = f.annotation
        else:
            origin = typing.get_origin(tp)
            args = typing.get_args(tp)
            if origin is list and args:
                tp = args[0]
            elif origin is dict and len(args) == 2:
                tp = args[1]
            else:
                return []
    tp = _unwrap(tp)
    if isinstance(tp, type) and issubclass(tp, BaseModel):
        keys = [f.alias or n for n, f in tp.model_fields.items()]
        return sorted(keys, key=lambda k: (k not in ("name", "type"), k != "name"))  # name, type first
    return []


def _unwrap(tp):
    while True:
        if typing.get_origin(tp) is typing.Annotated:
            tp = typing.get_args(tp)[0]
            continue
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        if typing.get_origin(tp) is typing.Union and len(args) == 1:
            tp = args[0]
            continue
        return tp


def _union_member(tp, tag):
    for member in typing.get_args(tp):
        m = _unwrap(member)
        meta = typing.get_args(member)[1:] if typing.get_origin(member) is typing.Annotated else ()
        if any(getattr(x, "tag", None) == tag for x in meta):
            return m
        if isinstance(m, type) and issubclass(m, BaseModel) and "type" in m.model_fields:
            if typing.get_args(m.model_fields["type"].annotation) == (tag,):
                return m
    return tp


# macro steps per communication step of a constant Profile (docs/performance.md)
CONSTANT_PROFILE_STEPS = 25


# ---- cross-field checks -----------------------------------------------------------------------
class _Checker:
    """Relations between fields and sections, each problem with the location of its field."""

    def __init__(self, layout, data):
        self.L, self.data, self.issues = layout, data, []

    def err(self, loc, reason):
        where, field = locate(self.data, loc)
        self.issues.append(Issue(where, field, reason))

    def run(self):
        L = self.L
        self.names = {}
        for i, e in enumerate(L.path):
            if e.name in self.names:
                self.err(("path", i, "name"), f"element name {e.name!r} used twice (also path item {self.names[e.name]})")
            else:
                self.names[e.name] = i
        self.web()
        self.path()
        self.drives()
        self.sensors()
        self.experiment()
        if not self.issues:
            self.tension_zones()
        return self.issues

    def web(self):
        w = self.L.web
        if (w.E is None) == (w.EA is None):
            self.err(("web",), "give exactly one of E (modulus) and EA (axial stiffness)")

    def EA(self):
        w = self.L.web
        return w.EA if w.EA is not None else (w.E or 0.0) * w.width * w.thickness

    def path(self):
        p = self.L.path
        last = len(p) - 1
        for i, e in enumerate(p):
            if e.type == "unwind" and i != 0:
                self.err(("path", i, "type"), "an unwind can only be the first element of the path")
            if e.type == "rewind" and i != last:
                self.err(("path", i, "type"), "a rewind can only be the last element of the path")
            if i == 0 and e.type != "unwind":
                self.err(("path", 0, "type"), f"the path must start with an unwind (got {e.type!r})")
            if i == last and e.type != "rewind":
                self.err(("path", i, "type"), f"the path must end with a rewind (got {e.type!r})")
            if i < last and e.span is None:
                self.err(("path", i, "span"), f"required field missing: the span from {e.name!r} to "
                                              f"{p[i + 1].name!r} (its length at least)")
            if i == last and e.span is not None:
                self.err(("path", i, "span"), "the last element has no span after it")
            if e.type in lm.ROLL_TYPES:
                self.roll_radius(("path", i, "radius"), e, e.radius)
            else:
                if (e.inertia is None) == (e.mass is None):
                    self.err(("path", i), f"give exactly one of inertia and mass for {e.name!r}")
                if e.inner_radius >= e.radius:
                    self.err(("path", i, "inner_radius"),
                             f"must be below the radius {e.radius:g} m (got {e.inner_radius:g} m)")
            if e.eccentricity is not None:
                self.eccentricity(("path", i, "eccentricity"), e.eccentricity)
            if isinstance(e.span, lm.Span):
                for end in ("up", "down"):
                    if getattr(e.span, end) is not None:
                        self.eccentricity(("path", i, "span", end), getattr(e.span, end))
        for i in range(last):
            amp = sum(abs(c) for c in _span_end_C(p, i))
            L0 = _span_length(p[i].span) if p[i].span is not None else None
            if L0 is not None and amp >= L0:
                self.err(("path", i, "span"), f"eccentricity amplitudes at both ends add up to {amp:g} m, "
                                              f"not below the span length {L0:g} m")

    def roll_radius(self, loc, e, radius):
        if e.type == "rewind" and radius == e.core_radius:
            if not e.core_inertia > 0.0:  # a bare core: only J_0 to turn
                self.err(loc[:2] + ("core_inertia",), "must be > 0 for a rewind starting on its bare core")
        elif not radius > e.core_radius:
            self.err(loc, f"roll radius {radius:g} m must be above the core radius {e.core_radius:g} m "
                          f"({e.name!r})")

    def eccentricity(self, loc, ecc):
        if ecc.psi and len(ecc.psi) != len(ecc.C):
            self.err(loc + ("psi",), f"has {len(ecc.psi)} phases for {len(ecc.C)} amplitudes C")

    def element(self, name, loc, what="element"):
        if name not in self.names:
            close = difflib.get_close_matches(name, list(self.names), n=1)
            hint = f"; did you mean {close[0]!r}?" if close else ""
            self.err(loc, f"unknown {what} {name!r}{hint} (path: {', '.join(self.names)})")
            return None
        return self.L.path[self.names[name]]

    def drives(self):
        d = self.L.drives
        m = self.element(d.master, ("drives", "master"))
        if m is not None and d.master not in d.speed_loops:
            self.err(("drives", "master"), f"the speed master {d.master!r} needs a speed loop in drives.speed_loops")
        for name, loop in d.speed_loops.items():
            e = self.element(name, ("drives", "speed_loops", name))
            if e is not None and e.type not in lm.DRIVEN_TYPES:
                self.err(("drives", "speed_loops", name),
                         f"{name!r} is a {e.type}; speed loops drive unwind, rewind and driven_roller elements")
            if loop.torque_limit is not None and e is not None and e.type in lm.DRIVEN_TYPES:
                pass  # checked against the operating point when building
        for i, e in enumerate(self.L.path):
            if e.type in lm.DRIVEN_TYPES and e.name not in d.speed_loops:
                self.err(("path", i, "type"), f"driven element {e.name!r} has no speed loop in drives.speed_loops")
        owners = {}
        for zone, t in d.tension_loops.items():
            e = self.element(t.element, ("drives", "tension_loops", zone, "element"))
            if e is None:
                continue
            if e.type not in lm.DRIVEN_TYPES:
                self.err(("drives", "tension_loops", zone, "element"),
                         f"{t.element!r} is a {e.type}; a tension loop trims a driven element's speed")
            elif t.element == d.master:
                self.err(("drives", "tension_loops", zone, "element"),
                         f"{t.element!r} is the speed master; its speed is the line speed, not trimmed")
            if t.element in owners:
                self.err(("drives", "tension_loops", zone, "element"),
                         f"{t.element!r} already has a tension loop ({owners[t.element]!r}); one speed trim per element")
            owners.setdefault(t.element, zone)
            if zone in self.names:
                self.err(("drives", "tension_loops", zone), f"zone name {zone!r} is also an element name")

    def sensors(self):
        for name, s in self.L.sensors.items():
            if name in self.names:
                self.err(("sensors", name), f"sensor name {name!r} is also an element name")
            e = self.element(s.roller, ("sensors", name, "roller"), "roller")
            if e is not None and e.type != "load_cell_roller":
                self.err(("sensors", name, "roller"), f"{s.roller!r} is a {e.type}, not a load_cell_roller")
            if math.cos(s.angle_in) + math.cos(s.angle_out) <= 0.0:
                self.err(("sensors", name), "wrap angles give no force along the load-cell axis")
            if s.filter_order == 2 and not s.filter > 0.0:
                self.err(("sensors", name, "filter_order"),
                         "a second-order filter needs a time constant: set filter > 0 (w_c = 1/filter)")

    def experiment(self):
        x = self.L.experiment
        if x.step > x.duration:
            self.err(("experiment", "step"), f"macro step {x.step:g} s is longer than the duration {x.duration:g} s")
        self.profile(("experiment", "line_speed"), x.line_speed, "speed")
        EA = self.EA()
        loops = self.L.drives.tension_loops
        for zone, prof in x.tension.items():
            if zone not in loops:
                self.err(("experiment", "tension", zone),
                         f"no tension loop {zone!r} in drives.tension_loops (have: {', '.join(loops) or 'none'})")
            for j, value in self.profile(("experiment", "tension", zone), prof, "tension"):
                if EA > 0 and not value < EA:
                    self.err(("experiment", "tension", zone) + j,
                             f"tension {value:g} N must stay below the web's EA = {EA:g} N")
        for zone in loops:
            if zone not in x.tension:
                self.err(("experiment", "tension"), f"no reference for tension loop {zone!r}")
        for name, radius in x.roll_radius.items():
            e = self.element(name, ("experiment", "roll_radius", name), "roll")
            if e is None:
                continue
            if e.type not in lm.ROLL_TYPES:
                self.err(("experiment", "roll_radius", name), f"{name!r} is a {e.type}, not an unwind or rewind")
            else:
                self.roll_radius(("experiment", "roll_radius", name), e, radius)

    def profile(self, loc, prof, what):
        """Check segments; returns [(sub-location, value)] of the values it reaches."""
        if not isinstance(prof, (lm.SpeedProfile, lm.TensionProfile)):
            return [((), prof)]
        values = [(("initial",), prof.initial)]
        for j, s in enumerate(prof.segments):
            sl = loc + ("segments", j)
            kinds = s.kind()
            if len(kinds) != 1:
                self.err(sl, "each segment is one of hold, ramp_to (with duration or rate) or step_to"
                             + (f" (got {', '.join(kinds)})" if kinds else ""))
                continue
            if kinds[0] == "ramp_to":
                if (s.duration is None) == (s.rate is None):
                    self.err(sl, "ramp_to needs exactly one of duration and rate")
            elif s.duration is not None or s.rate is not None:
                self.err(sl, f"duration and rate belong to ramp_to, not {kinds[0]}")
            value = s.ramp_to if s.ramp_to is not None else s.step_to
            if value is not None:
                values.append((("segments", j, kinds[0]), value))
        n = 1 + sum(1 for s in prof.segments)
        if n > lm.MAX_PROFILE_POINTS:
            self.err(loc + ("segments",), f"{n} points; a profile holds at most {lm.MAX_PROFILE_POINTS}")
        return values

    def tension_zones(self):
        """Every tension loop's element and load cell bound the same zone between driven elements."""
        p, d = self.L.path, self.L.drives
        driven = [i for i, e in enumerate(p) if e.type in lm.DRIVEN_TYPES]
        sensors = _sensor_map(self.L)
        used, n_issues = {}, len(self.issues)
        for zone, t in d.tension_loops.items():
            lc_loc = ("drives", "tension_loops", zone, "load_cell")
            sensor = sensors.get(t.load_cell)
            if sensor is None:
                names = sorted(set(sensors))
                self.err(lc_loc, f"unknown load cell {t.load_cell!r} (sensors and load_cell_rollers: "
                                 f"{', '.join(names) or 'none'})")
                continue
            c = self.names[t.element]
            r = self.names[self.L.sensors[sensor].roller] if sensor in self.L.sensors else self.names[t.load_cell]
            lo, hi = sorted((c, r))
            between = [p[i].name for i in driven if lo < i < hi]
            if between:
                self.err(lc_loc, f"tension zone not bounded by driven elements: load cell {t.load_cell!r} "
                                 f"(on {p[r].name!r}) is not in a span next to {t.element!r}; driven "
                                 f"{', '.join(between)} lie between")
                continue
            z = _zone_of(driven, r)
            if z in used:
                self.err(("drives", "tension_loops", zone), f"zone {p[z[0]].name!r}..{p[z[1]].name!r} already "
                                                            f"has tension loop {used[z]!r}")
            used.setdefault(z, zone)
        if len(self.issues) == n_issues and driven and driven[0] == 0 and len(driven) > 1:
            z0 = (driven[0], driven[1])
            if z0 not in used:
                self.err(("drives", "tension_loops"),
                         f"the zone after the unwind ({p[z0[0]].name}..{p[z0[1]].name}) needs a tension loop: "
                         f"without one it would start slack (draw 1 from the unstretched roll)")


def _zone_of(driven, r):
    """(upstream driven index, downstream driven index) around non-driven element index r."""
    up = max(i for i in driven if i < r)
    down = min(i for i in driven if i > r)
    return up, down


def _sensor_map(layout):
    """Name usable as a tension loop's load_cell -> sensor name (sensors and their rollers)."""
    out = {name: name for name in layout.sensors}
    for name, s in layout.sensors.items():
        out.setdefault(s.roller, name)
    for e in layout.path:
        if e.type == "load_cell_roller" and e.name not in out:
            out[e.name] = out[_default_sensor_name(e.name)] = _default_sensor_name(e.name)
    return out


def _default_sensor_name(roller):
    return f"{roller}_cell"


def _span_length(span):
    return span.length if isinstance(span, lm.Span) else float(span)


# ---- eccentricity per span end ----------------------------------------------------------------
def _series(ecc):
    C = list(ecc.C)
    psi = list(ecc.psi) if ecc.psi else [0.0] * len(C)
    return C, psi


def _wrap_phase(x):
    return (x + math.pi) % (2.0 * math.pi) - math.pi


def span_ends(path, k):
    """(C_up, psi_up, C_down, psi_down) of span k (from path[k] to path[k+1]).

    Up end: path[k]'s eccentricity as given (the length change of the span
    leaving it). Down end: path[k+1]'s eccentricity seen from the span
    entering it: the opposite change, delayed by the wrap alpha, psi_j + pi +
    j alpha; for the rewind (no leaving span) as given. ``span.up`` /
    ``span.down`` replace either end.
    """
    a, b, span = path[k], path[k + 1], path[k].span
    up = down = ([], [])
    if isinstance(span, lm.Span) and span.up is not None:
        up = _series(span.up)
    elif a.eccentricity is not None and a.type != "rewind":
        up = _series(a.eccentricity)
    if isinstance(span, lm.Span) and span.down is not None:
        down = _series(span.down)
    elif b.eccentricity is not None:
        C, psi = _series(b.eccentricity)
        if b.type != "rewind":
            alpha = b.wrap
            psi = [_wrap_phase(p + math.pi + (j + 1) * alpha) for j, p in enumerate(psi)]
        down = (C, psi)
    return up[0], up[1], down[0], down[1]


def _span_end_C(path, k):
    C_up, _, C_down, _ = span_ends(path, k)
    return C_up + C_down


# ---- building the System ----------------------------------------------------------------------
def build_system(layout):
    """The :class:`System` of a validated layout, started at its operating point.

    A Layout made in code (``Layout.model_validate``) is checked here as ``load_layout`` would."""
    _check(layout)
    return _Builder(layout).build()


class _Builder:
    def __init__(self, layout):
        self.L = layout
        self.data = getattr(layout, "_data", None) or {}
        self.file = getattr(layout, "_file", "") or ""
        self.components, self.connections, self.origin = [], [], {}

    # -- helpers
    def err(self, loc, reason):
        where, field = locate(self.data, loc) if self.data else (Location(self.file), ".".join(map(str, loc)))
        raise LayoutError(Issue(where, field, reason))

    def add(self, comp, loc):
        if comp.name in self.origin:
            self.err(loc, f"component name {comp.name!r} is already used by {self.origin[comp.name][1]}")
        self.origin[comp.name] = (loc, ".".join(str(x) for x in loc))
        self.components.append(comp)
        return comp

    def connect(self, src, src_var, dst, dst_var):
        self.connections.append(Connection(src, src_var, dst, dst_var))

    # -- main
    def build(self):
        L = self.L
        path, n = L.path, len(L.path)
        self.EA = L.web.EA if L.web.EA is not None else L.web.E * L.web.width * L.web.thickness
        self.web = {"rho": L.web.density, "width": L.web.width, "thickness": L.web.thickness}
        self.radius = [L.experiment.roll_radius.get(e.name, e.radius) for e in path]
        self.span_names = [self._span_name(k) for k in range(n - 1)]
        self.driven = [i for i, e in enumerate(path) if e.type in lm.DRIVEN_TYPES]
        self.index = {e.name: i for i, e in enumerate(path)}
        self.sensor_of = _sensor_map(L)
        self.sensors = self._sensors()
        self.zones = self._zones()
        self.profiles = {}
        self.line_speed = self._points(L.experiment.line_speed)
        self.op = self._operating_point()
        self.extrapolate = L.experiment.coupling == "extrapolate"

        for name, pts in self._tension_refs().items():
            self.profiles[name] = pts
        self._profiles()
        self._load_cells()
        self._tension_loops()
        self._speed_loops()
        for i, e in enumerate(path):
            self._element(i, e)
            if i < n - 1:
                self._span(i)
        self._apply_max_substep()
        x = L.experiment
        experiment = Experiment(start=x.start, stop=x.start + x.duration, step=x.step, algorithm=x.algorithm,
                                output_interval=x.output_interval)
        system = System(self.components, self.connections, experiment, self._meta())
        problems = system.check()
        if problems:  # a bug here, not in the layout: say so plainly
            raise LayoutError(Issue(Location(self.file), "", "internal: built system is inconsistent: "
                                    + "; ".join(problems)))
        return system

    def _span_name(self, k):
        span = self.L.path[k].span
        if isinstance(span, lm.Span) and span.name:
            return span.name
        return f"span{k + 1}"

    def _sensors(self):
        """{sensor name: (spec, roller index)}, with default sensors for unlisted load_cell_rollers."""
        out = {}
        for name, s in self.L.sensors.items():
            out[name] = (s, self.index[s.roller])
        listed = {s.roller for s in self.L.sensors.values()}
        for i, e in enumerate(self.L.path):
            if e.type == "load_cell_roller" and e.name not in listed:
                out[_default_sensor_name(e.name)] = (lm.LoadCellSensor(roller=e.name), i)
        return out

    def _zones(self):
        """[{up, down, first, last, loop, sensor}] between consecutive driven elements."""
        loops = {}
        for zone, t in self.L.drives.tension_loops.items():
            sensor = self.sensor_of[t.load_cell]
            loops[_zone_of(self.driven, self.sensors[sensor][1])] = (zone, t, sensor)
        zones = []
        for a, b in zip(self.driven, self.driven[1:]):
            zone, t, sensor = loops.get((a, b), (None, None, None))
            zones.append({"up": a, "down": b, "first": a, "last": b - 1, "loop": zone, "spec": t, "sensor": sensor})
        return zones

    def _points(self, prof, scale=1.0):
        """(t list, y list) of a profile field, times from experiment.start."""
        t = self.L.experiment.start
        if not isinstance(prof, (lm.SpeedProfile, lm.TensionProfile)):
            return [t], [prof * scale]
        y = prof.initial
        ts, ys = [t], [y]
        for s in prof.segments:
            if s.hold is not None:
                t += s.hold
            elif s.ramp_to is not None:
                t += s.duration if s.duration is not None else abs(s.ramp_to - y) / s.rate
                y = s.ramp_to
            else:
                y = s.step_to
            ts.append(t)
            ys.append(y)
        return ts, [v * scale for v in ys]

    def _tension_refs(self):
        return {f"{zone}_T_ref": self._points(self.L.experiment.tension[zone])
                for zone in self.L.drives.tension_loops}

    # -- operating point
    def _operating_point(self):
        L, path = self.L, self.L.path
        els = []
        for i, e in enumerate(path):
            if e.type in lm.ROLL_TYPES:
                els.append(opm.OpElement(e.name, e.type, self.radius[i], e.friction, 0.0, e.core_radius, e.core_inertia))
            else:
                els.append(opm.OpElement(e.name, e.type, e.radius, e.friction, self._roller_inertia(e)))
        zones = []
        for z in self.zones:
            if z["loop"] is None:
                zones.append(opm.OpZone(z["first"], z["last"]))
                continue
            spec, r = self.sensors[z["sensor"]]
            w_in, w_out = opm.wrap_weights(spec.angle_in, spec.angle_out)
            T_ref = self.profiles_T0(z["loop"])
            zones.append(opm.OpZone(z["first"], z["last"], T_ref, (r - 1, w_in, w_out)))
        master = self.index[L.drives.master]
        v0 = self.line_speed[1][0]
        op = opm.solve(els, zones, self.EA, master, v0, self.web)
        if not opm.is_finite(op) or any(T >= self.EA for T in op.T) or any(v < 0 for v in op.v):
            self.err(("experiment", "tension"), "no steady state: the tensions along the path reach the web's "
                                                f"EA = {self.EA:g} N")
        self.elements_op = els
        return op

    def profiles_T0(self, zone):
        return self._points(self.L.experiment.tension[zone])[1][0]

    @staticmethod
    def _roller_inertia(e):
        if e.inertia is not None:
            return e.inertia
        return 0.5 * e.mass * (e.radius ** 2 + e.inner_radius ** 2)

    # -- components
    def _profiles(self):
        master = self.L.drives.master
        ts, ys = self.line_speed
        self.speed_ref = {}
        for name in self.L.drives.speed_loops:
            i = self.index[name]
            comp = "line_speed" if name == master else f"{name}_v_ref"
            ratio = self.op.ratio[i]
            self._profile(comp, ts, [y * ratio for y in ys], name, "line_speed" if name == master else "speed_ref",
                          ("drives", "speed_loops", name))
            self.speed_ref[name] = comp
        for zone in self.L.drives.tension_loops:
            t, y = self.profiles[f"{zone}_T_ref"]
            self._profile(f"{zone}_T_ref", t, y, self.L.drives.tension_loops[zone].element, "tension_ref",
                          ("experiment", "tension", zone))

    def _profile(self, name, ts, ys, element, kind, loc):
        params = {"n": float(len(ts))}
        for k, (t, y) in enumerate(zip(ts, ys), start=1):
            params[f"t[{k}]"] = float(t)
            params[f"y[{k}]"] = float(y)
        # a constant profile cannot change between macro steps: step it at a slower rate
        self.add(Component(name, "Profile", params, {}, element, kind,
                           step_multiple=CONSTANT_PROFILE_STEPS if len(set(ys)) == 1 else 1), loc)
        self.profiles[name] = (list(ts), list(ys))

    def _load_cells(self):
        for seed, (name, (s, r)) in enumerate(self.sensors.items(), start=1):
            T_in, T_out = self.op.T[r - 1], self.op.T[r]
            T0 = opm.load_cell_reading(T_in, T_out, s.angle_in, s.angle_out)
            params = {"angle_in": s.angle_in, "angle_out": s.angle_out, "tau_filter": s.filter,
                      "noise_std": s.noise, "seed": float(s.seed if s.seed is not None else seed), "T0": T0}
            if s.filter_order != 1:
                params.update({"filter_order": float(s.filter_order), "filter_damping": s.filter_damping})
            self.add(Component(name, "LoadCell", params, {"T_in": T_in, "T_out": T_out},
                               self.L.path[r].name, "load_cell"), ("sensors", name))
            self.connect(self.span_names[r - 1], "T", name, "T_in")
            self.connect(self.span_names[r], "T", name, "T_out")
            if self.extrapolate:
                self.connect(self.span_names[r - 1], "dT", name, "dT_in")
                self.connect(self.span_names[r], "dT", name, "dT_out")

    def _tension_loops(self):
        self.trim_of = {}
        for z in self.zones:
            if z["loop"] is None:
                continue
            zone, t = z["loop"], z["spec"]
            c = self.index[t.element]
            sign = -1.0 if c == z["up"] else 1.0  # upstream end: too little tension slows it
            lim = t.trim_limit if t.trim_limit is not None else 1.0e3
            name = f"{zone}_tension_pi"
            T_ref = self.profiles[f"{zone}_T_ref"][1][0]
            params = {"K": t.K, "w_i": t.w_i, "sign": sign, "trim_min": -lim, "trim_max": lim, "I0": 0.0}
            self.add(Component(name, "TensionPI", params, {"T_ref": T_ref, "T_meas": T_ref}, t.element,
                               "tension_pi"), ("drives", "tension_loops", zone))
            self.connect(f"{zone}_T_ref", "y", name, "T_ref")
            self.connect(z["sensor"], "T", name, "T_meas")
            self.trim_of[t.element] = name

    def _zone_reference(self, k):
        """The T_ref profile component of the zone holding span k, or None (no tension loop)."""
        z = next(z for z in self.zones if z["first"] <= k <= z["last"])
        return f"{z['loop']}_T_ref" if z["loop"] else None

    def _feedforward_tensions(self, i, mode):
        """(T_in, T_out) start values of element i's speed loop and their sources [(side, component)].

        'measured': the adjacent spans' T (start: operating-point tensions). 'reference': the zones'
        T_ref profiles where the zone has a tension loop, else unconnected at the operating-point
        tension. 'none': operating-point tensions, unconnected (unused)."""
        op, n = self.op, len(self.L.path)
        T_in, T_out = op.element_tensions(i)
        sources = []
        for side, k, exists in (("T_in", i - 1, i > 0), ("T_out", i, i < n - 1)):
            if not exists or mode == "none":
                continue
            if mode == "measured":
                sources.append((side, self.span_names[k], "T"))
            else:
                ref = self._zone_reference(k)
                if ref is not None:
                    sources.append((side, ref, "y"))
                    value = self.profiles[ref][1][0]
                    T_in, T_out = (value, T_out) if side == "T_in" else (T_in, value)
        return T_in, T_out, sources

    def _speed_loops(self):
        op = self.op
        self.speed_pi = {}
        for k, (name, loop) in enumerate(self.L.drives.speed_loops.items(), start=1):
            i = self.index[name]
            e = self.L.path[i]
            R = self.radius[i]
            J = op.J[i] + (loop.drive.motor_inertia if loop.drive else 0.0)
            tau = op.torque[name]
            lim = loop.torque_limit if loop.torque_limit is not None else 1.0e6
            if abs(tau) > lim:
                self.err(("drives", "speed_loops", name, "torque_limit"),
                         f"the operating point needs {tau:.4g} N.m, beyond the limit {lim:g} N.m")
            _, w_default = opm.speed_gains(J, loop.K_ref, loop.zeta)
            w_ld = loop.w_ld if loop.w_ld is not None else w_default
            ff_on = loop.feedforward != "none"
            T_in, T_out, sources = self._feedforward_tensions(i, loop.feedforward)
            # The integrator covers what the feed-forward (whatever tensions it sees) misses.
            I0 = opm.speed_pi_start(tau, J, loop.K_ref, loop.zeta, w_ld, ff_on, R, T_in, T_out,
                                    e.friction, op.omega[i])
            params = {"K_ref": loop.K_ref, "zeta": loop.zeta, "w_ld": w_ld, "tau_min": -lim, "tau_max": lim,
                      "feedforward": 1.0 if ff_on else 0.0, "b_ff": e.friction, "I0": I0}
            if loop.acceleration_feedforward:
                params["acc_ff"] = 1.0
            if loop.current_lag > 0.0:
                params["tau_current"] = loop.current_lag
                params["tau0"] = tau  # the lag starts at the operating-point torque
            if loop.torque_noise > 0.0:
                # seeds apart from the load cells' (1, 2, ...): the ripple is not the sensor noise
                params.update({"torque_noise": loop.torque_noise,
                               "seed": float(loop.noise_seed if loop.noise_seed is not None else 1000 + k)})
            inputs = {"v_ref": op.v[i], "v_trim": 0.0, "R": R, "omega": op.omega[i], "J": J,
                      "T_in": T_in, "T_out": T_out}
            comp = f"{name}_speed_pi"
            self.add(Component(comp, "SpeedPI", params, inputs, name, "speed_pi"), ("drives", "speed_loops", name))
            self.connect(self.speed_ref[name], "y", comp, "v_ref")
            if loop.acceleration_feedforward:
                self.connect(self.speed_ref[name], "dy", comp, "a_ref")
            if name in self.trim_of:
                self.connect(self.trim_of[name], "v_trim", comp, "v_trim")
            if e.type in lm.ROLL_TYPES:
                self.connect(name, "R", comp, "R")
                self.connect(name, "J", comp, "J")
            self.connect(name, "omega_motor", comp, "omega")
            for side, src, var in sources:
                self.connect(src, var, comp, side)
            self.speed_pi[name] = (comp, tau)

    def _element(self, i, e):
        op, n = self.op, len(self.L.path)
        loop = self.L.drives.speed_loops.get(e.name)
        omega = op.omega[i]
        if e.type in lm.ROLL_TYPES:
            params = {"R0": self.radius[i], "R_core": e.core_radius, "thickness": self.L.web.thickness,
                      "width": self.L.web.width, "rho": self.L.web.density, "J_core": e.core_inertia,
                      "b": e.friction, "omega0": omega, "theta0": 0.0}
        else:
            params = {"R": e.radius, "J": self._roller_inertia(e), "b": e.friction, "omega0": omega, "theta0": 0.0}
        if e.type in lm.DRIVEN_TYPES:
            params.update(_drive_params(loop.drive if loop else None))
        inputs = {}
        # A driven element holds its torque over a macro step, and the torque's feed-forward
        # R (T_in - T_out) cancels the web pull only if the tensions are held too: its
        # tension rates stay unconnected (measured: 10x smaller error on lc15/lc19).
        extrapolate = self.extrapolate and e.type not in lm.DRIVEN_TYPES
        if i > 0:
            inputs["T_in"] = op.T[i - 1]
            self.connect(self.span_names[i - 1], "T", e.name, "T_in")
            if extrapolate:
                self.connect(self.span_names[i - 1], "dT", e.name, "dT_in")
        if i < n - 1:
            inputs["T_out"] = op.T[i]
            self.connect(self.span_names[i], "T", e.name, "T_out")
            if extrapolate:
                self.connect(self.span_names[i], "dT", e.name, "dT_out")
        if e.type in lm.DRIVEN_TYPES:
            comp, tau = self.speed_pi[e.name]
            inputs["tau"] = tau
            self.connect(comp, "tau", e.name, "tau")
        self.add(Component(e.name, MODEL_OF[e.type], params, inputs, e.name, e.type), ("path", i, "name"))

    def _span(self, k):
        path, op = self.L.path, self.op
        a, b = path[k], path[k + 1]
        span = a.span
        name = self.span_names[k]
        C_up, psi_up, C_down, psi_down = span_ends(path, k)
        mode = 2 if isinstance(span, lm.Span) and span.fixed_frequency is not None else 0
        L0 = _span_length(span)
        params = {"EA": self.EA, "L0": L0, "T0": op.T[k], "length_mode": float(mode),
                  "f_fixed": span.fixed_frequency if mode == 2 else 0.0}
        for prefix, C, psi in (("up", C_up, psi_up), ("down", C_down, psi_down)):
            if any(C):
                for j in range(lm.N_HARMONICS):
                    params[f"{prefix}.C[{j + 1}]"] = C[j] if j < len(C) else 0.0
                    params[f"{prefix}.psi[{j + 1}]"] = psi[j] if j < len(psi) else 0.0
        inputs = {"v_in": op.v[k], "v_out": op.v[k + 1], "T_in": op.T_in(k),
                  "theta_up": 0.0, "omega_up": op.omega[k], "theta_down": 0.0, "omega_down": op.omega[k + 1],
                  "L_ext": L0, "dL_ext": 0.0}
        model = "Span"
        if self.L.web.damping > 0.0:  # Kelvin-Voigt web: T is then a feed-through (DampedSpan)
            model = "DampedSpan"
            params["damping_time"] = self.L.web.damping
        self.add(Component(name, model, params, inputs, a.name, "span"), ("path", k, "span"))
        self.connect(a.name, "v", name, "v_in")
        self.connect(b.name, "v", name, "v_out")
        if self.extrapolate:
            self.connect(a.name, "a", name, "a_in")
            self.connect(b.name, "a", name, "a_out")
        if k > 0:
            self.connect(self.span_names[k - 1], "T", name, "T_in")
            if self.extrapolate:
                self.connect(self.span_names[k - 1], "dT", name, "dT_in")
        if any(C_up) and mode == 0:
            self.connect(a.name, "theta", name, "theta_up")
            self.connect(a.name, "omega", name, "omega_up")
        if any(C_down):
            self.connect(b.name, "theta", name, "theta_down")
            self.connect(b.name, "omega", name, "omega_down")

    def _apply_max_substep(self):
        # Default: one RK4 sub-step per macro step. Inside one FMU the dynamics are slow
        # (the fast web modes couple FMUs); a stiff drive shaft picks its own sub-step.
        x = self.L.experiment
        h = x.max_substep if x.max_substep is not None else x.step
        for c in self.components:
            c.parameters["max_step"] = h

    # -- meta
    def _meta(self):
        L, op, path = self.L, self.op, self.L.path
        elements = {}
        for i, e in enumerate(path):
            loop = L.drives.speed_loops.get(e.name)
            elements[e.name] = {
                "index": i, "kind": e.type, "model": MODEL_OF[e.type], "component": e.name,
                "radius": self.radius[i], "radius_varies": e.type in lm.ROLL_TYPES,
                "core_radius": getattr(e, "core_radius", None), "rotating": True,
                "driven": e.type in lm.DRIVEN_TYPES, "speed_pi": self.speed_pi.get(e.name, (None,))[0],
                "eccentric": e.eccentricity is not None, "wrap": getattr(e, "wrap", None),
                "non_ideal_drive": bool(loop and loop.drive),
                "feedforward": loop.feedforward if loop else None,
                "acceleration_feedforward": bool(loop and loop.acceleration_feedforward),
                "current_lag": loop.current_lag if loop else 0.0,
                "v0": op.v[i], "omega0": op.omega[i], "f0": op.omega[i] / (2 * math.pi),
            }
        spans = []
        for k in range(len(path) - 1):
            C_up, _, C_down, _ = span_ends(path, k)
            spans.append({"component": self.span_names[k], "up": path[k].name, "down": path[k + 1].name,
                          "length": _span_length(path[k].span), "T0": op.T[k],
                          "zone": next(zi for zi, z in enumerate(self.zones) if z["first"] <= k <= z["last"]),
                          "eccentric_up": any(C_up), "eccentric_down": any(C_down)})
        zones = [{"index": zi, "up": path[z["up"]].name, "down": path[z["down"]].name,
                  "spans": [self.span_names[k] for k in range(z["first"], z["last"] + 1)],
                  "tension_loop": z["loop"], "controlled_by": z["spec"].element if z["spec"] else None,
                  "load_cell": z["sensor"],
                  "tension_pi": f"{z['loop']}_tension_pi" if z["loop"] else None,
                  "T_ref": f"{z['loop']}_T_ref" if z["loop"] else None} for zi, z in enumerate(self.zones)]
        sensors = {name: {"component": name, "roller": path[r].name, "variable": f"{name}.T",
                          "span_in": self.span_names[r - 1], "span_out": self.span_names[r],
                          "zone": next(zi for zi, z in enumerate(self.zones) if z["first"] <= r - 1 <= z["last"]),
                          "filter": s.filter, "filter_order": s.filter_order,
                          "filter_damping": s.filter_damping, "noise": s.noise}
                   for name, (s, r) in self.sensors.items()}
        return {
            "name": L.name or Path(self.file).stem, "description": L.description,
            "layout": self.file, "layout_file": str(Path(self.file).resolve()) if self.file and Path(self.file).is_file() else self.file,
            "web": {"material": L.web.material, "width": L.web.width, "thickness": L.web.thickness,
                    "density": L.web.density, "E": L.web.E, "EA": self.EA, "damping": L.web.damping},
            "master": L.drives.master, "line_speed": "line_speed.y",
            "elements": elements,
            "rotating": [{"component": e.name, "element": e.name, "radius": self.radius[i],
                          "radius_output": "R" if e.type in lm.ROLL_TYPES else None,
                          "speed_output": "v", "angle_output": "theta"} for i, e in enumerate(path)],
            "spans": spans, "zones": zones, "sensors": sensors,
            "profiles": {k: {"t": v[0], "y": v[1]} for k, v in self.profiles.items()},
            "operating_point": {"T": list(op.T), "v": list(op.v), "omega": list(op.omega),
                                "ratio": list(op.ratio), "torque": dict(op.torque), "iterations": op.iterations},
            "units": {"si": dict(SI_UNITS), "display": self._display_units(), "written": _units_written(self.data)},
        }

    def _display_units(self):
        L = self.L
        chosen = {"speed": L.units.speed, "tension": L.units.tension, "length": L.units.length,
                  "torque": L.units.torque}
        guess = {"speed": _unit_text(_raw(self.data, "experiment", "line_speed")),
                 "tension": next((u for u in (_unit_text(_raw(self.data, "experiment", "tension", z))
                                              for z in L.experiment.tension) if u and _is_force(u)), None),
                 "length": _unit_text(_raw(self.data, "web", "width"))}
        si = {"speed": "m/s", "tension": "N", "length": "m", "torque": "N.m"}
        out = {}
        for key, unit in chosen.items():
            unit = unit or guess.get(key) or si[key]
            try:
                factor = si_factor(unit.replace(".", "*")) if unit != si[key] else 1.0
            except QuantityError:
                unit, factor = si[key], 1.0
            out[key] = {"unit": unit, "si_per_unit": factor}
        return out


def _drive_params(drive):
    if drive is None:
        return {"drive.enabled": 0.0}
    return {"drive.enabled": 1.0, "drive.J_motor": drive.motor_inertia, "drive.stiffness": drive.stiffness,
            "drive.damping": drive.damping, "drive.backlash": drive.backlash}


def _raw(data, *keys):
    cur = data
    for k in keys:
        if isinstance(cur, dict) and k in cur:
            cur = cur[k]
        else:
            return None
    if isinstance(cur, dict):
        cur = cur.get("initial")
    return cur


_NUMBER = re.compile(r"^\s*[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?\s*")


def _unit_text(value):
    """The unit part of a quantity string as written ("200 ft/min" -> "ft/min"), or None."""
    if not isinstance(value, str):
        return None
    m = _NUMBER.match(value)
    unit = value[m.end():].strip() if m else ""
    return unit or None


@functools.lru_cache(maxsize=1024)
def _is_force(unit):
    try:
        return parse(f"1 {unit}").check("[force]")
    except QuantityError:
        return False


def _units_written(data):
    """Sorted unit strings used in the layout file (for reports)."""
    found = set()

    def walk(v):
        if isinstance(v, dict):
            for x in v.values():
                walk(x)
        elif isinstance(v, list):
            for x in v:
                walk(x)
        elif isinstance(v, str):
            u = _written_unit(v)
            if u:
                found.add(u)

    walk(data)
    return sorted(found)


@functools.lru_cache(maxsize=4096)
def _written_unit(text):
    """The unit of a quantity string if it has a dimension, else None. Cached: every
    derived layout the diagnosis builds walks the same strings (24 ms a build)."""
    u = _unit_text(text)
    if not u:
        return None
    try:
        return None if parse(text).unitless else u
    except QuantityError:
        return None


def display(value_si, unit):
    """``value_si`` in ``unit`` (e.g. for reports): ``display(1.016, 'ft/min') == 200``."""
    return convert(value_si, unit)
