"""Non-ideal drive between a motor and the element it turns.

The paper (Introduction) tried backlash and shaft/belt compliance before it
found span-length variation; these are those effects. The motor (inertia
J_m) drives the element through a shaft of stiffness k and damping c with a
dead zone of total width ``backlash`` (rad): no torque passes while the
twist lies inside the dead zone.
"""


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
