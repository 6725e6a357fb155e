"""Idle and driven rollers, {22}: J w' = -b w + R (T_{i+1} - T_i) + tau.

``T_out`` is the downstream span tension T_{i+1}, ``T_in`` the upstream T_i.
An idle roller has tau = 0.
"""
from webline.physics.drive import Drive
from webline.physics.element import ElementModel, require_finite, require_non_negative, require_positive


def roller_acceleration(omega, R, T_in, T_out, tau, J, b):
    """d omega/dt of {22}."""
    return (-b * omega + R * (T_out - T_in) + tau) / J


def holding_torque(omega, R, T_in, T_out, b):
    """Motor torque that keeps a roller at constant speed: tau = b w - R (T_out - T_in)."""
    return b * omega - R * (T_out - T_in)


def _roller_problems(model):
    p = require_positive([], R=model.R, J=model.J)
    require_non_negative(p, b=model.b)
    return require_finite(p, omega0=model.omega0, theta0=model.theta0)


class IdleRollerModel(ElementModel):
    """Idle roller, {22} with tau = 0. States [omega, theta]; web speed v = R omega."""

    STATES = ("omega", "theta")
    INPUTS = ("T_in", "T_out", "dT_in", "dT_out")
    OUTPUTS = ("omega", "theta", "v", "a")
    EXTRAPOLATE = {"T_in": "dT_in", "T_out": "dT_out"}
    RATE_INPUTS = ("dT_in", "dT_out")

    def __init__(self, R, J, b=0.0, omega0=0.0, theta0=0.0):
        self.R, self.J, self.b, self.omega0, self.theta0 = R, J, b, omega0, theta0

    def problems(self):
        return _roller_problems(self)

    def initial_state(self):
        return [self.omega0, self.theta0]

    def derivatives(self, t, x, u):
        return [roller_acceleration(x[0], self.R, u[0], u[1], 0.0, self.J, self.b), x[0]]

    def outputs(self, t, x, u):
        R = self.R
        return [x[0], x[1], R * x[0], R * roller_acceleration(x[0], R, u[0], u[1], 0.0, self.J, self.b)]


class DrivenRollerModel(ElementModel):
    """Driven roller, {22}, optionally through a non-ideal drive (:class:`webline.physics.drive.Drive`).

    Input ``tau`` is the motor torque. With the ideal drive ``J`` includes the
    motor; with the non-ideal drive ``J`` is the roller side only and the motor
    is ``drive.J_motor``. States [omega, theta] (+ [theta_motor, omega_motor]);
    ``tau0`` the motor torque at the start, carried by the shaft's initial twist.
    """

    INPUTS = ("tau", "T_in", "T_out", "dT_in", "dT_out")
    OUTPUTS = ("omega", "theta", "v", "omega_motor", "a")
    EXTRAPOLATE = {"T_in": "dT_in", "T_out": "dT_out"}
    RATE_INPUTS = ("dT_in", "dT_out")

    def __init__(self, R, J, b=0.0, omega0=0.0, theta0=0.0, drive=None, tau0=0.0):
        self.R, self.J, self.b, self.omega0, self.theta0 = R, J, b, omega0, theta0
        self.drive, self.tau0 = drive or Drive(), tau0
        self.STATES = ("omega", "theta") + self.drive.states

    def problems(self):
        return _roller_problems(self) + self.drive.problems()

    def initial_state(self):
        return [self.omega0, self.theta0] + self.drive.initial_state(self.theta0, self.omega0, self.tau0)

    def derivatives(self, t, x, u):
        tau_el, dxm = self.drive.element_torque(u[0], x[1], x[0], x[2:])
        return [roller_acceleration(x[0], self.R, u[1], u[2], tau_el, self.J, self.b), x[0]] + dxm

    def outputs(self, t, x, u):
        tau_el, _ = self.drive.element_torque(u[0], x[1], x[0], x[2:])
        a = self.R * roller_acceleration(x[0], self.R, u[1], u[2], tau_el, self.J, self.b)
        return [x[0], x[1], self.R * x[0], self.drive.motor_speed(x[0], x[2:]), a]

    def max_substep(self, x):
        return self.drive.max_substep(self.J)
