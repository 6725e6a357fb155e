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

from webline.fmi_slave import ElementSlave, Var, roller_outputs, roller_parameters, roller_tension_inputs
from webline.physics.roller import IdleRollerModel


class IdleRoller(ElementSlave):
    description = "Idle roller: speed and angle from the web tensions on both sides (Branca et al. {22})"
    PARAMETERS = (
        *roller_parameters("Roller inertia"),
    )
    INPUTS = (
        *roller_tension_inputs(),
    )
    OUTPUTS = (
        *roller_outputs(),
        Var("a", "m/s2", 0.0, "Web acceleration on the roller R*d(omega)/dt (rate input for the adjacent "
            "spans' extrapolation of v)", depends=("T_in", "T_out")),
    )

    def make_model(self):
        return IdleRollerModel(self.R, self.J, self.b, self.omega0, self.theta0)
