"""PI controllers of the EWL, {24} and {25}, with limits and anti-windup.

{24}: C_v(s) = K_p (s + w_ld)/s, K_p = J K_ref, w_ld = K_ref/(4 zeta^2).
{25}: printed as "2(s + 10)/2"; read as C_t(s) = K (s + w_t)/s with w_t = 10
rad/s (see docs/paper-notes: the gain unit is (ft/min)/lbf, converted to SI
(m/s)/N by the layout).

Both are the same parallel-form PI, u = K (e + w_i * integral e), written in
states that make anti-windup clean: the integrator stops while the output
saturates in the direction the error pushes it (conditional integration).
"""


def speed_gains(J, K_ref, zeta):
    """(K_p, w_ld) of {24}."""
    return J * K_ref, K_ref / (4.0 * zeta * zeta)


def pi_output(K, w_i, error, integral, u_ff, u_min, u_max):
    """Saturated PI output and the unsaturated value: u = u_ff + K (e + w_i I)."""
    u = u_ff + K * (error + w_i * integral)
    return min(max(u, u_min), u_max), u


def integral_rate(error, u_unsat, u_min, u_max):
    """dI/dt = e, except while saturated and the error pushes further into the limit."""
    if (u_unsat > u_max and error > 0.0) or (u_unsat < u_min and error < 0.0):
        return 0.0
    return error


def pi_step_response(K, w_i, e0, t):
    """Analytic open-loop output of K (s + w_i)/s to a constant error e0: K e0 (1 + w_i t)."""
    return K * e0 * (1.0 + w_i * t)
