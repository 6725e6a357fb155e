"""RewindRoll FMU: winding material roll, {8} with {3}-{5}, optional non-ideal drive.

Thin wrapper of :class:`webline.physics.material_roll.RewindRollModel`. The
radius grows by one web thickness per revolution.
"""
import os
import sys

# pythonfmu imports each FMU's bundled ``webline`` under one process-wide name.
# A copy imported from another FMU's folder that the host has since deleted
# (fmpy.simulate_fmu removes its extraction) would break the imports below.
if not os.path.exists(getattr(sys.modules.get("webline"), "__file__", None) or "."):
    for _name in [m for m in sys.modules if m == "webline" or m.startswith("webline.")]:
        del sys.modules[_name]

from webline.fmi_slave import (ElementSlave, Var, drive_from, material_roll_outputs, material_roll_parameters,
                               tension_rate_input)
from webline.physics.material_roll import RewindRollModel


class RewindRoll(ElementSlave):
    description = "Rewind material roll: speed, angle and growing radius (Branca et al. {3}-{5},{8})"
    PARAMETERS = material_roll_parameters()
    INPUTS = (
        Var("tau", "N.m", 0.0, "Motor torque in the direction of rotation (tau_r of {8})"),
        Var("T_in", "N", 0.0, "Tension of the span entering the roll (T_n)"),
        tension_rate_input("dT_in", "T_in"),
    )
    OUTPUTS = material_roll_outputs("T_in")

    def make_model(self):
        return RewindRollModel(self.R0, self.R_core, self.thickness, self.width, self.rho, self.J_core,
                               self.b, self.omega0, self.theta0, drive_from(self),
                               tau0=self.tau)
