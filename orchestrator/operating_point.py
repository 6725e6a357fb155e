"""Steady state of a line at its start: tensions, speeds, torques and controller integrators.

A line that starts at speed starts in equilibrium, so a run at constant speed
has no start-up transient. The equations are the element models' own
(``webline.physics``), set to steady state:

* span tensions: in a tension-controlled zone the load cell reads the
  reference; along the zone each idle roller's bearing friction raises the
  tension by b omega / R (its torque balance {22} with tau = 0). A zone
  without a tension loop runs at draw 1 (its two driven ends at equal speed),
  so its last span carries the tension of the span entering it;
* speeds: the speed master runs at the line speed; across span k mass
  conservation {21} at steady state gives v_out/v_in = (EA - T_in)/(EA - T)
  (``speed_ratio_for_tension``), T_in the tension of the span before
  (0 for the first span: the web on the unwind is unstretched);
* driven elements: the motor torque that holds the speed ({7}, {8}, {22});
  the speed PI integrator makes the controller output that torque with zero
  speed error (with feed-forward it only covers what the feed-forward
  misses: the roll's inertia-change term {6} and the slow acceleration that
  keeps a roll's surface speed constant while its radius changes {5}).

Friction terms depend on the speeds and the speeds on the tensions, so the
two are iterated to a fixed point (a few iterations; exact at zero speed).
"""
import math
from dataclasses import dataclass, field

from webline.physics.controllers import speed_gains
from webline.physics.load_cell import measured_tension, wrap_weights
from webline.physics.material_roll import inertia, radius_rate, rewind_acceleration, unwind_acceleration
from webline.physics.roller import holding_torque
from webline.physics.span import speed_ratio_for_tension


@dataclass
class OpElement:
    """What the operating point needs of one path element (SI)."""
    name: str
    kind: str  # unwind, rewind, idle_roller, load_cell_roller, driven_roller
    R: float
    b: float = 0.0
    J: float = 0.0  # rollers: J; rolls: filled from the roll geometry
    R_core: float = 0.0
    J_core: float = 0.0


@dataclass
class OpZone:
    """Spans ``first``..``last`` (indices) between two driven elements. ``T_ref``: the
    reference its load cell must read (None: no tension loop, draw 1); ``cell``: the
    span index entering the load-cell roller and the weights (w_in, w_out)."""
    first: int
    last: int
    T_ref: float = None
    cell: tuple = None  # (span index p: roller between spans p and p+1, w_in, w_out)


@dataclass
class OperatingPoint:
    T: list  # span tensions (N), index k = span after element k
    v: list  # element surface speeds (m/s)
    omega: list  # element angular speeds (rad/s)
    ratio: list  # v / v_master (speed-reference scale of every element)
    J: list  # element inertias (kg.m2; rolls from {3}, {4})
    torque: dict = field(default_factory=dict)  # driven element -> holding motor torque (N.m)
    iterations: int = 0

    def T_in(self, k):
        """Tension of the web entering span k (0 for the first span)."""
        return self.T[k - 1] if k > 0 else 0.0

    def element_tensions(self, i):
        """(T_in, T_out) around element i; 0 where it has no span."""
        return (self.T[i - 1] if i > 0 else 0.0), (self.T[i] if i < len(self.T) else 0.0)


def idle_tension_rise(omega, R, b):
    """T_out - T_in across an idle roller at constant speed: {22} with tau = 0 and omega' = 0."""
    return holding_torque(omega, R, 0.0, 0.0, b) / R


def tracking_acceleration(el, omega, web):
    """d omega/dt that keeps a roll's surface speed R omega constant while its radius changes ({5}):
    omega' = -omega R'/R (the unwind speeds up, the rewind slows down); 0 for rollers."""
    if el.kind not in ("unwind", "rewind"):
        return 0.0
    return -omega * radius_rate(omega, web["thickness"], -1 if el.kind == "unwind" else 1) / el.R


