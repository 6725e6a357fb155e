"""The protocol every element model follows, so one piece of physics serves
both its FMU (integrated alone, inputs held over a macro step) and the
monolithic reference (all elements in one ODE).

An element model is a small class built from SI parameters with

* ``STATES``, ``INPUTS``, ``OUTPUTS``: tuples of names (orders of the lists below);
* ``EXTRAPOLATE``: {input: input that is its time derivative}; a co-simulation
  wrapper advances such inputs linearly inside a step (an element's angle
  from its speed, a tension from its rate) instead of holding them;
* ``RATE_INPUTS``: inputs that only serve that extrapolation (the equations
  never read them); the monolithic reference leaves them unconnected;
* ``problems()`` -> list of (parameter, reason) for invalid parameters;
* ``initial_state()`` -> list of floats;
* ``derivatives(t, x, u)`` -> list (dx/dt), ``x`` states, ``u`` inputs;
* ``outputs(t, x, u)`` -> list in ``OUTPUTS`` order;
* ``max_substep(x)`` -> longest integration step the dynamics tolerate at
  state ``x`` (``math.inf`` unless the element has a stiff mode, e.g. a
  compliant drive shaft).

``STATES`` may be set per instance when options add states (a non-ideal
drive adds the motor angle and speed).
"""
import math


class ElementModel:
    STATES = ()
    INPUTS = ()
    OUTPUTS = ()
    EXTRAPOLATE = {}
    RATE_INPUTS = ()

    def problems(self):
        return []

    def initial_state(self):
        return []

    def derivatives(self, t, x, u):
        return []

    def outputs(self, t, x, u):
        raise NotImplementedError

    def max_substep(self, x):
        return math.inf


def require_positive(problems, **values):
    """Append (name, reason) for every value that is not a positive finite number."""
    for name, value in values.items():
        if not (value > 0.0 and value < float("inf")):
            problems.append((name, f"must be > 0 (got {value!r})"))
    return problems


def require_non_negative(problems, **values):
    """Append (name, reason) for every value that is not a non-negative finite number."""
    for name, value in values.items():
        if not (value >= 0.0 and value < float("inf")):
            problems.append((name, f"must be >= 0 (got {value!r})"))
    return problems


def require_finite(problems, **values):
    """Append (name, reason) for every value that is not finite."""
    for name, value in values.items():
        if not (value > -float("inf") and value < float("inf")):
            problems.append((name, f"must be finite (got {value!r})"))
    return problems
