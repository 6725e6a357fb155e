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

from webline.fmi_slave import (ElementSlave, Var, drive_from, drive_vars, finite, non_negative, positive,
                               tension_rate_input)
from webline.physics.roller import DrivenRollerModel


class DrivenRoller(ElementSlave):
    description = "Driven roller: speed and angle from motor torque and web tensions (Branca et al. {22})"
    PARAMETERS = (
        Var("R", "m", 0.05, "Roller radius", check=positive),
        Var("J", "kg.m2", 0.01, "Roller inertia (with the ideal drive include the motor)", check=positive),
        Var("b", "N.m.s/rad", 0.0, "Viscous friction coefficient", check=non_negative),
        Var("omega0", "rad/s", 0.0, "Initial angular speed", check=finite),
        Var("theta0", "rad", 0.0, "Initial angle", check=finite),
        *drive_vars(),
    )
    INPUTS = (
        Var("tau", "N.m", 0.0, "Motor torque in the direction of rotation"),
        Var("T_in", "N", 0.0, "Tension of the span entering the roller (T_i)"),
        Var("T_out", "N", 0.0, "Tension of the span leaving the roller (T_{i+1})"),
        tension_rate_input("dT_in", "T_in"),
        tension_rate_input("dT_out", "T_out"),
    )
    OUTPUTS = (
        Var("omega", "rad/s", 0.0, "Angular speed of the roller"),
        Var("theta", "rad", 0.0, "Angle of the roller"),
        Var("v", "m/s", 0.0, "Web speed on the roller, R*omega"),
        Var("omega_motor", "rad/s", 0.0, "Motor speed (equals omega with the ideal drive)"),
        Var("a", "m/s2", 0.0, "Web acceleration on the roller R*d(omega)/dt (rate input for the adjacent "
            "spans' extrapolation of v)", depends=("tau", "T_in", "T_out")),
    )

    def make_model(self):
        return DrivenRollerModel(self.R, self.J, self.b, self.omega0, self.theta0, drive_from(self),
                                 tau0=self.tau)
