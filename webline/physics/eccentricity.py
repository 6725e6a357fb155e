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


def sine_cosine_form(C, psi):
    """(a, b) with C_j sin(j theta + psi_j) = a_j sin(j theta) + b_j cos(j theta):
    a_j = C_j cos(psi_j), b_j = C_j sin(psi_j). Computed once per series, so that
    :func:`length_terms` needs no trigonometry of the phases."""
    return ([c * math.cos(ph) for c, ph in zip(C, psi)],
            [c * math.sin(ph) for c, ph in zip(C, psi)])


def length_terms(theta, omega, a, b):
    """(Delta L, d(Delta L)/dt) of {28}-{29} from the series in sine-cosine form
    (:func:`sine_cosine_form`): the same values as :func:`length_offset` and
    :func:`length_rate`, to rounding. sin(theta) and cos(theta) are taken once and the
    higher orders follow by angle addition: the fast engine evaluates this at every
    stage of every step, and two trigonometric calls per order per sum cost more than
    the rest of an eccentric line's right-hand side (a 60 s run with 18 orders on three
    eccentric elements: 0.52-0.87 s against 0.14 s for the round line)."""
    s1 = math.sin(theta)
    c1 = math.cos(theta)
    s, c = s1, c1
    off = 0.0
    rate = 0.0
    for j in range(len(a)):
        if j > 0:
            s, c = s * c1 + c * s1, c * c1 - s * s1
        off += a[j] * s + b[j] * c
        rate += (j + 1) * (a[j] * c - b[j] * s)
    return off, omega * rate


def fundamental_frequency(v, R):
    """f = omega/(2 pi) with omega = v/R, {30}-{31} in SI (v in m/s, R in m)."""
    return v / (2.0 * math.pi * R)
