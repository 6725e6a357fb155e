"""SpeedPI FMU: speed loop of {24} with feed-forward, torque limits and anti-windup.

Thin wrapper of :class:`webline.physics.controllers.SpeedPIModel`. The
torque is a feed-through of every input (the integrator is the only state) when
``tau_current`` = 0; with a current lag (``tau_current`` > 0) it is the lag's state and
depends on no input, but a parameter cannot change the model description, so the
dependencies are declared always (a superset, as the LoadCell does).
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
from webline.physics.controllers import SpeedPIModel

ALL_INPUTS = ("v_ref", "v_trim", "R", "omega", "J", "T_in", "T_out", "a_ref")


class SpeedPI(ElementSlave):
    description = "Speed PI controller C_v(s) = J K_ref (s + w_ld)/s (Branca et al. {24})"
    PARAMETERS = (
        Var("K_ref", "1/s", 15.0, "Reference gain: K_p = J K_ref", check=positive),
        Var("zeta", "1", 1.1, "Damping ratio: w_ld = K_ref/(4 zeta^2)", check=positive),
        Var("w_ld", "1/s", 0.0, "Integral corner frequency; <= 0 selects K_ref/(4 zeta^2)", check=finite),
        Var("tau_min", "N.m", -1.0e6, "Lower torque limit", check=finite),
        Var("tau_max", "N.m", 1.0e6, "Upper torque limit", check=finite),
        Var("feedforward", "1", 0, "1: add R (T_in - T_out) + b_ff omega, the torque that holds the speed",
            check=choice(0.0, 1.0)),
        Var("b_ff", "N.m.s/rad", 0.0, "Friction coefficient used by the feed-forward", check=finite),
        Var("I0", "rad", 0.0, "Initial value of the integral of the speed error", check=finite),
        Var("acc_ff", "1", 0, "1: add the acceleration feed-forward J a_ref/R (J d omega_ref/dt)",
            check=choice(0.0, 1.0)),
        Var("tau_current", "s", 0.0, "Time constant of the drive's current loop, a first-order lag on the "
            "torque (0: none, tau is the PI law)", check=non_negative),
        Var("tau0", "N.m", 0.0, "Initial torque of the current-loop lag (tau_current > 0)", check=finite),
        Var("torque_noise", "N.m", 0.0, "RMS of the drive's broadband torque ripple added to tau (0: none)",
            check=non_negative),
        Var("seed", "1", 0.0, "Seed of the torque ripple (an integer)", check=finite),
    )
    INPUTS = (
        Var("v_ref", "m/s", 0.0, "Web speed reference"),
        Var("v_trim", "m/s", 0.0, "Speed trim added to the reference (from a tension loop)"),
        Var("R", "m", 0.1, "Radius of the controlled element"),
        Var("omega", "rad/s", 0.0, "Measured angular speed (the motor speed)"),
        Var("J", "kg.m2", 1.0, "Total inertia reflected at the motor"),
        Var("T_in", "N", 0.0, "Tension entering the element (0 for an unwind; feed-forward)"),
        Var("T_out", "N", 0.0, "Tension leaving the element (0 for a rewind; feed-forward)"),
        Var("a_ref", "m/s2", 0.0, "Rate of the speed reference d v_ref/dt (acceleration feed-forward)"),
    )
    OUTPUTS = (
        Var("tau", "N.m", 0.0, "Motor torque command", depends=ALL_INPUTS),
        Var("omega_ref", "rad/s", 0.0, "Angular speed reference (v_ref + v_trim)/R",
            depends=("v_ref", "v_trim", "R")),
    )

    def make_model(self):
        return SpeedPIModel(self.K_ref, self.zeta, self.w_ld, self.tau_min, self.tau_max, self.feedforward,
                            self.b_ff, self.I0, self.acc_ff, self.tau_current, self.tau0,
                            self.torque_noise, self.seed)
