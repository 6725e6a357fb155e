"""Non-ideal drive between a motor and the element it turns.

The paper (Introduction) tried backlash and shaft/belt compliance before it
found span-length variation; these are those effects. The motor (inertia
J_m) drives the element through a shaft of stiffness k and damping c with a
dead zone of total width ``backlash`` (rad): no torque passes while the
twist lies inside the dead zone.

With the drive enabled the element gains two states, the motor angle and
speed; the motor torque ``tau`` then acts on the motor inertia and the shaft
torque on the element. Disabled, ``tau`` acts on the element directly (the
ideal, rigid drive of {1}, {8}, {22}).
"""
import math

from webline.physics.element import require_positive

# A classical RK4 sub-step is accurate to well under 1e-4 per period at
# h*omega_n = 0.1 (stability alone would allow about 2.8).
SUBSTEP_TIMES_RATE = 0.1


def dead_zone(twist, backlash):
    """Twist that loads the shaft, with a dead zone of total width ``backlash``."""
    half = 0.5 * backlash
    if twist > half:
        return twist - half
    if twist < -half:
        return twist + half
    return 0.0


def shaft_torque(twist, twist_rate, stiffness, damping, backlash):
    """Torque the shaft passes from motor to load (positive drives the load).

    Damping acts only while the teeth are in contact, and the torque never
    pulls the two sides together (a gap cannot transmit tension).
    """
    loaded = dead_zone(twist, backlash)
    if loaded == 0.0 and backlash > 0.0:
        return 0.0
    tau = stiffness * loaded + damping * twist_rate
    if backlash > 0.0 and tau * loaded < 0.0:
        return 0.0
    return tau


def motor_acceleration(tau_motor, tau_shaft, J_motor):
    """d omega_m/dt of the motor side."""
    return (tau_motor - tau_shaft) / J_motor


class Drive:
    """Motor + compliant shaft with backlash, shared by the driven roller and the material rolls.

    ``enabled`` 0 is the ideal drive (no states, ``tau`` reaches the element);
    1 adds the states ``theta_motor``, ``omega_motor``. The shaft twist is
    motor angle minus element angle (gear ratio 1: parameters refer to the
    element side, as the paper's {1} does).
    """

    STATES = ("theta_motor", "omega_motor")

    def __init__(self, enabled=0, J_motor=0.01, stiffness=1.0e4, damping=1.0, backlash=0.0):
        self.enabled_value = enabled
        self.enabled = int(round(enabled)) == 1
        self.J_motor, self.stiffness = J_motor, stiffness
        self.damping, self.backlash = damping, backlash

    @property
    def states(self):
        return self.STATES if self.enabled else ()

    def problems(self, prefix="drive."):
        p = []
        if self.enabled_value not in (0.0, 1.0):
            p.append((prefix + "enabled", f"must be 0 or 1 (got {self.enabled_value!r})"))
        if not self.enabled:
            return p
        p2 = require_positive([], J_motor=self.J_motor, stiffness=self.stiffness)
        p += [(prefix + n, r) for n, r in p2]
        for name in ("damping", "backlash"):
            value = getattr(self, name)
            if not (value >= 0.0 and math.isfinite(value)):
                p.append((prefix + name, f"must be >= 0 (got {value!r})"))
        return p

    def preload_twist(self, tau0):
        """Twist at which the shaft passes the torque ``tau0`` at rest (teeth in contact)."""
        if tau0 == 0.0:
            return 0.0
        return tau0 / self.stiffness + math.copysign(0.5 * self.backlash, tau0)

    def initial_state(self, theta0, omega0, tau0=0.0):
        """Motor at the element's speed, ahead of it by the twist that carries ``tau0``.

        With ``tau0`` the motor torque at the start, motor and element are in
        equilibrium: a line started at its operating point does not first jolt
        through the dead zone and wind up the shaft.
        """
        return [theta0 + self.preload_twist(tau0), omega0] if self.enabled else []

    def element_torque(self, tau, theta, omega, xm):
        """(torque on the element, [d theta_m/dt, d omega_m/dt]) for motor torque ``tau``.

        ``xm`` the drive states [theta_m, omega_m] (ignored when ideal).
        """
        if not self.enabled:
            return tau, []
        theta_m, omega_m = xm
        ts = shaft_torque(theta_m - theta, omega_m - omega, self.stiffness, self.damping, self.backlash)
        return ts, [omega_m, motor_acceleration(tau, ts, self.J_motor)]

    def motor_speed(self, omega, xm):
        return xm[1] if self.enabled else omega

    def rate(self, J_load):
        """Largest |eigenvalue| of the linearised two-mass shaft mode (1/s).

        Relative motion obeys s^2 + c/J_e s + k/J_e with 1/J_e = 1/J_m + 1/J_load;
        with damping the fast real root is at most c/J_e.
        """
        if not self.enabled:
            return 0.0
        inv = 1.0 / self.J_motor + (1.0 / J_load if J_load > 0.0 else math.inf)
        return max(math.sqrt(self.stiffness * inv), self.damping * inv)

    def max_substep(self, J_load):
        """Longest safe RK4 sub-step for the shaft mode with the element inertia ``J_load``."""
        r = self.rate(J_load)
        return SUBSTEP_TIMES_RATE / r if r > 0.0 else math.inf
