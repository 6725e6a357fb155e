"""Gauss-Newton of the time-domain fit reuses responses a step proved linear.

A fake line whose sensor is a known function of the Fourier coefficients (no
FMU, no engine): linear, one batch of responses is enough and the estimate is
the least-squares one; nonlinear, the first step's prediction misses and the
responses are simulated again.
"""
from types import SimpleNamespace

import numpy as np

from webline.diagnosis import regress

FS, FC, T = 200.0, 0.5, 20.0
F1 = 1.3      # the candidate's first order, Hz
H = 3         # orders of the candidate


class FakeFloor:
    def __init__(self):
        self.S = np.ones(64) * 1e-4


class FakeModel:
    """y(t) = sum_j Re(X_j) cos(j w t + p_j) - Im(X_j) sin(j w t + p_j) (+ nl |X_1|^2 cos(2 w t)),
    in newtons per metre of span length; counts the simulations asked for."""

    def __init__(self, t, nl):
        self.t, self.nl, self.count = t, nl, 0

    def output(self, X):
        w = 2 * np.pi * F1
        y = np.zeros_like(self.t)
        for j in range(1, H + 1):
            g = 4e4 / j    # a gain per order, N/m
            y += g * (X[j - 1].real * np.cos(j * w * self.t + 0.3 * j) - X[j - 1].imag * np.sin(j * w * self.t + 0.3 * j))
        y += self.nl * abs(X[0]) ** 2 * np.cos(2 * w * self.t)
        return y

    def simulate_many(self, jobs):
        self.count += len(jobs)
        return [SimpleNamespace(columns={"lc.T": self.output(doc)}) for _, doc, _ in jobs]


NOISE_N = 0.3   # white sensor noise, N rms


def _line(nl):
    t = np.arange(0.0, T, 1.0 / FS)
    model = FakeModel(t, nl)
    X_true = np.array([2e-4 * np.exp(0.7j), 8e-5 * np.exp(-1.1j), 3e-5 * np.exp(2.0j)])
    noise = np.random.default_rng(7).normal(0.0, NOISE_N, t.size)
    ctx = SimpleNamespace(run=None, name="run1", sensors=["lc.T"], fs=FS, fc=FC,
                          mask=(t > 2.0) & (t < T - 2.0), floors={"lc.T": FakeFloor()},
                          meas={"lc.T": model.output(X_true) + noise}, freq={"cand": F1})
    d = SimpleNamespace(opt=SimpleNamespace(harmonics=H, test_amplitude=1e-6), model=model,
                        with_effect=lambda doc, k, X: np.asarray(X, complex))
    cand = SimpleNamespace(element="idler", key="cand")
    return d, ctx, cand, X_true


def _fit(nl):
    d, ctx, cand, X_true = _line(nl)
    X0 = np.zeros(H, complex)
    Xs, sims, e, hist = regress.gauss_newton(d, X0, [cand], [X0], [[1, 2, 3]], [ctx], steps=3, drop_rounds=0)
    return d.model.count, Xs[0], X_true, hist, int(ctx.mask.sum())


def test_linear_line_needs_one_batch_of_responses():
    count, X, X_true, hist, n = _fit(0.0)
    # start (1) + responses (2 per order) + the step (1); the second step's reused
    # responses promise less than GAIN_MIN (only noise is left) and cost no simulation
    assert count == 1 + 2 * H + 1
    assert len(hist) == 2
    # least squares of a sinusoid's quadratures in white noise: each within 5 standard
    # errors, sigma sqrt(2 / n) / gain
    se = NOISE_N * np.sqrt(2.0 / n) / (4e4 / np.arange(1, H + 1))
    assert np.all(np.abs(X.real - X_true.real) < 5 * se)
    assert np.all(np.abs(X.imag - X_true.imag) < 5 * se)


def test_nonlinear_line_gets_fresh_responses():
    # the quadratic term moves the simulated fall of the first step far from the linear
    # prediction: the next step must simulate its responses again
    count, X, X_true, hist, _ = _fit(4e8)
    assert count >= 1 + 2 * (2 * H + 1)
    assert len(hist) >= 3 and hist[-1] < hist[1]
