"""The noise of measured images, measured in the images themselves (no model involved, so that a
real residual cannot pass for noise).

Every pixel's noise-only response to the 3 x 3 operator [1 -2 1]^T [1 -2 1] (Immerkær 1996, "Fast
noise variance estimation"), which cancels any signal that is locally a plane or a quadric and
multiplies white noise's variance by 36. Its variance is measured per level of the local (3 x 3
mean) signal, so that noise growing with the signal (photon and Monte Carlo noise, speckle) is
measured as such, and 8-bit quantisation adds its own share wherever the image is not exactly 0.
Robust per level (median of squares: the spot's edges, where the operator sees some signal, do not
inflate it), and piecewise linear between the levels (`NoiseModel`).

What it does not count: noise correlated over several pixels (a blur after the noise) is
underestimated by a pixel-scale operator. What it counts too much: the operator sees a spot's own
fourth derivative, about peak / (6 sigma^4) for a Gaussian spot of sigma pixels (a floor of ~1e-4
misplaced flux for noise-free spots of 3 px); read in a residual (measured - predicted, with the
prediction's levels: `measure_noise(residual, signal=prediction)`) the spot is gone.

Used by the diagnosis' noise floor (diagnosis/noise.py) and the fits' uncertainty
(models/uncertainty.py).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

OPERATOR = torch.tensor([[1.0, -2.0, 1.0], [-2.0, 4.0, -2.0], [1.0, -2.0, 1.0]])  # gain 36 on white noise
LEVEL_BINS = 16  # equal-count bins of the local signal level (pixels above zero)
MEDIAN_CHI2_1 = 0.45494  # median of a chi-square variable with one degree of freedom
ZERO = 1e-12  # a level at or below this (relative to the images' peak) is an exactly dark pixel


@dataclass(frozen=True)
class NoiseModel:
    """Noise variance of a pixel as a function of its signal level, measured at `levels`:
    piecewise linear in between, constant below the lowest, and above the highest along the
    line through the upper half of the levels (the brightest pixels are few: they get the trend
    of the many). Measured, not assumed: a noise-free camera background at a constant level has
    none, photon and Monte Carlo noise grow with the signal, quantisation adds a constant.

    Attributes:
        levels: (K,) signal levels (image units), increasing.
        variance: (K,) noise variance measured at each (image units squared).
        slope: variance per unit level above the highest level (>= 0).
    """

    levels: np.ndarray
    variance: np.ndarray
    slope: float

    def std(self, images: Tensor) -> Tensor:
        """Noise standard deviation (same shape and units as `images`) at each pixel's level."""
        x = images.detach().double().cpu().numpy()
        top = self.levels[-1]
        variance = np.where(x <= top, np.interp(x, self.levels, self.variance),
                            self.variance[-1] + self.slope * (x - top))
        return torch.as_tensor(np.sqrt(np.maximum(variance, 0.0)), dtype=images.dtype, device=images.device)

    def as_json(self) -> dict:
        return {"levels": [float(f"{x:.6g}") for x in self.levels],
                "std": [float(f"{x:.6g}") for x in np.sqrt(self.variance)],
                "variance_slope_above": float(f"{self.slope:.6g}")}


def measure_noise(images: Tensor, signal: Tensor | None = None) -> NoiseModel:
    """The noise model of measured images (N, H, W) (module doc, step 1). `signal` (N, H, W): the
    levels are those of this signal (a model's prediction) and the operator reads `images` as they
    are (the residual images - prediction: no spot left whose curvature the operator could see)."""
    x = images.detach().double().cpu()[:, None]
    response = torch.nn.functional.conv2d(x, OPERATOR.double()[None, None]).flatten().numpy()
    levels = x if signal is None else signal.detach().double().cpu()[:, None]
    level = torch.nn.functional.avg_pool2d(levels, 3, stride=1).flatten().numpy()
    dark = level <= ZERO * max(float(x.abs().max()), 1e-30)
    groups = [np.flatnonzero(dark)] if dark.any() else []
    lit = np.flatnonzero(~dark)
    if len(lit):
        order = lit[np.argsort(level[lit])]
        groups += np.array_split(order, min(LEVEL_BINS, len(order)))
    levels = np.array([float(np.median(level[g])) for g in groups])
    variance = np.array([_robust_variance(response[g]) for g in groups])
    levels, unique = np.unique(levels, return_index=True)  # equal levels (a constant background): one point
    variance = variance[unique]
    upper = slice(len(levels) // 2, None)
    slope = float(np.polyfit(levels[upper], variance[upper], 1)[0]) if len(levels) >= 4 else 0.0
    return NoiseModel(levels, variance, max(slope, 0.0))


def _robust_variance(response: np.ndarray) -> float:
    """White-noise variance behind the operator's responses (0 for none)."""
    if not len(response):
        return 0.0
    return float(np.median(response**2) / MEDIAN_CHI2_1 / 36.0)
