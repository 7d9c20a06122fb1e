"""The noise of measured images, measured in the images themselves (no model involved, so that a
real residual cannot pass for noise).

Every pixel's noise-only response to the 3 x 3 operator [1 -2 1]^T [1 -2 1] (Immerkær 1996, "Fast
noise variance estimation"), which cancels any signal that is locally a plane or a quadric and
multiplies white noise's variance by 36. Its variance is measured per level of the local (3 x 3
mean) signal, so that noise growing with the signal (photon and Monte Carlo noise, speckle) is
measured as such, and 8-bit quantisation adds its own share wherever the image is not exactly 0.
Robust per level (median of squares: the spot's edges, where the operator sees some signal, do not
inflate it), and piecewise linear between the levels (`NoiseModel`).

What it does not count: noise correlated over several pixels (a blur after the counting, a
resampled or rectified image) is underestimated by a pixel-scale operator, and under 8-bit
quantisation it is not seen at all: noise blurred over one pixel of a 64 x 64 image keeps 1/100 of
its variance in the operator's response, less than the quantisation's. `residual_noise` measures
that noise where it is: in the residual of a model, at the spatial frequencies its spot lacks.
What it counts too much: the operator sees a spot's own
fourth derivative, about peak / (6 sigma^4) for a Gaussian spot of sigma pixels (a floor of ~1e-4
misplaced flux for noise-free spots of 3 px); read in a residual (measured - predicted, with the
prediction's levels: `measure_noise(residual, signal=prediction)`) the spot is gone.

**Correlated noise** (`residual_noise`): the residual measured - predicted holds the noise and
whatever the model misses. What it misses is a part of the spot, so its power lies at the spatial
frequencies the predicted spot has; at the frequencies where the prediction's power is below
BAND_SHARE of the residual's, the residual is noise. There its mean periodogram is fitted by the
spectrum of white noise plus Gaussian-correlated noise, W + C exp(-4 pi^2 b^2 |f|^2) (b: the
correlation length, px; W: the white share, e.g. quantisation), and the fitted spectrum summed
over every frequency is the noise's variance (Parseval): its low frequencies, where the spot
hides it, are the model's extrapolation. How it is spread over the image: the white share as the
pixel-scale operator reads it in the residual per level of the prediction (a smooth mismatch does
not reach it), the correlated share in proportion to the signal (photon noise counted, then
blurred). Read in the whole residual instead, a mismatch spreads the variance to the levels where
it lies and raises the floor (a soiled mirror's residual called explained: 1.9 x, not 2.1 x).

Used by the diagnosis' noise floor (diagnosis/noise.py) and the fits' uncertainty
(models/uncertainty.py).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
from scipy.optimize import minimize
from scipy.stats import chi2
from torch import Tensor

OPERATOR = torch.tensor([[1.0, -2.0, 1.0], [-2.0, 4.0, -2.0], [1.0, -2.0, 1.0]])  # gain 36 on white noise
LEVEL_BINS = 16  # equal-count bins of the local signal level (pixels above zero)
MEDIAN_CHI2_1 = 0.45494  # median of a chi-square variable with one degree of freedom
ZERO = 1e-12  # a level at or below this (relative to the images' peak) is an exactly dark pixel
BAND_SHARE = 0.01  # frequencies where the prediction holds less than this share of the residual's power are noise
CORRELATION_PX = np.geomspace(0.2, 6.0, 48)  # correlation lengths tried (px) beside white noise
SPECTRUM_SIGNIFICANCE = 1e-3  # a correlated share is read in the spectrum only beyond this chance of a white one's
MIN_BAND = 16  # fewer noise-dominated frequencies than this: the residual's noise is not measured


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
        correlation_px: b, the standard deviation (px) of the Gaussian kernel that correlates the
            noise's correlated share (0: white noise).
        white_share: the share of the variance that is white (quantisation, a sensor's own noise);
            the rest is correlated over b.
    """

    levels: np.ndarray
    variance: np.ndarray
    slope: float
    correlation_px: float = 0.0
    white_share: float = 1.0

    def std(self, images: Tensor) -> Tensor:
        """Noise standard deviation (same shape and units as `images`) at each pixel's level."""
        x = images.detach().double().cpu().numpy()
        top = self.levels[-1]
        variance = np.where(x <= top, np.interp(x, self.levels, self.variance),
                            self.variance[-1] + self.slope * (x - top))
        return torch.as_tensor(np.sqrt(np.maximum(variance, 0.0)), dtype=images.dtype, device=images.device)

    def draw(self, images: Tensor, generator: torch.Generator) -> Tensor:
        """A draw of this noise (same shape and dtype as `images` (N, H, W)) at each pixel's level:
        its white share white, the rest white noise blurred over `correlation_px` and rescaled to
        unit variance, both times the pixel's standard deviation."""
        std = self.std(images)
        white = torch.randn(images.shape, generator=generator, dtype=images.dtype)
        if self.white_share >= 1.0 or self.correlation_px <= 0.0:
            return std * white
        correlated = correlate(torch.randn(images.shape, generator=generator, dtype=images.dtype),
                               self.correlation_px)
        return std * (math.sqrt(self.white_share) * white + math.sqrt(1.0 - self.white_share) * correlated)

    def as_json(self) -> dict:
        """The noise as JSON: levels, std per level, variance slope above them, correlation, white share."""
        return {"levels": [float(f"{x:.6g}") for x in self.levels],
                "std": [float(f"{x:.6g}") for x in np.sqrt(self.variance)],
                "variance_slope_above": float(f"{self.slope:.6g}"),
                "correlation_px": float(f"{self.correlation_px:.4g}"), "white_share": float(f"{self.white_share:.4g}")}


