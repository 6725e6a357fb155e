"""Idle and driven rollers, {22}: J w' = -b w + R (T_{i+1} - T_i) + tau.

``T_out`` is the downstream span tension T_{i+1}, ``T_in`` the upstream T_i.
An idle roller has tau = 0.
"""


def roller_acceleration(omega, R, T_in, T_out, tau, J, b):
    """d omega/dt of {22}."""
    return (-b * omega + R * (T_out - T_in) + tau) / J


def holding_torque(omega, R, T_in, T_out, b):
    """Motor torque that keeps a roller at constant speed: tau = b w - R (T_out - T_in)."""
    return b * omega - R * (T_out - T_in)
