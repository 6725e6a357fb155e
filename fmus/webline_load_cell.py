"""LoadCell FMU: tension reading of a load-cell roller (wrap geometry, filter, seeded noise).

Thin wrapper of :class:`webline.physics.load_cell.LoadCellModel`. The output
depends on the inputs only when ``tau_filter`` = 0; being a parameter, that
cannot change the model description, so the dependency is declared always.
"""
import os
import sys

# pythonfmu imports each FMU's bundled ``webline`` under one process-wide name.
# A copy imported from another FMU's folder that the host has since deleted
# (fmpy.simulate_fmu removes its extraction) would break the imports below.
if not os.path.exists(getattr(sys.modules.get("webline"), "__file__", None) or "."):
    for _name in [m for m in sys.modules if m == "webline" or m.startswith("webline.")]:
        del sys.modules[_name]

from webline.fmi_slave import ElementSlave, Var, choice, finite, non_negative, positive, tension_rate_input
from webline.physics.load_cell import LoadCellModel


class LoadCell(ElementSlave):
    description = ("Load cell: weighted mean of the adjacent span tensions, first- or second-order filter, "
                   "seeded noise")
    PARAMETERS = (
        Var("angle_in", "rad", 0.0, "Angle between the entering web and the measuring axis (0: along it)",
            check=finite),
        Var("angle_out", "rad", 0.0, "Angle between the leaving web and the measuring axis (0: along it)",
            check=finite),
        Var("tau_filter", "s", 0.0, "Time constant of the first-order filter (0: none)", check=non_negative),
        Var("noise_std", "N", 0.0, "Standard deviation of the Gaussian measurement noise (0: none)",
            check=non_negative),
        Var("seed", "1", 0, "Integer seed of the noise (a function of seed and time only)", check=finite),
        Var("T0", "N", 0.0, "Initial filter output", check=finite),
        Var("filter_order", "1", 1, "1: first-order lag; 2: second-order low pass, w_c = 1/tau_filter",
            check=choice(1.0, 2.0)),
        Var("filter_damping", "1", 0.707, "Damping ratio of the second-order filter", check=positive),
    )
    INPUTS = (
        Var("T_in", "N", 0.0, "Tension of the span entering the roller"),
        Var("T_out", "N", 0.0, "Tension of the span leaving the roller"),
        tension_rate_input("dT_in", "T_in"),
        tension_rate_input("dT_out", "T_out"),
    )
    OUTPUTS = (
        Var("T", "N", 0.0, "Measured tension", depends=("T_in", "T_out")),
    )

    def make_model(self):
        return LoadCellModel(self.angle_in, self.angle_out, self.tau_filter, self.noise_std, self.seed, self.T0,
                             self.filter_order, self.filter_damping)
