"""DrivenRoller FMU: motor-driven roller, {22}, optional non-ideal drive.

Thin wrapper of :class:`webline.physics.roller.DrivenRollerModel`. With
``drive.enabled`` = 1 the torque ``tau`` acts on the motor inertia and
reaches the roller through a compliant shaft with backlash; the FMU then
shortens its RK4 sub-step to suit the shaft's natural frequency.
"""
import os
import sys

# pythonfmu imports each FMU's bundled ``webline`` under one process-wide name.
# A copy imported from another FMU's folder that the host has since deleted
# (fmpy.simulate_fmu removes its extraction) would break the imports below.
if not os.path.exists(getattr(sys.modules.get("webline"), "__file__", None) or "."):
    for _name in [m for m in sys.modules if m == "webline" or m.startswith("webline.")]:
        del sys.modules[_name]

from webline.fmi_slave import (ElementSlave, Var, drive_from, drive_vars, roller_outputs, roller_parameters,
                               roller_tension_inputs)
from webline.physics.roller import DrivenRollerModel


class DrivenRoller(ElementSlave):
    description = "Driven roller: speed and angle from motor torque and web tensions (Branca et al. {22})"
    PARAMETERS = (
        *roller_parameters("Roller inertia (with the ideal drive include the motor)"),
        *drive_vars(),
    )
    INPUTS = (
        Var("tau", "N.m", 0.0, "Motor torque in the direction of rotation"),
        *roller_tension_inputs(),
    )
    OUTPUTS = (
        *roller_outputs(),
        Var("omega_motor", "rad/s", 0.0, "Motor speed (equals omega with the ideal drive)"),
        Var("a", "m/s2", 0.0, "Web acceleration on the roller R*d(omega)/dt (rate input for the adjacent "
            "spans' extrapolation of v)", depends=("tau", "T_in", "T_out")),
    )

    def make_model(self):
        return DrivenRollerModel(self.R, self.J, self.b, self.omega0, self.theta0, drive_from(self),
                                 tau0=self.tau)
