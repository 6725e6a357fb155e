"""Span FMU: tension in a free web span, {20}/{21}/{26}, with span-length variation {27}-{32}.

Thin wrapper of :class:`webline.physics.span.SpanModel`. ``length_mode``:
0 angle-locked Fourier series of the upstream/downstream element (inputs
``theta_*``, ``omega_*``; the angles are advanced with the speeds inside a
step), 1 external ``L_ext``/``dL_ext`` inputs, 2 the paper's {32} at a fixed
frequency ``f_fixed``. An elastic web: ``T`` is the state and depends on no input
(a Kelvin-Voigt web is the DampedSpan FMU).
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



class Span(ElementSlave):
    description = "Web span: tension state with Fourier span-length variation (Branca et al. {20},{26},{28})"
    PARAMETERS, INPUTS, OUTPUTS = span_declarations(damped=False)

    def make_model(self):
        return SpanModel(self.EA, self.L0, self.T0,
                         self.values("up"), self.values("up", field="psi"),
                         self.values("down"), self.values("down", field="psi"),
                         self.length_mode, self.f_fixed)
