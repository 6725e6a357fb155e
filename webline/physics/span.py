"""Tension in a free web span, {20}, {21}, {26}.

Sign convention: ``v_in`` is the web speed on the upstream element (i-1),
``v_out`` on the downstream element (i). The span length is
L = L0 + dL_up + dL_down, where dL_up is the lengthening caused by the
upstream element (its contact point moving upstream, x_{i-1} decreasing) and
dL_down the lengthening caused by the downstream one (x_i increasing).
"""
import math

from webline.physics.eccentricity import length_terms, sine_cosine_form
from webline.physics.element import ElementModel, require_positive


def tension_rate(T, T_in, v_in, v_out, EA, L, dL_up_dt=0.0, dL_down_dt=0.0):
    """dT_i/dt of {20}.

    With x_i' = dL_down_dt and x_{i-1}' = -dL_up_dt:
    dT/dt = [v_out (EA - T) - v_in (EA - T_in) + (EA - T) dL_down_dt
             + (EA - T_in) dL_up_dt] / L.
    With both rates zero this is {21}; with only the downstream end still it is {26}.
    ``T_in`` is the tension of the web entering the span (upstream span, or the
    wound-in tension for the first span after an unwind, usually 0).
    """
    return (v_out * (EA - T) - v_in * (EA - T_in)
            + (EA - T) * dL_down_dt + (EA - T_in) * dL_up_dt) / L


def kelvin_voigt_tension(T_e, dT_e_dt, damping_time):
    """Tension of a Kelvin-Voigt web: the elastic tension plus a strain-rate (viscous) term.

    With strain eps = T_e/EA, a spring EA in parallel with a dashpot EA * damping_time
    carries T = EA (eps + damping_time eps') = T_e + damping_time dT_e/dt, where T_e
    follows {20} (mass conservation fixes the strain, not the force). At steady
    state dT_e/dt = 0 and T = T_e: the operating point does not change."""
    return T_e + damping_time * dT_e_dt


def steady_state_tension(T_in, v_in, v_out, EA):
    """Equilibrium of {21}: T = EA (v_out - v_in)/v_out + v_in T_in / v_out."""
    return EA * (v_out - v_in) / v_out + v_in * T_in / v_out


def speed_ratio_for_tension(T, T_in, EA):
    """v_out/v_in that holds tension T given entering tension T_in: (EA - T_in)/(EA - T)."""
    return (EA - T_in) / (EA - T)


class SpanModel(ElementModel):
    """Span with tension state T and span length L = L0 + dL_up(theta_up) + dL_down(theta_down).

    ``length_mode``: 0 angle-locked Fourier series of both ends ({28}, {29}
    with 2 pi f t replaced by the element angle, so {30}/{31} hold at any
    speed and radius); 1 L and dL/dt from inputs ``L_ext``/``dL_ext``;
    2 the paper's {32}: upstream series at a fixed frequency ``f_fixed``.
    ``C_up``/``psi_up``/``C_down``/``psi_down``: Fourier coefficients (m, rad).

    ``damping_time`` (s) > 0 makes the web Kelvin-Voigt ({20} with a strain-rate
    term, :func:`kelvin_voigt_tension`): the state (named ``T`` as before) is the elastic
    tension T_e, which obeys {20} unchanged, and the output ``T`` is
    T_e + damping_time dT_e/dt, so it then depends directly on the inputs. ``dT`` stays
    dT_e/dt (it only extrapolates T inside a co-simulation step). ``T_in`` is what the
    layout connects: the upstream span's output T (for a damped upstream span, its
    total tension rather than the elastic tension that sets the entering strain; the
    difference, damping_time dT_e,in/dt, vanishes at steady state).
    """

    STATES = ("T",)
    INPUTS = ("v_in", "v_out", "T_in", "theta_up", "omega_up", "theta_down", "omega_down",
              "L_ext", "dL_ext", "a_in", "a_out", "dT_in")
    OUTPUTS = ("T", "L", "dL", "dT")
    EXTRAPOLATE = {"theta_up": "omega_up", "theta_down": "omega_down",
                   "v_in": "a_in", "v_out": "a_out", "T_in": "dT_in"}
    RATE_INPUTS = ("a_in", "a_out", "dT_in")

    def __init__(self, EA, L0, T0, C_up=(), psi_up=(), C_down=(), psi_down=(),
                 length_mode=0, f_fixed=0.0, damping_time=0.0):
        self.EA, self.L0, self.T0 = EA, L0, T0
        self.damping_time = damping_time
        self.C_up, self.psi_up = list(C_up), list(psi_up)
        self.C_down, self.psi_down = list(C_down), list(psi_down)
        self.length_mode, self.f_fixed = int(round(length_mode)), f_fixed
        # Most spans have round rollers at both ends: skip their Fourier sums.
        self.round_up = not any(self.C_up)
        self.round_down = not any(self.C_down)
        self.ab_up = sine_cosine_form(self.C_up, self.psi_up)
        self.ab_down = sine_cosine_form(self.C_down, self.psi_down)

    def problems(self):
        p = require_positive([], EA=self.EA, L0=self.L0)
        if not (self.damping_time >= 0.0 and math.isfinite(self.damping_time)):
            p.append(("damping_time", f"must be >= 0 (got {self.damping_time!r})"))
        if self.length_mode not in (0, 1, 2):
            p.append(("length_mode", f"must be 0, 1 or 2 (got {self.length_mode!r})"))
        amp = sum(abs(c) for c in self.C_up + self.C_down)
        if amp >= self.L0:
            p.append(("C_up/C_down", f"total Fourier amplitude {amp:g} m must stay below L0 = {self.L0:g} m"))
        if not self.T0 < self.EA:
            p.append(("T0", f"must be below EA = {self.EA:g} N (got {self.T0!r})"))
        return p

    def initial_state(self):
        return [self.T0]

    def length(self, t, u):
        """(L, dL_up/dt, dL_down/dt) from the inputs at time t."""
        if self.length_mode == 1:
            return u[7], 0.0, u[8]
        th_up, w_up, th_dn, w_dn = u[3], u[4], u[5], u[6]
        if self.length_mode == 2:
            w_up = 2.0 * math.pi * self.f_fixed
            th_up = w_up * t
        L, up, dn = self.L0, 0.0, 0.0
        if not self.round_up:
            off, up = length_terms(th_up, w_up, *self.ab_up)
            L += off
        if not self.round_down:
            off, dn = length_terms(th_dn, w_dn, *self.ab_down)
            L += off
        return L, up, dn

    def derivatives(self, t, x, u):
        L, up, dn = self.length(t, u)
        return [tension_rate(x[0], u[2], u[0], u[1], self.EA, L, up, dn)]

    def outputs(self, t, x, u):
        L, up, dn = self.length(t, u)
        rate = tension_rate(x[0], u[2], u[0], u[1], self.EA, L, up, dn)
        T = kelvin_voigt_tension(x[0], rate, self.damping_time) if self.damping_time else x[0]
        return [T, L, up + dn, rate]
