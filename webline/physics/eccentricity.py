"""Span-length variation from an eccentric roller or out-of-round roll, {27}-{32}.

The paper writes L(t) = sum_j C_j sin(2 pi j f t + psi_j) with f = omega/(2 pi)
({28}, {31}). With the element's angle theta = integral of omega dt in place
of 2 pi f t, the same series follows a speed that changes and a radius that
shrinks: the harmonics stay locked to the element, as order tracking assumes.
"""
import math


def length_offset(theta, C, psi):
    """Delta L(theta) = sum_j C_j sin(j theta + psi_j), {28}. C in m, psi in rad."""
    s = 0.0
    for j in range(len(C)):
        if C[j] != 0.0:
            s += C[j] * math.sin((j + 1) * theta + psi[j])
    return s


def length_rate(theta, omega, C, psi):
    """d(Delta L)/dt = sum_j j omega C_j cos(j theta + psi_j), {29} with 2 pi f = omega."""
    s = 0.0
    for j in range(len(C)):
        if C[j] != 0.0:
            s += (j + 1) * C[j] * math.cos((j + 1) * theta + psi[j])
    return omega * s


def fundamental_frequency(v, R):
    """f = omega/(2 pi) with omega = v/R, {30}-{31} in SI (v in m/s, R in m)."""
    return v / (2.0 * math.pi * R)
