"""DampedSpan FMU: a Span ({20}/{21}/{26}, {27}-{32}) of a Kelvin-Voigt web.

Thin wrapper of :class:`webline.physics.span.SpanModel` with ``damping_time``: the state
is the elastic tension T_e of {20}; the output ``T`` = T_e + damping_time dT_e/dt depends
directly on the inputs that ``dT`` depends on, and declares them. It is a model of its own
rather than a parameter of Span because a parameter cannot change the model description:
declaring that dependency on every Span would make each elastic span's ``T`` a feed-through
for the master, which then re-resolves it whenever any element upstream steps (2x slower
runs of the EWL, no other change). No algebraic loop follows: the inputs are element speeds
and angles (state outputs) and the upstream span's ``T``, a chain that ends at the first
span; the rate inputs (a_in, a_out, dT_in) only extrapolate inside a step and are left out,
as for ``dT``. Same variables as Span plus the parameter ``damping_time``.
"""
import os
import sys

# pythonfmu imports each FMU's bundled ``webline`` under one process-wide name.
# A copy imported from another FMU's folder that the host has since deleted
# (fmpy.simulate_fmu removes its extraction) would break the imports below.
if not os.path.exists(getattr(sys.modules.get("webline"), "__file__", None) or "."):
    for _name in [m for m in sys.modules if m == "webline" or m.startswith("webline.")]:
        del sys.modules[_name]

from webline.fmi_slave import ElementSlave, span_declarations
from webline.physics.span import SpanModel



class DampedSpan(ElementSlave):
    description = ("Web span of a Kelvin-Voigt web: T = T_e + damping_time dT_e/dt, T_e of {20}, with Fourier "
                   "span-length variation (Branca et al. {20},{26},{28})")
    PARAMETERS, INPUTS, OUTPUTS = span_declarations(damped=True)

    def make_model(self):
        return SpanModel(self.EA, self.L0, self.T0,
                         self.values("up"), self.values("up", field="psi"),
                         self.values("down"), self.values("down", field="psi"),
                         self.length_mode, self.f_fixed, self.damping_time)
