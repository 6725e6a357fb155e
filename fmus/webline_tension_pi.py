"""TensionPI FMU: tension loop of {25} producing a speed trim, with limits and anti-windup.

Thin wrapper of :class:`webline.physics.controllers.TensionPIModel`.
"""
import os
import sys

# pythonfmu imports each FMU's bundled ``webline`` under one process-wide name.
# A copy imported from another FMU's folder that the host has since deleted
# (fmpy.simulate_fmu removes its extraction) would break the imports below.
if not os.path.exists(getattr(sys.modules.get("webline"), "__file__", None) or "."):
    for _name in [m for m in sys.modules if m == "webline" or m.startswith("webline.")]:
        del sys.modules[_name]

from webline.fmi_slave import ElementSlave, Var, choice, finite, non_negative, positive
from webline.physics.controllers import TensionPIModel


class TensionPI(ElementSlave):
    description = "Tension PI controller C_t(s) = K (s + w_i)/s giving a speed trim (Branca et al. {25})"
    PARAMETERS = (
        Var("K", "m/(s.N)", 2.0 * 0.00508 / 4.448222, "Gain: speed trim per newton of tension error "
            "(default 2 (ft/min)/lbf, {25} unwind)", check=positive),
        Var("w_i", "1/s", 10.0, "Integral corner frequency w_t of {25}", check=non_negative),
        Var("sign", "1", 1, "+1 at the downstream end of the tension zone (rewind), -1 at the upstream end (unwind)",
            check=choice(1.0, -1.0)),
        Var("trim_min", "m/s", -1.0e3, "Lower speed-trim limit", check=finite),
        Var("trim_max", "m/s", 1.0e3, "Upper speed-trim limit", check=finite),
        Var("I0", "N.s", 0.0, "Initial value of the integral of the tension error", check=finite),
    )
    INPUTS = (
        Var("T_ref", "N", 0.0, "Tension reference"),
        Var("T_meas", "N", 0.0, "Measured tension (load cell)"),
    )
    OUTPUTS = (
        Var("v_trim", "m/s", 0.0, "Speed trim for the speed loop", depends=("T_ref", "T_meas")),
    )

    def make_model(self):
        return TensionPIModel(self.K, self.w_i, self.sign, self.trim_min, self.trim_max, self.I0)