def correlate(white: Tensor, correlation_px: float) -> Tensor:
    """White noise (N, H, W) of unit variance blurred by a Gaussian of `correlation_px` (px) and
    rescaled to unit variance again (circular: the kernel's spectrum applied by FFT)."""
    h, w = white.shape[-2:]
    gain = _spectral_gain(h, w, correlation_px)  # (H, W) the kernel's squared spectrum
    amplitude = torch.as_tensor(np.sqrt(gain / gain.mean()), dtype=white.dtype)
    return torch.fft.ifft2(torch.fft.fft2(white) * amplitude).real


def _spectral_gain(h: int, w: int, correlation_px: float) -> np.ndarray:
    """(H, W) |K(f)|^2 of a Gaussian kernel of std `correlation_px` on the FFT grid."""
    fy, fx = np.fft.fftfreq(h)[:, None], np.fft.fftfreq(w)[None, :]
    return np.exp(-4.0 * math.pi**2 * correlation_px**2 * (fx**2 + fy**2))


def residual_noise(measured: Tensor, predicted: Tensor) -> NoiseModel | None:
    """The noise of `measured` (N, H, W), white or correlated, read in its residual against
    `predicted` (N, H, W, same units) at the frequencies the predicted spots lack (module doc);
    None when fewer than MIN_BAND frequencies are free of them (noise-free images, or noise too
    weak to stand above the spot anywhere)."""
    meas, pred = measured.detach().double().cpu(), predicted.detach().double().cpu()
    residual = meas - pred
    h, w = residual.shape[-2:]
    power = (torch.fft.fft2(residual).abs() ** 2).mean(0).numpy() / (h * w)  # (H, W) mean periodogram
    spot = (torch.fft.fft2(pred).abs() ** 2).mean(0).numpy() / (h * w)
    band = (spot < BAND_SHARE * power) & (power > 0)
    band[0, 0] = False
    half = band & _half_plane(h, w)  # a real image's spectrum is symmetric: each frequency once
    if half.sum() < MIN_BAND:
        return None
    white, correlated, b = _fit_spectrum(power[half], {b: _spectral_gain(h, w, b)[half] for b in CORRELATION_PX},
                                         len(residual))
    spread = correlated * _spectral_gain(h, w, b).mean()  # the correlated share's mean pixel variance (Parseval)
    operator = measure_noise(residual, pred)  # the white share's shape over the levels: blind to smooth mismatch
    white_scale = white / max(float((operator.std(pred) ** 2).mean()), 1e-300)
    per_level = spread / max(float(pred.clamp_min(0).mean()), 1e-300)  # photon noise: grows with the signal
    variance = operator.variance * white_scale + per_level * np.clip(operator.levels, 0.0, None)
    return NoiseModel(operator.levels, variance, operator.slope * white_scale + per_level, b, white / (white + spread))


def _half_plane(h: int, w: int) -> np.ndarray:
    """(H, W) bool: one of each pair of FFT frequencies f, -f (both where f = -f)."""
    fy, fx = np.fft.fftfreq(h)[:, None], np.fft.fftfreq(w)[None, :]
    return (fx > 0) | ((fx == 0) & (fy >= 0)) | ((fx == -0.5) & (fy >= 0))


def _fit_spectrum(power: np.ndarray, gains: dict[float, np.ndarray], images: int) -> tuple[float, float, float]:
    """(W, C, b) of the spectrum W + C gains[b] that fits the mean periodogram `power` (K,) of
    `images` images best by Whittle's likelihood (each value a mean of `images` exponential
    variables), with C = 0 and b = 0 (white) unless the correlated share raises the log-likelihood
    beyond the chi^2 quantile of SPECTRUM_SIGNIFICANCE with 2 degrees of freedom (b and C): a
    white spectrum's scatter at the band's low edge must not extrapolate into noise at the spot's
    frequencies."""
    def nll(white: float, correlated: float, gain: np.ndarray) -> float:
        model = np.maximum(white + correlated * gain, 1e-9 * float(power.mean()))
        return float(images * np.sum(np.log(model) + power / model))

    white_only = float(power.mean())  # the white spectrum's maximum likelihood
    null = nll(white_only, 0.0, np.zeros_like(power))
    best = (null, white_only, 0.0, 0.0)
    for b, gain in gains.items():
        fit = minimize(lambda x: nll(x[0] * white_only, x[1] * white_only, gain), x0=[0.5, 0.5],
                       bounds=[(0.0, 1e3), (0.0, 1e9)], method="L-BFGS-B")
        if fit.fun < best[0]:
            best = (float(fit.fun), float(fit.x[0] * white_only), float(fit.x[1] * white_only), float(b))
    if 2.0 * (null - best[0]) < chi2.isf(SPECTRUM_SIGNIFICANCE, 2):
        return white_only, 0.0, 0.0
    return best[1], best[2], best[3]


def measure_noise(images: Tensor, signal: Tensor | None = None) -> NoiseModel:
    """The noise model of measured images (N, H, W) (module doc, step 1). `signal` (N, H, W): the
    levels are those of this signal (a model's prediction) and the operator reads `images` as they
    are (the residual images - prediction: no spot left whose curvature the operator could see)."""
    x = images.detach().double().cpu()[:, None]
    response = torch.nn.functional.conv2d(x, OPERATOR.double()[None, None]).flatten().numpy()
    source = x if signal is None else signal.detach().double().cpu()[:, None]
    level = torch.nn.functional.avg_pool2d(source, 3, stride=1).flatten().numpy()
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
