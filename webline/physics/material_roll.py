"""Unwind and rewind material rolls, {1}-{8}.

Torque convention: ``tau`` is the motor torque in the direction of rotation
(positive accelerates the roll). The paper's unwind torque tau_u of {1} holds
the roll back, so tau = -tau_u for the unwind; for the rewind tau = tau_r.
"""
import math

from webline.physics.drive import Drive
from webline.physics.element import ElementModel, require_finite, require_non_negative, require_positive


def wound_inertia(R, R_core, rho, width):
    """J_w = pi/2 rho w (R^4 - R_c^4), {4}."""
    return 0.5 * math.pi * rho * width * (R ** 4 - R_core ** 4)


def inertia(R, R_core, rho, width, J_core):
    """J = J_0 + J_w, {3}."""
    return J_core + wound_inertia(R, R_core, rho, width)


def radius_rate(omega, thickness, winding):
    """dR/dt = -t_w omega/(2 pi) for an unwind (winding=-1), + for a rewind (winding=+1), {5}."""
    return winding * thickness * omega / (2.0 * math.pi)


def unwind_acceleration(omega, R, T_out, tau, J, b, rho, width, thickness):
    """d omega/dt of the unwind, {7}: J w' = -b w + R T_1 + tau + rho w_w R^3 t_w w^2."""
    return (-b * omega + R * T_out + tau + rho * width * R ** 3 * thickness * omega * omega) / J


def rewind_acceleration(omega, R, T_in, tau, J, b, rho, width, thickness):
    """d omega/dt of the rewind, {8}: J w' = -b w - R T_n + tau - rho w_w R^3 t_w w^2."""
    return (-b * omega - R * T_in + tau - rho * width * R ** 3 * thickness * omega * omega) / J


def web_length(R_from, R_to, thickness):
    """Web length between radii R_from and R_to of a roll: pi |R_from^2 - R_to^2| / t_w.

    Integrating {5}: each revolution (length 2 pi R) changes R by t_w, so
    dl = 2 pi R dR / t_w. The paid-out (or wound-on) length is the integral of v dt.
    """
    return math.pi * abs(R_from ** 2 - R_to ** 2) / thickness


class RollEmptyError(RuntimeError):
    """An unwind ran out of material (or a rewind was unwound past its core)."""


class _MaterialRollModel(ElementModel):
    """States [omega, theta, R] (+ [theta_motor, omega_motor] with the non-ideal drive).

    ``J_core`` is J_0 of {3}: core, shaft and coupling; with the ideal drive it
    includes the motor, with the non-ideal drive the motor is ``drive.J_motor``.
    The output ``J`` is the total inertia the motor accelerates (what K_p = J K_ref
    of {24} needs): {3} plus ``drive.J_motor`` when the drive is enabled.
    ``tau0``: motor torque at the start, which the non-ideal drive's shaft
    initially carries (see ``Drive.initial_state``).
    """

    WINDING = 0  # -1 unwind, +1 rewind
    OUTPUTS = ("omega", "theta", "R", "v", "J", "omega_motor", "a")

    def __init__(self, R0, R_core, thickness, width, rho, J_core=0.0, b=0.0, omega0=0.0, theta0=0.0,
                 drive=None, tau0=0.0):
        self.R0, self.R_core, self.thickness = R0, R_core, thickness
        self.width, self.rho, self.J_core, self.b = width, rho, J_core, b
        self.omega0, self.theta0 = omega0, theta0
        self.drive, self.tau0 = drive or Drive(), tau0
        self.STATES = ("omega", "theta", "R") + self.drive.states

    def problems(self):
        p = require_positive([], R_core=self.R_core, thickness=self.thickness, width=self.width, rho=self.rho)
        require_non_negative(p, J_core=self.J_core, b=self.b)
        require_finite(p, R0=self.R0, omega0=self.omega0, theta0=self.theta0)
        p += self._radius_problems()
        p += self.drive.problems()
        return p

    def _radius_problems(self):
        raise NotImplementedError

    def initial_state(self):
        return [self.omega0, self.theta0, self.R0] + self.drive.initial_state(self.theta0, self.omega0, self.tau0)

    def roll_inertia(self, R):
        """J of {3}, {4}."""
        return inertia(R, self.R_core, self.rho, self.width, self.J_core)

    def _check_radius(self, t, R):
        raise NotImplementedError

    def _acceleration(self, omega, R, T, tau, J):
        raise NotImplementedError

    def derivatives(self, t, x, u):
        omega, theta, R = x[0], x[1], x[2]
        self._check_radius(t, R)
        tau_el, dxm = self.drive.element_torque(u[0], theta, omega, x[3:])
        J = self.roll_inertia(R)
        return [self._acceleration(omega, R, u[1], tau_el, J), omega,
                radius_rate(omega, self.thickness, self.WINDING)] + dxm

    def outputs(self, t, x, u):
        omega, theta, R = x[0], x[1], x[2]
        J_roll = self.roll_inertia(R)
        J = J_roll + (self.drive.J_motor if self.drive.enabled else 0.0)
        # web acceleration d(R omega)/dt = R omega' + omega R'
        tau_el, _ = self.drive.element_torque(u[0], theta, omega, x[3:])
        a = (R * self._acceleration(omega, R, u[1], tau_el, J_roll)
             + omega * radius_rate(omega, self.thickness, self.WINDING))
        return [omega, theta, R, R * omega, J, self.drive.motor_speed(omega, x[3:]), a]

    def max_substep(self, x):
        return self.drive.max_substep(self.roll_inertia(x[2]))


