"""A family fitted beside a taken family's near line gets back what that line took.

Independent seed-42 c12: an eccentric roller19 (1.5 in, order 1 at 5.22 Hz at
246 ft/min) beside an eccentric S-wrap leader (6.05 in, order 4 at 5.18 Hz). On a
15 s steady window the two lines are 0.65 resolutions apart, which a joint fit
separates; the leader, taken first and fitted alone, took part of the roller's
line, and the roller was then judged on what was left (log10 p -5.7, missed).
On 3.75 s coherence segments the lines are 0.16 resolutions apart (not separable),
on 7.5 s ones 0.33 (separable): the roller's order 1 is read on the longer ones.
The arithmetic here is exact (noise-free tones), so the tolerances are those of a
least-squares fit of pure tones.
"""
import math
from types import SimpleNamespace

import numpy as np

from webline.diagnosis import estimate as est
from webline.diagnosis import pipeline as P

FS = 500.0
F_SW = 1.2943                     # the leader's speed, Hz (6.05 in at 246 ft/min)
F_ROLLER = 5.2204                 # roller19's (1.5 in)


def _run(t, theta, floor=1e-6):
    return SimpleNamespace(t=t, fs=FS, fc=0.1, mask=np.ones(len(t), bool), sensors=["lc.T"],
                           floors={"lc.T": lambda f: np.full(np.shape(f), floor)},
                           theta=theta, freq={k: est.mean_frequency(t, th, np.arange(len(t)))
                                              for k, th in theta.items()})


def _diagnosis(harmonics=1):
    d = P.Diagnosis.__new__(P.Diagnosis)
    d.opt = P.Options(harmonics=harmonics)
    return d


def test_near_lines_are_the_taken_lines_a_piece_can_separate():
    t = np.arange(0.0, 15.0, 1 / FS)
    c = _run(t, {})
    idx = np.arange(len(t))
    roller = 2 * math.pi * F_ROLLER * t
    leader = 2 * math.pi * F_SW * t
    # order 4 of the leader: 0.043 Hz x 15 s = 0.65 resolutions; its order 3 sits 1.3 Hz
    # away (19 resolutions), orthogonal enough to leave alone
    assert P._near_lines(c, roller, [1], [(leader, [1, 2, 3, 4, 5, 6])], idx) == [(leader, [4])]
    same = 2 * math.pi * (4 * F_SW + 0.2 / 15.0) * t     # a fifth of a resolution: not separable
    assert P._near_lines(c, same, [1], [(leader, [1, 2, 3, 4, 5, 6])], idx) == []
    assert P._near_lines(c, roller, [1], [], idx) == []


def test_a_family_taken_second_recovers_its_line_from_the_first():
    t = np.arange(0.0, 15.0, 1 / FS)
    roller = 2 * math.pi * F_ROLLER * t
    leader = 2 * math.pi * F_SW * t
    a_roller = 0.30
    y = a_roller * np.sin(roller + 0.7) + 0.8 * np.sin(4 * leader + 2.0)
    # the leader taken first, its order 4 fitted alone, takes part of the roller's line
    Y4 = est.fit_harmonics(y, leader, [4])
    resid = y - est.harmonic_signal(leader, Y4, [4])
    c = _run(t, {"roller": roller, "leader": leader})
    d = _diagnosis(harmonics=1)
    alone = d._family_fit(c, "roller", {"lc.T": resid}, roller, beside=[])
    joint = d._family_fit(c, "roller", {"lc.T": resid}, roller, beside=[(leader, [4])])
    E_true = a_roller ** 2 / 2 * t[-1]
    assert alone["E"]["lc.T"] < 0.9 * E_true     # what the leader left
    assert abs(joint["E"]["lc.T"] / E_true - 1) < 0.01
    # taken, it leaves nothing: its own line and what the leader took of it both go
    left = resid - joint["signal"]["lc.T"]
    assert np.sqrt(np.mean(left ** 2)) < 1e-3 * a_roller


def test_an_order_too_close_on_short_segments_is_read_on_longer_ones():
    t = np.arange(0.0, 15.0, 1 / FS)
    roller = 2 * math.pi * F_ROLLER * t
    leader = 2 * math.pi * F_SW * t
    rng = np.random.default_rng(0)
    # order 1 steady beside the leader's order 4; order 2 a weak line whose phase jumps
    # segment by segment (what the roller's noise orders read)
    jumps = np.repeat(rng.uniform(0, 2 * math.pi, 4), len(t) // 4 + 1)[:len(t)]
    y = np.sin(roller + 0.7) + 0.8 * np.sin(4 * leader + 2.0) + 0.1 * np.cos(2 * roller + jumps)
    c = _run(t, {}, floor=0.0)
    c.floors = {}
    me = SimpleNamespace(_mask_pieces=P.Diagnosis._mask_pieces)
    fit = {"Y": {"lc.T": np.array([1.0, 0.1], complex)}}
    coh = P.Diagnosis._coherence(me, c, "roller", {"lc.T": y}, roller, [1, 2], fit, beside=[(leader, [4])])
    assert coh > 0.95
    # order 1 alone and free of the leader at K = 2 only
    segs4 = np.array_split(np.arange(len(t)), 4)
    segs2 = np.array_split(np.arange(len(t)), 2)
    assert P._apart(c, roller, [1], [(leader, [4])], segs4, 15.0 / 4).tolist() == [False]
    assert P._apart(c, roller, [1], [(leader, [4])], segs2, 15.0 / 2).tolist() == [True]


def test_the_noise_of_a_line_fitted_beside_another_is_inflated_as_the_joint_fit_says():
    # white noise of variance s2 alone: a line's quadrature coefficient has variance 2 s2 / N
    # alone (z = |Y|^2 T / (2 S) is Exp(1)), times the inflation beside a near line
    t = np.arange(0.0, 15.0, 1 / FS)
    roller = 2 * math.pi * F_ROLLER * t
    leader = 2 * math.pi * F_SW * t
    _, near = est.fit_harmonics_families(np.zeros_like(t), [(roller, [1]), (leader, [4])], inflation=True)
    _, far = est.fit_harmonics_families(np.zeros_like(t), [(roller, [1]), (leader, [1])], inflation=True)
    assert near[0] > 1.1                 # 0.65 resolutions: correlation about 0.45
    assert abs(far[0] - 1.0) < 1e-3      # 3.9 Hz apart, 59 resolutions
    rng = np.random.default_rng(1)
    z = []
    for _ in range(400):
        y = rng.standard_normal(len(t))
        Ys, infl = est.fit_harmonics_families(y, [(roller, [1]), (leader, [4])], inflation=True)
        # S = 1 / FS (two-sided white PSD of unit variance per sample, one-sided 2 / FS)
        z.append(est.harmonic_z(Ys[0], [F_ROLLER], lambda f: np.full(np.shape(f), 2.0 / FS), t[-1])[0] / infl[0])
    # Exp(1): mean 1, the mean of 400 has a standard error of 0.05
    assert abs(np.mean(z) - 1.0) < 0.15
