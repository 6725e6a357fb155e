"""Fixed-step explicit integration used inside the FMUs' ``do_step``.

Plain lists and floats: per-step numpy on a handful of scalars costs more than
the arithmetic (see docs/architecture.md, FMU boundary costs).
"""
import math


def rk4_step(f, t, x, h):
    """One classical Runge-Kutta step of ``dx/dt = f(t, x)``; ``x`` a list."""
    n = len(x)
    k1 = f(t, x)
    x2 = [x[i] + 0.5 * h * k1[i] for i in range(n)]
    k2 = f(t + 0.5 * h, x2)
    x3 = [x[i] + 0.5 * h * k2[i] for i in range(n)]
    k3 = f(t + 0.5 * h, x3)
    x4 = [x[i] + h * k3[i] for i in range(n)]
    k4 = f(t + h, x4)
    return [x[i] + h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]) for i in range(n)]


def rk4_1(f, t, x, h):
    """:func:`rk4_step` for one state, without list comprehensions."""
    h2 = 0.5 * h
    x0 = x[0]
    k1 = f(t, x)[0]
    k2 = f(t + h2, [x0 + h2 * k1])[0]
    k3 = f(t + h2, [x0 + h2 * k2])[0]
    k4 = f(t + h, [x0 + h * k3])[0]
    return [x0 + h / 6.0 * (k1 + 2.0 * (k2 + k3) + k4)]


def rk4_2(f, t, x, h):
    """:func:`rk4_step` for two states."""
    h2 = 0.5 * h
    x0, x1 = x
    a0, a1 = f(t, x)
    b0, b1 = f(t + h2, [x0 + h2 * a0, x1 + h2 * a1])
    c0, c1 = f(t + h2, [x0 + h2 * b0, x1 + h2 * b1])
    d0, d1 = f(t + h, [x0 + h * c0, x1 + h * c1])
    h6 = h / 6.0
    return [x0 + h6 * (a0 + 2.0 * (b0 + c0) + d0), x1 + h6 * (a1 + 2.0 * (b1 + c1) + d1)]


def rk4_3(f, t, x, h):
    """:func:`rk4_step` for three states."""
    h2 = 0.5 * h
    x0, x1, x2 = x
    a0, a1, a2 = f(t, x)
    b0, b1, b2 = f(t + h2, [x0 + h2 * a0, x1 + h2 * a1, x2 + h2 * a2])
    c0, c1, c2 = f(t + h2, [x0 + h2 * b0, x1 + h2 * b1, x2 + h2 * b2])
    d0, d1, d2 = f(t + h, [x0 + h * c0, x1 + h * c1, x2 + h * c2])
    h6 = h / 6.0
    return [x0 + h6 * (a0 + 2.0 * (b0 + c0) + d0), x1 + h6 * (a1 + 2.0 * (b1 + c1) + d1),
            x2 + h6 * (a2 + 2.0 * (b2 + c2) + d2)]


def integrate(f, t, x, h, max_substep, step=rk4_step):
    """Advance ``x`` from ``t`` to ``t + h`` with RK4 sub-steps no longer than ``max_substep``
    (``step``: :func:`rk4_step` or its specialisation for ``len(x)`` states)."""
    if h <= max_substep * (1.0 + 1e-9):
        return step(f, t, x, h)
    n = max(1, math.ceil(h / max_substep - 1e-9))
    dt = h / n
    for k in range(n):
        x = step(f, t + k * dt, x, dt)
    return x
