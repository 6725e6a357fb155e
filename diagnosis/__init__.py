"""Sim-to-real gap analysis for web lines: which rotating element causes a tension oscillation.

Model-free layer (GitHub issue #4), function-first like ``scipy.signal``:
arrays in, arrays (or small named tuples / dataclasses) out, no hidden state.

- :mod:`diagnosis.data`      measured records from CSV / MATLAB files, in SI, uniform time
- :mod:`diagnosis.orders`    shaft angle from tachometers, angle-domain resampling,
  order spectra, least-squares harmonic fits, model-angle refinement
- :mod:`diagnosis.spectra`   amplitude spectra, noise floor, significant peaks,
  tagging peaks to the harmonic families of named shafts
- :mod:`diagnosis.metrics`   model-vs-measurement error measures, residual splitting,
  speed windows, band energy
- :mod:`diagnosis.synthetic` synthetic tension records with known answers (tests, demos)
- :mod:`diagnosis.orders_cmd` the ``webline orders`` command

Conventions: SI inside (s, N, m/s, rad, rad/s); a shaft's harmonic j is written
``A_j sin(j theta + psi_j)`` as in the paper's {27}-{28} and
``webline.physics.eccentricity``.
"""
