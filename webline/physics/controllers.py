"""PI controllers of the EWL, {24} and {25}, with limits and anti-windup.

{24}: C_v(s) = K_p (s + w_ld)/s, K_p = J K_ref, w_ld = K_ref/(4 zeta^2).
{25}: printed as "2(s + 10)/2"; read as C_t(s) = K (s + w_t)/s with w_t = 10
rad/s (see docs/paper-notes: the gain unit is (ft/min)/lbf, converted to SI
(m/s)/N by the layout).

Both are the same parallel-form PI, u = K (e + w_i * integral e), written in
states that make anti-windup clean: the integrator stops while the output
saturates in the direction the error pushes it (conditional integration).
"""
import math

from webline.physics.element import ElementModel, require_finite, require_non_negative, require_positive
from webline.physics.load_cell import standard_normal


def speed_gains(J, K_ref, zeta):
    """(K_p, w_ld) of {24}."""
    return J * K_ref, K_ref / (4.0 * zeta * zeta)


def pi_output(K, w_i, error, integral, u_ff, u_min, u_max):
    """Saturated PI output and the unsaturated value: u = u_ff + K (e + w_i I)."""
    u = u_ff + K * (error + w_i * integral)
    return min(max(u, u_min), u_max), u


def integral_rate(error, u_unsat, u_min, u_max, direction=1.0):
    """dI/dt = e, except while saturated and the error pushes further into the limit.

    ``direction``: sign of du/dI (the sign of the gain), so a PI with a
    negative gain stops integrating at the right limit.
    """
    push = error * direction
    if (u_unsat > u_max and push > 0.0) or (u_unsat < u_min and push < 0.0):
        return 0.0
    return error


def pi_step_response(K, w_i, e0, t):
    """Analytic open-loop output of K (s + w_i)/s to a constant error e0: K e0 (1 + w_i t)."""
    return K * e0 * (1.0 + w_i * t)


def _limit_problems(p, lo_name, lo, hi_name, hi):
    if not lo < hi:
        p.append((hi_name, f"must be above {lo_name} = {lo!r} (got {hi!r})"))
    return p


def acceleration_feedforward(J, a_ref, R):
    """Torque J d(omega_ref)/dt = J a_ref / R that accelerates inertia J with the speed reference.

    {24} alone is a type-1 loop for the speed: following a ramp of the reference it lags by a
    constant error (the integrator must build up the accelerating torque); feeding this torque
    forward removes that error when J is the true inertia. The roll's radius change
    (omega_ref = v_ref/R with R slowly varying, {5}) is left to the integrator."""
    return J * a_ref / R


def current_lag_rate(tau_m, tau_cmd, tau_current):
    """d tau_m/dt of the drive's closed current (torque) loop as a first-order lag:
    tau_m/tau_cmd = 1/(tau_current s + 1)."""
    return (tau_cmd - tau_m) / tau_current