def holding_motor_torque(el, omega, T_in, T_out, web, J=1.0):
    """Motor torque (direction of rotation) that keeps driven element ``el`` at constant surface speed.

    Rollers: {22} at omega' = 0. Rolls: {7}/{8} at omega' = ``tracking_acceleration``
    (J the roll's inertia): J (omega' - a0), a0 the acceleration without motor torque."""
    if el.kind == "unwind":
        a0 = unwind_acceleration(omega, el.R, T_out, 0.0, J, el.b, web["rho"], web["width"], web["thickness"])
        return J * (tracking_acceleration(el, omega, web) - a0)
    if el.kind == "rewind":
        a0 = rewind_acceleration(omega, el.R, T_in, 0.0, J, el.b, web["rho"], web["width"], web["thickness"])
        return J * (tracking_acceleration(el, omega, web) - a0)
    return holding_torque(omega, el.R, T_in, T_out, el.b)


def solve(elements, zones, EA, master, v_line, web, tol=1e-13, max_iter=100):
    """The operating point of a path (``elements`` in order, ``zones`` in order)."""
    n = len(elements)
    J = [inertia(e.R, e.R_core, web["rho"], web["width"], e.J_core) if e.kind in ("unwind", "rewind") else e.J
         for e in elements]
    v = [v_line] * n
    ratio = [1.0] * n
    T = [0.0] * (n - 1)
    for it in range(1, max_iter + 1):
        omega = [v[i] / elements[i].R for i in range(n)]
        T = [0.0] * (n - 1)
        T_before = 0.0  # tension of the span entering the zone's upstream driven element
        for z in zones:
            rise = [0.0]  # tension of span first+j relative to span first
            for k in range(z.first + 1, z.last + 1):
                e = elements[k]  # the idle roller between spans k-1 and k
                rise.append(rise[-1] + idle_tension_rise(omega[k], e.R, e.b))
            if z.T_ref is not None:
                p, w_in, w_out = z.cell
                T_first = z.T_ref - measured_tension(rise[p - z.first], rise[p + 1 - z.first], w_in, w_out)
            else:
                T_first = T_before - rise[-1]  # draw 1: the zone's last span carries T_before
            for j, k in enumerate(range(z.first, z.last + 1)):
                T[k] = T_first + rise[j]
            T_before = T[z.last]
        ratio = [1.0] * n
        for k in range(master, n - 1):  # downstream of the master
            ratio[k + 1] = ratio[k] * speed_ratio_for_tension(T[k], T[k - 1] if k > 0 else 0.0, EA)
        for k in range(master - 1, -1, -1):  # upstream
            ratio[k] = ratio[k + 1] / speed_ratio_for_tension(T[k], T[k - 1] if k > 0 else 0.0, EA)
        v_new = [v_line * r for r in ratio]
        change = max(abs(a - b) for a, b in zip(v_new, v))
        v = v_new
        if change <= tol * max(1.0, abs(v_line)):
            break
    omega = [v[i] / elements[i].R for i in range(n)]
    op = OperatingPoint(T=T, v=v, omega=omega, ratio=ratio, J=J, iterations=it)
    for i, e in enumerate(elements):
        if e.kind in ("unwind", "rewind", "driven_roller"):
            t_in, t_out = op.element_tensions(i)
            op.torque[e.name] = holding_motor_torque(e, omega[i], t_in, t_out, web, J[i])
    return op


def speed_pi_start(tau_hold, J, K_ref, zeta, w_ld, feedforward, R, T_in, T_out, b_ff, omega):
    """Integrator I0 of the speed PI that outputs ``tau_hold`` at zero speed error.

    tau = ff + K_p (e + w_ld I) with e = 0, so I0 = (tau_hold - ff)/(K_p w_ld). ``T_in``/``T_out``
    are the tensions the feed-forward sees: the span tensions (feed-forward from the measured
    tensions) or the zones' set points (from the references; they differ from the span
    tensions by the idle rollers' friction, and the integrator covers that difference).
    The acceleration feed-forward is 0 on a steady line, and a current-loop lag starts at
    ``tau_hold`` (its own start value), so neither changes I0."""
    K_p, w_default = speed_gains(J, K_ref, zeta)
    w = w_ld if w_ld else w_default
    ff = R * (T_in - T_out) + b_ff * omega if feedforward else 0.0
    if K_p * w == 0.0:
        return 0.0
    return (tau_hold - ff) / (K_p * w)


def load_cell_reading(T_in, T_out, angle_in, angle_out):
    """Steady load-cell reading for the tensions around its roller."""
    return measured_tension(T_in, T_out, *wrap_weights(angle_in, angle_out))


def is_finite(op):
    return all(math.isfinite(x) for x in (*op.T, *op.v, *op.omega))
