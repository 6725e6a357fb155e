"""Load-cell roller: the tension a load cell reports from the two spans it sits between.

A load cell measures the resultant web force along its axis. Calibrated with
equal tensions, it reports a weighted mean of the entering and leaving
tensions: weights are the projections of each web direction on the measuring
axis (wrap geometry). With equal angles this is the plain mean.
"""
import math


def wrap_weights(angle_in, angle_out):
    """Weights of the entering/leaving tension for web directions at ``angle_*`` (rad)
    from the plane normal to the measuring axis (0 = force fully along the axis)."""
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
