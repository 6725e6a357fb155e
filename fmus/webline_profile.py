"""Profile FMU: piecewise-linear table of up to 32 points (speed ramps, reference steps).

Thin wrapper of :class:`webline.physics.profile.ProfileModel`: y holds y[1]
before t[1] and y[n] after t[n]; two points at the same time make a step.
"""
import os
import sys

# pythonfmu imports each FMU's bundled ``webline`` under one process-wide name.
# A copy imported from another FMU's folder that the host has since deleted
# (fmpy.simulate_fmu removes its extraction) would break the imports below.
if not os.path.exists(getattr(sys.modules.get("webline"), "__file__", None) or "."):
    for _name in [m for m in sys.modules if m == "webline" or m.startswith("webline.")]:
        del sys.modules[_name]

from webline.fmi_slave import ElementSlave, Var, finite
from webline.physics.profile import MAX_POINTS, ProfileModel


def _table_vars():
    out = []
    for k in range(1, MAX_POINTS + 1):
        out.append(Var(f"t[{k}]", "s", float(k - 1), f"Time of point {k}", check=finite))
        out.append(Var(f"y[{k}]", "1", 0.0, f"Value at point {k} (unit of the connected input)", check=finite))
    return out


class Profile(ElementSlave):
    description = "Piecewise-linear time profile, held after the last point"
    PARAMETERS = (
        Var("n", "1", 1, f"Number of points used (1..{MAX_POINTS})", check=finite),
        *_table_vars(),
    )
    OUTPUTS = (
        Var("y", "1", 0.0, "Profile value"),
        Var("dy", "1", 0.0, "Slope dy/dt of the profile (unit of y per second; 0 on flat parts and steps)"),
    )

    def make_model(self):
        return ProfileModel(self.n, self.values("", MAX_POINTS, "t"), self.values("", MAX_POINTS, "y"))
