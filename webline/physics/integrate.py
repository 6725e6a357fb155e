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


def integrate(f, t, x, h, max_substep):
    """Advance ``x`` from ``t`` to ``t + h`` with RK4 sub-steps no longer than ``max_substep``."""
    n = max(1, math.ceil(h / max_substep - 1e-9))
    dt = h / n
    for k in range(n):
        x = rk4_step(f, t + k * dt, x, dt)
    return x
