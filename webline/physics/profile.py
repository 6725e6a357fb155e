"""Piecewise-linear time profile: line-speed ramps, tension-reference steps.

A table of n points (t[k], y[k]) with t non-decreasing. Before the first
point the output holds y[1], after the last it holds y[n]; two points at the
same time make a step, and at the step time the output already has the new
value (right-continuous, so a master sampling there feeds the new value to
the whole following step).
"""
from bisect import bisect_right

from webline.physics.element import ElementModel, require_finite

MAX_POINTS = 32
# Points count as reached this much early (s): libcosim counts time in
# integer nanoseconds, fmpy in floats, and k*h may land a hair below a step
# time written as a decimal; both masters must see the same side of the step.
TIME_TOLERANCE = 1.0e-9


def profile_value(ts, ys, t):
    """y(t) of the table (ts, ys); ``ts`` non-decreasing."""
    k = bisect_right(ts, t + TIME_TOLERANCE) - 1
    if k < 0:
        return ys[0]
    if k >= len(ts) - 1:
        return ys[-1]
    t0, t1 = ts[k], ts[k + 1]
    f = min(max((t - t0) / (t1 - t0), 0.0), 1.0)
    return ys[k] + f * (ys[k + 1] - ys[k])


def profile_slope(ts, ys, t):
    """dy/dt of the table at t: the slope of the segment that holds t (right-continuous, like
    :func:`profile_value`); 0 before the first point, after the last and on a step (two
    points at the same time: the jump itself has no finite slope)."""
    k = bisect_right(ts, t + TIME_TOLERANCE) - 1
    if k < 0 or k >= len(ts) - 1:
        return 0.0
    dt = ts[k + 1] - ts[k]
    if not dt > 0.0:
        return 0.0
    return (ys[k + 1] - ys[k]) / dt


class ProfileModel(ElementModel):
    """Source with output ``y`` = ``profile_value(t[:n], y[:n], time)`` and its slope ``dy``
    (:func:`profile_slope`; feeds a speed loop's acceleration feed-forward); no inputs, no states."""

    OUTPUTS = ("y", "dy")

    def __init__(self, n, t, y):
        self.n_value = n
        self.n = int(round(n)) if n == n and abs(n) < 1e9 else 0
        self.t = list(t)[:max(self.n, 0)]
        self.y = list(y)[:max(self.n, 0)]

    def problems(self):
        if not (self.n_value == self.n and 1 <= self.n <= MAX_POINTS and self.n <= len(self.t)):
            return [("n", f"must be an integer from 1 to {min(MAX_POINTS, len(self.t))} (got {self.n_value!r})")]
        p = []
        for k in range(self.n):
            require_finite(p, **{f"t[{k + 1}]": self.t[k], f"y[{k + 1}]": self.y[k]})
        for k in range(1, self.n):
            if self.t[k] < self.t[k - 1]:
                p.append((f"t[{k + 1}]", f"must not be before t[{k}] = {self.t[k - 1]!r} (got {self.t[k]!r})"))
        return p

    def outputs(self, t, x, u):
        return [profile_value(self.t, self.y, t), profile_slope(self.t, self.y, t)]
