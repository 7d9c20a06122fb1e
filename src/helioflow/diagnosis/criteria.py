"""What the diagnosis counts as a finding, and what it compares a remaining error with: the
thresholds a candidate's cut of the held-out error must pass, the significance of its fitted values,
and the floor below which a residual is explained down to the noise (diagnosis/diagnose.py's module
doc; their error rates: docs/diagnosis.md, "Error rates")."""

from __future__ import annotations

import numpy as np

THRESHOLD = 0.25  # relative held-out error reduction a candidate needs to count
ABSOLUTE_FLOOR = 0.002  # ... and absolute reduction of the misplaced flux fraction
EXPLAINED = 2.0  # a held-out error up to this many times `compared_floor` is explained down to the noise (what a
#                  fitted model leaves beyond it: the nothing-hidden folders of scripts/experiments/error_rates.py
#                  0.97-1.45 x, the independent cases with every hidden effect named up to 1.96 x)
NUMERICAL_FLOOR = 0.001  # misplaced flux below which a noise floor is not resolved by the diagnosis' fits
MODEL_RESOLUTION = 0.002  # misplaced flux between the model's spot and an independent Monte Carlo of the same physics
#                           on nearly noise-free 8-bit images (0.0020-0.0027, scripts/experiments/model_resolution.py):
#                           the model's own mismatch, which no candidate removes; `compared_floor` adds it to the
#                           noise's
PARTLY = 0.1  # a best candidate that cuts an unexplained residual by this much is named as explaining part of it
SIGNIFICANCE = 1e-3  # a candidate's fitted parameters depart from their do-nothing values at this level (Wald test)


def compared_floor(noise_floor, measured: bool):
    """What a model without a missing effect leaves (misplaced flux; a float or an array per image):
    on `measured` images (not helioflow's own traces) the noise's floor and the model's own
    resolution, MODEL_RESOLUTION, in quadrature (a systematic difference d and noise e leave a pixel
    E|d + e|, which goes from E|e| at d = 0 to |d| at d >> e as sqrt(d^2 + E|e|^2) does; on noise
    blurred over pixels the noise's floor falls to the model's resolution: docs/diagnosis.md,
    "Error rates"); on helioflow's own traces the noise's floor. At least NUMERICAL_FLOOR."""
    return np.maximum(np.hypot(noise_floor, MODEL_RESOLUTION if measured else 0.0), NUMERICAL_FLOOR)


def is_meaningful(before: float, after: float) -> bool:
    """Does going from held-out error `before` to `after` count as a finding (diagnosis/diagnose.py's module doc)?"""
    return after <= (1.0 - THRESHOLD) * before and before - after >= ABSOLUTE_FLOOR