class SpeedPIModel(ElementModel):
    """Speed loop of {24} with feed-forward, limits and conditional-integration anti-windup.

    omega_ref = (v_ref + v_trim)/R; e = omega_ref - omega; K_p = J K_ref (J an
    input: a material roll's inertia changes); tau = ff + K_p (e + w_ld I),
    ff = R (T_in - T_out) + b_ff omega when ``feedforward`` is 1 (the torque
    that holds the element at constant speed against the web, {7}/{8}/{22}).
    Which tensions reach T_in/T_out (measured span tensions or the zone's set
    point) is the layout's choice. ``w_ld`` <= 0 selects K_ref/(4 zeta^2).
    State: I = integral of e (rad).

    ``acc_ff`` 1 adds the acceleration feed-forward J a_ref/R
    (:func:`acceleration_feedforward`), a_ref = d v_ref/dt (input, m/s^2).
    ``tau_current`` > 0 puts a first-order lag (the drive's current loop) between the
    torque command and the torque output: extra state tau_m
    (:func:`current_lag_rate`, starting at ``tau0``), output tau = tau_m, which then
    depends on no input. 0: the output is the PI law itself (no extra state).

    ``torque_noise`` (N.m rms) adds the drive's broadband torque ripple (current
    ripple, PWM, commutation) to the torque output: ``standard_normal(seed, t)``
    of :mod:`webline.physics.load_cell`, held between communication points as a
    load cell's noise is, so every master draws the same sequence. It excites
    whatever lightly damped mode the line has (a compliant shaft's torsional
    mode shows as a fixed-frequency hump in the tensions); the integrator does
    not see it (the loop cannot know the ripple).
    """

    INPUTS = ("v_ref", "v_trim", "R", "omega", "J", "T_in", "T_out", "a_ref")
    OUTPUTS = ("tau", "omega_ref")

    def __init__(self, K_ref, zeta=1.1, w_ld=0.0, tau_min=-math.inf, tau_max=math.inf, feedforward=0,
                 b_ff=0.0, I0=0.0, acc_ff=0, tau_current=0.0, tau0=0.0, torque_noise=0.0, seed=0):
        self.K_ref, self.zeta = K_ref, zeta
        self.w_ld_param = w_ld
        self.w_ld = w_ld if w_ld > 0.0 else (K_ref / (4.0 * zeta * zeta) if zeta > 0.0 else math.nan)
        self.tau_min, self.tau_max = tau_min, tau_max
        self.feedforward_value = feedforward
        self.feedforward = int(round(feedforward)) == 1 if math.isfinite(feedforward) else False
        self.b_ff, self.I0 = b_ff, I0
        self.acc_ff_value = acc_ff
        self.acc_ff = int(round(acc_ff)) == 1 if math.isfinite(acc_ff) else False
        self.tau_current, self.tau0 = tau_current, tau0
        self.lag = tau_current > 0.0
        self.STATES = ("I", "tau_m") if self.lag else ("I",)
        self.torque_noise, self.seed = torque_noise, seed

    def problems(self):
        p = require_positive([], K_ref=self.K_ref, zeta=self.zeta)
        require_finite(p, w_ld=self.w_ld_param, b_ff=self.b_ff, I0=self.I0, tau0=self.tau0)
        require_non_negative(p, tau_current=self.tau_current, torque_noise=self.torque_noise)
        if math.isfinite(self.seed) and self.seed != round(self.seed):
            p.append(("seed", f"must be an integer (got {self.seed!r})"))
        _limit_problems(p, "tau_min", self.tau_min, "tau_max", self.tau_max)
        for name, value in (("feedforward", self.feedforward_value), ("acc_ff", self.acc_ff_value)):
            if value not in (0.0, 1.0):
                p.append((name, f"must be 0 or 1 (got {value!r})"))
        return p

    def initial_state(self):
        return [self.I0, self.tau0] if self.lag else [self.I0]

    def _law(self, x, u):
        """(tau command, unsaturated tau, error, omega_ref)."""
        v_ref, v_trim, R, omega, J, T_in, T_out = u[:7]
        if not R > 0.0:
            raise ValueError(f"input R must be > 0 (got {R!r})")
        if not J > 0.0:
            raise ValueError(f"input J must be > 0 (got {J!r})")
        omega_ref = (v_ref + v_trim) / R
        e = omega_ref - omega
        ff = R * (T_in - T_out) + self.b_ff * omega if self.feedforward else 0.0
        if self.acc_ff:
            ff += acceleration_feedforward(J, u[7], R)  # only read when on: older 7-input callers stay valid
        tau, unsat = pi_output(J * self.K_ref, self.w_ld, e, x[0], ff, self.tau_min, self.tau_max)
        return tau, unsat, e, omega_ref

    def derivatives(self, t, x, u):
        tau, unsat, e, _ = self._law(x, u)
        if self.lag:
            return [integral_rate(e, unsat, self.tau_min, self.tau_max),
                    current_lag_rate(x[1], tau, self.tau_current)]
        return [integral_rate(e, unsat, self.tau_min, self.tau_max)]

    def noise(self, t):
        if self.torque_noise == 0.0:
            return 0.0
        return self.torque_noise * standard_normal(int(self.seed), t)

    def outputs(self, t, x, u):
        tau, _, _, omega_ref = self._law(x, u)
        return [(x[1] if self.lag else tau) + self.noise(t), omega_ref]


class TensionPIModel(ElementModel):
    """Tension loop of {25}: v_trim = sign K (e + w_i I), e = T_ref - T_meas, saturated to
    [trim_min, trim_max] with conditional-integration anti-windup. State I = integral of e (N.s).

    ``sign`` -1 for a loop at the upstream end of its tension zone (an unwind:
    too little tension must slow it), +1 at the downstream end (a rewind).
    """

    STATES = ("I",)
    INPUTS = ("T_ref", "T_meas")
    OUTPUTS = ("v_trim",)

    def __init__(self, K, w_i=10.0, sign=1.0, trim_min=-math.inf, trim_max=math.inf, I0=0.0):
        self.K, self.w_i, self.sign = K, w_i, sign
        self.trim_min, self.trim_max, self.I0 = trim_min, trim_max, I0

    def problems(self):
        p = require_positive([], K=self.K)
        if not (self.w_i >= 0.0 and math.isfinite(self.w_i)):
            p.append(("w_i", f"must be >= 0 (got {self.w_i!r})"))
        if self.sign not in (1.0, -1.0):
            p.append(("sign", f"must be +1 or -1 (got {self.sign!r})"))
        require_finite(p, I0=self.I0)
        return _limit_problems(p, "trim_min", self.trim_min, "trim_max", self.trim_max)

    def initial_state(self):
        return [self.I0]

    def _law(self, x, u):
        e = u[0] - u[1]
        trim, unsat = pi_output(self.sign * self.K, self.w_i, e, x[0], 0.0, self.trim_min, self.trim_max)
        return trim, unsat, e

    def derivatives(self, t, x, u):
        _, unsat, e = self._law(x, u)
        return [integral_rate(e, unsat, self.trim_min, self.trim_max, direction=self.sign)]

    def outputs(self, t, x, u):
        return [self._law(x, u)[0]]
