"""Unwind and rewind material rolls, {1}-{8}.

Torque convention: ``tau`` is the motor torque in the direction of rotation
(positive accelerates the roll). The paper's unwind torque tau_u of {1} holds
the roll back, so tau = -tau_u for the unwind; for the rewind tau = tau_r.
"""
import math


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