class UnwindRollModel(_MaterialRollModel):
    """Unwind roll, {7} with {3}-{5}: the radius shrinks by one thickness per revolution.

    Inputs ``tau`` (motor torque in the direction of rotation, = -tau_u of {1})
    and ``T_out`` (tension of the first span, T_1). The run stops with
    :class:`RollEmptyError` when the radius reaches the core.
    """

    WINDING = -1
    INPUTS = ("tau", "T_out", "dT_out")
    EXTRAPOLATE = {"T_out": "dT_out"}
    RATE_INPUTS = ("dT_out",)

    def _radius_problems(self):
        if not self.R_core > 0.0 or self.R0 > self.R_core:
            return []
        return [("R0", f"must be above the core radius R_core = {self.R_core!r} m (got {self.R0!r})")]

    def _check_radius(self, t, R):
        if not R > self.R_core:
            raise RollEmptyError(
                f"unwind roll empty: radius R = {R:.6g} m reached the core radius R_core = "
                f"{self.R_core:.6g} m at t = {t:.6g} s")

    def _acceleration(self, omega, R, T, tau, J):
        return unwind_acceleration(omega, R, T, tau, J, self.b, self.rho, self.width, self.thickness)


class RewindRollModel(_MaterialRollModel):
    """Rewind roll, {8} with {3}-{5}: the radius grows by one thickness per revolution.

    Inputs ``tau`` (motor torque, tau_r of {8}) and ``T_in`` (tension of the
    last span, T_n). ``R0`` may equal ``R_core`` (an empty core); turning
    backwards past the core stops the run with :class:`RollEmptyError`.
    """

    WINDING = 1
    INPUTS = ("tau", "T_in", "dT_in")
    EXTRAPOLATE = {"T_in": "dT_in"}
    RATE_INPUTS = ("dT_in",)

    def _radius_problems(self):
        if not self.R_core > 0.0 or self.R0 > self.R_core:
            return []
        if self.R0 == self.R_core:
            # An empty core has only J_core to turn.
            return [] if self.J_core > 0.0 else [
                ("J_core", f"must be > 0 for a rewind starting on the bare core (R0 = R_core) (got {self.J_core!r})")]
        return [("R0", f"must not be below the core radius R_core = {self.R_core!r} m (got {self.R0!r})")]

    def _check_radius(self, t, R):
        if R < self.R_core:
            raise RollEmptyError(
                f"rewind roll unwound past its core: radius R = {R:.6g} m below R_core = "
                f"{self.R_core:.6g} m at t = {t:.6g} s")

    def _acceleration(self, omega, R, T, tau, J):
        return rewind_acceleration(omega, R, T, tau, J, self.b, self.rho, self.width, self.thickness)
