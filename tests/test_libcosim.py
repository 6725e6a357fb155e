"""The element FMUs in a foreign master: libcosim (libcosimpy).

Every FMU loads and steps there with hand-checked results, and a closed
loop of several FMUs gives the same trajectory in libcosim as in an fmpy loop
that calls the FMUs in libcosim's fixed-step order (``fmu_loop.run_libcosim_order``).
"""
import math

import numpy as np
import pytest
from libcosimpy.CosimExecution import CosimExecution
from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
from libcosimpy.CosimObserver import CosimObserver
from libcosimpy.CosimSlave import CosimLocalSlave

from fmu_loop import Instance, run_libcosim_order
from webline.physics.load_cell import standard_normal

H = 1.0e-3


class Cosim:
    """A libcosim execution of named FMU instances with start values and connections."""

    def __init__(self, fmus, components, connections=(), step=H):
        log_output_level(CosimLogLevel.ERROR)  # its default level floods the test output
        self.ex = CosimExecution.from_step_size(int(round(step * 1e9)))
        self.index, self.refs = {}, {}
        for name, (model, values) in components.items():
            i = self.ex.add_local_slave(CosimLocalSlave(fmu_path=str(fmus[model]), instance_name=name))
            self.index[name] = i
            self.refs[name] = {v.name.decode(): v.reference for v in self.ex.slave_variables(i)}
            for var, value in values.items():
                assert self.ex.real_initial_value(i, self.refs[name][var], float(value)), f"{name}.{var}"
        for src, sv, dst, dv in connections:
            status = self.ex.connect_real_variables(self.index[src], self.refs[src][sv],
                                                    self.index[dst], self.refs[dst][dv])
            assert status in (0, True), f"connect {src}.{sv} -> {dst}.{dv}"
        self.observer = CosimObserver.create_last_value()
        self.ex.add_observer(self.observer)

    def run(self, n, record):
        """Step n times; {"comp.var": [value after each step]}."""
        data = {f"{c}.{v}": [] for c, vs in record.items() for v in vs}
        for k in range(n):
            assert self.ex.step(1), f"libcosim step {k + 1} failed"
            for c, vs in record.items():
                values = self.observer.last_real_values(self.index[c], [self.refs[c][v] for v in vs])
                for v, value in zip(vs, values):
                    data[f"{c}.{v}"].append(value)
        assert self.ex.status().current_time == int(round(n * H * 1e9))
        return {k: np.array(v) for k, v in data.items()}


# model: (start values, outputs to record, expected outputs at t = 20 ms by hand)
T_END = 20 * H
EA, L0, V_OUT, T_SS = 2.0e4, 0.5, 1.01, 2.0e4 * 0.01 / 1.01
ROLL = {"R0": 0.12, "R_core": 0.04, "thickness": 2e-4, "width": 0.4, "rho": 900.0, "J_core": 0.02, "omega0": 10.0}


def roll_inertia(R):
    return ROLL["J_core"] + 0.5 * math.pi * ROLL["rho"] * ROLL["width"] * (R ** 4 - ROLL["R_core"] ** 4)


CASES = {
    # {21}: T = T_ss (1 - exp(-v_out t/L0)) from T0 = 0 with v_in = 1, T_in = 0
    "Span": ({"EA": EA, "L0": L0, "T0": 0.0, "v_in": 1.0, "v_out": V_OUT},
             lambda y: y["T"] == pytest.approx(T_SS * (1 - math.exp(-V_OUT * T_END / L0)), rel=1e-9)),
    # free roll: J omega constant ({1}, {8}) and R on its revolution count
    "UnwindRoll": (ROLL, lambda y: (y["J"] * y["omega"] == pytest.approx(roll_inertia(0.12) * 10.0, rel=1e-9)
                                    and y["R"] == pytest.approx(0.12 - 2e-4 * y["theta"] / (2 * math.pi), rel=1e-12))),
    "RewindRoll": (ROLL, lambda y: (y["J"] * y["omega"] == pytest.approx(roll_inertia(0.12) * 10.0, rel=1e-9)
                                    and y["R"] == pytest.approx(0.12 + 2e-4 * y["theta"] / (2 * math.pi), rel=1e-12))),
    "IdleRoller": ({"R": 0.05, "J": 0.01, "omega0": 5.0, "T_in": 60.0, "T_out": 60.0},
                   lambda y: y["theta"] == pytest.approx(5.0 * T_END) and y["v"] == pytest.approx(0.25)),
    # (tau + R (T_out - T_in))/J = (0.2 + 0.1*1)/0.01 = 30 rad/s^2
    "DrivenRoller": ({"R": 0.1, "J": 0.01, "tau": 0.2, "T_in": 10.0, "T_out": 11.0},
                     lambda y: y["omega"] == pytest.approx(30.0 * T_END) and y["omega_motor"] == y["omega"]),
    # K_p = 0.5*10, w_ld = 10/4, e = 1/0.1 = 10: tau = 50 (1 + 2.5 t)
    "SpeedPI": ({"K_ref": 10.0, "zeta": 1.0, "v_ref": 1.0, "R": 0.1, "J": 0.5},
                lambda y: y["tau"] == pytest.approx(50.0 * (1 + 2.5 * T_END)) and y["omega_ref"] == 10.0),
    "TensionPI": ({"K": 2e-3, "w_i": 10.0, "sign": -1.0, "T_ref": 90.0, "T_meas": 100.0},
                  lambda y: y["v_trim"] == pytest.approx(2e-3 * 10.0 * (1 + 10.0 * T_END))),
    "LoadCell": ({"noise_std": 0.5, "seed": 9, "T_in": 100.0, "T_out": 100.0},
                 lambda y: y["T"] == pytest.approx(100.0 + 0.5 * standard_normal(9, T_END), rel=1e-15)),
    "Profile": ({"n": 2, "t[1]": 0.0, "t[2]": 0.04, "y[1]": 1.0, "y[2]": 3.0},
                lambda y: y["y"] == pytest.approx(2.0)),
}


