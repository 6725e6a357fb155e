"""Span FMU: tension in a free web span, {20}/{21}/{26}, with span-length variation {27}-{32}.

Thin wrapper of :class:`webline.physics.span.SpanModel`. ``length_mode``:
0 angle-locked Fourier series of the upstream/downstream element (inputs
``theta_*``, ``omega_*``; the angles are advanced with the speeds inside a
step), 1 external ``L_ext``/``dL_ext`` inputs, 2 the paper's {32} at a fixed
frequency ``f_fixed``.
"""
import os
import sys

# pythonfmu imports each FMU's bundled ``webline`` under one process-wide name.
# A copy imported from another FMU's folder that the host has since deleted
# (fmpy.simulate_fmu removes its extraction) would break the imports below.
if not os.path.exists(getattr(sys.modules.get("webline"), "__file__", None) or "."):
    for _name in [m for m in sys.modules if m == "webline" or m.startswith("webline.")]:
        del sys.modules[_name]

from webline.fmi_slave import ElementSlave, Var, finite, fourier_vars, positive
from webline.physics.span import SpanModel


class Span(ElementSlave):
    description = "Web span: tension state with Fourier span-length variation (Branca et al. {20},{26},{28})"
    PARAMETERS = (
        Var("EA", "N", 2.0e4, "Web axial stiffness E*A", check=positive),
        Var("L0", "m", 1.0, "Nominal (mean) span length", check=positive),
        Var("T0", "N", 100.0, "Initial tension", check=finite),
        Var("length_mode", "1", 0, "0 angle-locked Fourier, 1 external L/dL inputs, 2 fixed frequency {32}"),
        Var("f_fixed", "Hz", 0.0, "Fundamental frequency for length_mode 2", check=finite),
        *fourier_vars("up", "upstream"),
        *fourier_vars("down", "downstream"),
    )
    INPUTS = (
        Var("v_in", "m/s", 1.0, "Web speed on the upstream element"),
        Var("v_out", "m/s", 1.0, "Web speed on the downstream element"),
        Var("T_in", "N", 0.0, "Tension of the web entering the span (upstream span; 0 after an unwind)"),
        Var("theta_up", "rad", 0.0, "Angle of the upstream element"),
        Var("omega_up", "rad/s", 0.0, "Angular speed of the upstream element", rate_of="theta_up"),
        Var("theta_down", "rad", 0.0, "Angle of the downstream element"),
        Var("omega_down", "rad/s", 0.0, "Angular speed of the downstream element", rate_of="theta_down"),
        Var("L_ext", "m", 1.0, "Span length (length_mode 1)"),
        Var("dL_ext", "m/s", 0.0, "Span length rate (length_mode 1)"),
        Var("a_in", "m/s2", 0.0, "Web acceleration on the upstream element (extrapolates v_in inside a step; "
            "0 holds it)", rate_of="v_in"),
        Var("a_out", "m/s2", 0.0, "Web acceleration on the downstream element (extrapolates v_out inside a "
            "step; 0 holds it)", rate_of="v_out"),
        Var("dT_in", "N/s", 0.0, "Rate of T_in (extrapolates T_in inside a step; 0 holds it)", rate_of="T_in"),
    )
    OUTPUTS = (
        Var("T", "N", 100.0, "Web tension in the span"),
        Var("L", "m", 1.0, "Span length", depends=("theta_up", "theta_down", "L_ext")),
        Var("dL", "m/s", 0.0, "Span length rate dL/dt",
            depends=("theta_up", "omega_up", "theta_down", "omega_down", "dL_ext")),
        Var("dT", "N/s", 0.0, "Tension rate dT/dt ({20}; rate input for the extrapolation of T by its "
            "neighbours)", depends=("v_in", "v_out", "T_in", "theta_up", "omega_up", "theta_down",
                                    "omega_down", "L_ext", "dL_ext")),
    )

    def make_model(self):
        return SpanModel(self.EA, self.L0, self.T0,
                         self.values("up"), self.values("up", field="psi"),
                         self.values("down"), self.values("down", field="psi"),
                         self.length_mode, self.f_fixed)
