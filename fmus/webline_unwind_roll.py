"""UnwindRoll FMU: unwinding material roll, {7} with {3}-{5}, optional non-ideal drive.

Thin wrapper of :class:`webline.physics.material_roll.UnwindRollModel`. The
radius shrinks by one web thickness per revolution; a roll that runs empty
fails its step (logged, fmi2Discard).
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
from webline.physics.material_roll import UnwindRollModel


class UnwindRoll(ElementSlave):
    description = "Unwind material roll: speed, angle and shrinking radius (Branca et al. {3}-{7})"
    PARAMETERS = material_roll_parameters()
    INPUTS = (
        Var("tau", "N.m", 0.0, "Motor torque in the direction of rotation (= -tau_u of {1})"),
        Var("T_out", "N", 0.0, "Tension of the span leaving the roll (T_1)"),
        tension_rate_input("dT_out", "T_out"),
    )
    OUTPUTS = material_roll_outputs("T_out")

    def make_model(self):
        return UnwindRollModel(self.R0, self.R_core, self.thickness, self.width, self.rho, self.J_core,
                               self.b, self.omega0, self.theta0, drive_from(self),
                               tau0=self.tau)