@pytest.mark.parametrize("model", sorted(CASES))
def test_fmu_steps_in_libcosim(fmus, model):
    values, check = CASES[model]
    sim = Cosim(fmus, {"x": (model, values)})
    outputs = [v.name.decode() for v in sim.ex.slave_variables(sim.index["x"]) if v.causality == 2]  # output
    assert outputs
    data = sim.run(20, {"x": outputs})
    assert check({k.split(".", 1)[1]: v[-1] for k, v in data.items()})


def closed_loop():
    """Two loops in one system: a speed-controlled driven roller with a compliant
    drive whose reference comes from a profile and a (noisy) tension trim, and an
    eccentric idle roller between two spans."""
    components = {
        "prof": ("Profile", {"n": 3, "t[1]": 0.0, "t[2]": 0.1, "t[3]": 0.3, "y[1]": 0.0, "y[2]": 0.0, "y[3]": 1.0}),
        "pi": ("SpeedPI", {"K_ref": 20.0, "zeta": 1.1, "R": 0.1, "J": 0.05, "feedforward": 1,
                           "T_in": 100.0, "T_out": 100.0, "tau_min": -5.0, "tau_max": 5.0}),
        "drv": ("DrivenRoller", {"R": 0.1, "J": 0.04, "b": 0.01, "drive.enabled": 1, "drive.J_motor": 0.01,
                                 "drive.stiffness": 2000.0, "drive.damping": 0.2, "drive.backlash": 1e-3,
                                 "T_in": 100.0, "T_out": 100.0}),
        "lc": ("LoadCell", {"noise_std": 0.5, "seed": 4, "tau_filter": 0.0, "T_in": 100.0, "T_out": 102.0}),
        "tpi": ("TensionPI", {"K": 1e-3, "sign": 1.0, "T_ref": 101.0, "trim_min": -0.05, "trim_max": 0.05}),
        "s1": ("Span", {"EA": 1.0e4, "L0": 1.0, "T0": 100.0, "v_in": 1.0, "T_in": 0.0}),
        "roll": ("IdleRoller", {"R": 0.05, "J": 0.01, "omega0": 20.0 * 1.0101}),
        "s2": ("Span", {"EA": 1.0e4, "L0": 1.5, "T0": 200.0, "v_out": 1.0204, "up.C[1]": 2e-3, "up.psi[1]": 0.4}),
    }
    connections = [
        ("prof", "y", "pi", "v_ref"), ("tpi", "v_trim", "pi", "v_trim"), ("lc", "T", "tpi", "T_meas"),
        ("pi", "tau", "drv", "tau"), ("drv", "omega_motor", "pi", "omega"),
        ("roll", "v", "s1", "v_out"), ("s1", "T", "roll", "T_in"), ("s2", "T", "roll", "T_out"),
        ("roll", "v", "s2", "v_in"), ("s1", "T", "s2", "T_in"),
        ("roll", "theta", "s2", "theta_up"), ("roll", "omega", "s2", "omega_up"),
    ]
    record = {"pi": ["tau"], "drv": ["omega", "omega_motor"], "lc": ["T"], "tpi": ["v_trim"], "prof": ["y"],
              "s1": ["T"], "roll": ["omega"], "s2": ["T", "L"]}
    return components, connections, record


def test_closed_loop_same_in_libcosim_and_fmpy(fmus):
    components, connections, record = closed_loop()
    n = 500
    cosim = Cosim(fmus, components, connections).run(n, record)
    instances = {name: Instance(fmus[model], name, values) for name, (model, values) in components.items()}
    try:
        times, ours = run_libcosim_order(instances, connections, H, n, record)
    finally:
        for inst in instances.values():
            inst.free()
    assert times[-1] == pytest.approx(n * H)
    for key, ref in ours.items():
        ref = np.array(ref)
        scale = np.max(np.abs(ref))
        assert np.allclose(cosim[key], ref, rtol=1e-6, atol=1e-9 * scale), key
    # the loops did something: the roller tracked the ramp, the spans carry the eccentricity
    assert cosim["drv.omega"][-1] > 5.0 and np.ptp(cosim["s2.L"]) == pytest.approx(4e-3, rel=1e-3)
    assert np.ptp(cosim["tpi.v_trim"]) > 0 and np.ptp(cosim["s2.T"]) > 1.0
