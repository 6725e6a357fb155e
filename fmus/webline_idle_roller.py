"""IdleRoller FMU: free roller turned by the web, {22} with tau = 0.

Thin wrapper of :class:`webline.physics.roller.IdleRollerModel`.
"""
import os
import sys

# pythonfmu imports each FMU's bundled ``webline`` under one process-wide name.
# A copy imported from another FMU's folder that the host has since deleted
# (fmpy.simulate_fmu removes its extraction) would break the imports below.
if not os.path.exists(getattr(sys.modules.get("webline"), "__file__", None) or "."):
    for _name in [m for m in sys.modules if m == "webline" or m.startswith("webline.")]:
        del sys.modules[_name]

from webline.fmi_slave import ElementSlave, Var, finite, non_negative, positive, tension_rate_input
from webline.physics.roller import IdleRollerModel


class IdleRoller(ElementSlave):
    description = "Idle roller: speed and angle from the web tensions on both sides (Branca et al. {22})"
    PARAMETERS = (
        Var("R", "m", 0.05, "Roller radius", check=positive),
        Var("J", "kg.m2", 0.01, "Roller inertia", check=positive),
        Var("b", "N.m.s/rad", 0.0, "Viscous friction coefficient", check=non_negative),
        Var("omega0", "rad/s", 0.0, "Initial angular speed", check=finite),
        Var("theta0", "rad", 0.0, "Initial angle", check=finite),
    )
    INPUTS = (
        Var("T_in", "N", 0.0, "Tension of the span entering the roller (T_i)"),
        Var("T_out", "N", 0.0, "Tension of the span leaving the roller (T_{i+1})"),
        tension_rate_input("dT_in", "T_in"),
        tension_rate_input("dT_out", "T_out"),
    )
    OUTPUTS = (
        Var("omega", "rad/s", 0.0, "Angular speed of the roller"),
        Var("theta", "rad", 0.0, "Angle of the roller"),
        Var("v", "m/s", 0.0, "Web speed on the roller, R*omega"),
        Var("a", "m/s2", 0.0, "Web acceleration on the roller R*d(omega)/dt (rate input for the adjacent "
            "spans' extrapolation of v)", depends=("T_in", "T_out")),
    )

    def make_model(self):
        return IdleRollerModel(self.R, self.J, self.b, self.omega0, self.theta0)
