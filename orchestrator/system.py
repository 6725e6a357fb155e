"""System structure: the FMU instances of a line and the connections between them.

This is all the master knows: model names, parameter values (SI), and which
output feeds which input. The layout module derives it from a line layout;
the SSP exporter writes it out. No physics here.
"""
from dataclasses import dataclass, field


@dataclass
class Component:
    """One FMU instance. ``model`` is the FMU's model name (e.g. ``"Span"``);
    ``name`` matches ``[A-Za-z_][A-Za-z0-9_]*`` and is unique in the system;
    ``parameters`` and ``inputs`` hold start values in SI, by FMI variable name;
    ``element`` names the layout element it belongs to (for reports)."""
    name: str
    model: str
    parameters: dict = field(default_factory=dict)
    inputs: dict = field(default_factory=dict)
    element: str = ""
    kind: str = ""  # layout element type, e.g. "idle_roller", "span", "speed_pi"
    # communication steps of this instance span this many macro steps (multi-rate; outputs
    # held in between): only for instances without connected inputs, e.g. a constant source
    step_multiple: int = 1


@dataclass(frozen=True)
class Connection:
    """Output ``src.src_var`` feeds input ``dst.dst_var``."""
    src: str
    src_var: str
    dst: str
    dst_var: str


@dataclass
class Experiment:
    start: float = 0.0
    stop: float = 10.0
    step: float = 1.0e-3
    algorithm: str = "jacobi"  # or "gauss-seidel"
    output_interval: float = 0.0  # 0: every macro step


@dataclass
class System:
    components: list
    connections: list
    experiment: Experiment = field(default_factory=Experiment)
    meta: dict = field(default_factory=dict)  # free-form info for plots/reports (radii, sensors, units)

    def component(self, name):
        for c in self.components:
            if c.name == name:
                return c
        raise KeyError(f"no component named {name!r}")

    def check(self):
        """Structural problems (list of strings): duplicate names, dangling or doubly-fed inputs."""
        problems = []
        names = [c.name for c in self.components]
        dup = {n for n in names if names.count(n) > 1}
        problems += [f"component name {n!r} used more than once" for n in sorted(dup)]
        known = set(names)
        fed = {}
        for k in self.connections:
            for end in (k.src, k.dst):
                if end not in known:
                    problems.append(f"connection {k} names unknown component {end!r}")
            key = (k.dst, k.dst_var)
            if key in fed:
                problems.append(f"input {k.dst}.{k.dst_var} fed twice ({fed[key]} and {k})")
            fed[key] = k
        return problems
