"""Load-cell roller: the tension a load cell reports from the two spans it sits between.

A load cell measures the resultant web force along its axis. Calibrated with
equal tensions, it reports a weighted mean of the entering and leaving
tensions: weights are the projections of each web direction on the measuring
axis (wrap geometry). With equal angles this is the plain mean.

Measurement noise is a deterministic function of (seed, time): the same run
gives the same noise whichever master steps it, and a rerun reproduces it.
"""
import math

from webline.physics.element import ElementModel, require_finite, require_non_negative

# Time grid of the noise (s): masters that disagree on a communication time by
# float rounding (k*h vs a running sum, or libcosim's integer nanoseconds)
# still draw the same sample.
NOISE_TIME_RESOLUTION = 1.0e-6
_MASK64 = (1 << 64) - 1


def wrap_weights(angle_in, angle_out):
    """Weights of the entering/leaving tension for web directions at ``angle_*`` (rad)
    from the measuring axis (0 = the web pulls fully along the axis)."""
    a, b = math.cos(angle_in), math.cos(angle_out)
    s = a + b
    if s <= 0.0:
        raise ValueError("wrap angles give no force along the load-cell axis")
    return a / s, b / s


def measured_tension(T_in, T_out, w_in, w_out):
    """Calibrated load-cell reading: w_in T_in + w_out T_out."""
    return w_in * T_in + w_out * T_out


def first_order_filter_rate(y, u, tau):
    """dy/dt of a first-order lag y/u = 1/(tau s + 1); tau = 0 passes u through."""
    return (u - y) / tau


def second_order_filter_rates(y, dy, u, w_c, zeta):
    """(dy/dt, d2y/dt2) of the second-order low pass y/u = w_c^2/(s^2 + 2 zeta w_c s + w_c^2):
    y'' = w_c^2 (u - y) - 2 zeta w_c y' (a load cell's own mass-spring plus its amplifier's
    filter; zeta = 0.707 is the Butterworth response)."""
    return dy, w_c * w_c * (u - y) - 2.0 * zeta * w_c * dy


def second_order_step_response(t, w_c, zeta):
    """Unit-step response of :func:`second_order_filter_rates` from rest (0 < zeta < 1):
    1 - e^{-zeta w_c t} (cos w_d t + zeta/sqrt(1 - zeta^2) sin w_d t), w_d = w_c sqrt(1 - zeta^2)."""
    s = math.sqrt(1.0 - zeta * zeta)
    w_d = w_c * s
    return 1.0 - math.exp(-zeta * w_c * t) * (math.cos(w_d * t) + zeta / s * math.sin(w_d * t))


def _splitmix64(z):
    """One SplitMix64 output for input ``z`` (a well-mixed 64-bit hash; Steele et al. 2014)."""
    z = (z + 0x9E3779B97F4A7C15) & _MASK64
    z = ((z ^ (z >> 30)) * 0xBF58476D1CE4E5B9) & _MASK64
    z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) & _MASK64
    return z ^ (z >> 31)


def standard_normal(seed, t, resolution=NOISE_TIME_RESOLUTION):
    """A N(0, 1) sample that depends only on (integer ``seed``, time ``t`` on a ``resolution`` grid).

    Box-Muller on two uniforms hashed from (seed, round(t/resolution)):
    independent across grid points and seeds, no generator state to carry.
    """
    k = int(round(t / resolution))
    a = _splitmix64(_splitmix64(int(seed) & _MASK64) ^ (k & _MASK64))
    b = _splitmix64(a)
    u1 = ((a >> 11) + 1) * 2.0 ** -53  # (0, 1]: log stays finite
    u2 = (b >> 11) * 2.0 ** -53
    return math.sqrt(-2.0 * math.log(u1)) * math.cos(2.0 * math.pi * u2)


class LoadCellModel(ElementModel):
    """Load-cell reading T = filter(w_in T_in + w_out T_out) + noise.

    ``tau_filter`` > 0 with ``filter_order`` 1: first-order lag with state T (starts at
    ``T0``); with ``filter_order`` 2: second-order low pass
    (:func:`second_order_filter_rates`), w_c = 1/``tau_filter``, damping ``filter_damping``,
    states [T, dT] starting at rest at ``T0``. ``tau_filter`` 0: no filter and no state
    (either order), the reading follows the inputs directly.
    ``noise_std`` (N): Gaussian measurement noise added to the reading,
    ``standard_normal(seed, t)``; 0 turns it off.
    """

    INPUTS = ("T_in", "T_out", "dT_in", "dT_out")
    OUTPUTS = ("T",)
    EXTRAPOLATE = {"T_in": "dT_in", "T_out": "dT_out"}
    RATE_INPUTS = ("dT_in", "dT_out")

    def __init__(self, angle_in=0.0, angle_out=0.0, tau_filter=0.0, noise_std=0.0, seed=0, T0=0.0,
                 filter_order=1, filter_damping=0.707):
        self.angle_in, self.angle_out = angle_in, angle_out
        self.tau_filter, self.noise_std, self.seed, self.T0 = tau_filter, noise_std, seed, T0
        self.filter_order_value, self.filter_damping = filter_order, filter_damping
        self.filter_order = 2 if filter_order == 2 else 1
        if not tau_filter > 0.0:
            self.STATES = ()
        else:
            self.STATES = ("T", "dT") if self.filter_order == 2 else ("T",)
        self.w_c = 1.0 / tau_filter if tau_filter > 0.0 else math.inf
        try:
            self.w_in, self.w_out = wrap_weights(angle_in, angle_out)
        except (ValueError, OverflowError):
            self.w_in = self.w_out = math.nan

    def problems(self):
        p = require_finite([], angle_in=self.angle_in, angle_out=self.angle_out, seed=self.seed, T0=self.T0)
        require_non_negative(p, tau_filter=self.tau_filter, noise_std=self.noise_std)
        if self.filter_order_value not in (1.0, 2.0):
            p.append(("filter_order", f"must be 1 or 2 (got {self.filter_order_value!r})"))
        if not (self.filter_damping > 0.0 and math.isfinite(self.filter_damping)):
            p.append(("filter_damping", f"must be > 0 (got {self.filter_damping!r})"))
        if not p and math.isnan(self.w_in):
            p.append(("angle_in/angle_out",
                      f"wrap angles {self.angle_in!r}, {self.angle_out!r} rad give no force along the load-cell axis"))
        if math.isfinite(self.seed) and self.seed != round(self.seed):
            p.append(("seed", f"must be an integer (got {self.seed!r})"))
        return p

    def initial_state(self):
        return [self.T0, 0.0][:len(self.STATES)]

    def derivatives(self, t, x, u):
        if not self.STATES:
            return []
        reading = measured_tension(u[0], u[1], self.w_in, self.w_out)
        if len(self.STATES) == 2:
            return list(second_order_filter_rates(x[0], x[1], reading, self.w_c, self.filter_damping))
        return [first_order_filter_rate(x[0], reading, self.tau_filter)]

    def noise(self, t):
        if self.noise_std == 0.0:
            return 0.0
        return self.noise_std * standard_normal(int(self.seed), t)

    def outputs(self, t, x, u):
        y = x[0] if self.STATES else measured_tension(u[0], u[1], self.w_in, self.w_out)
        return [y + self.noise(t)]
