"""The residual's correlation over pixels, and what it does to a fit's covariance.

The sandwich covariance of an unweighted least-squares fit (models/uncertainty.py) is
H+ (J^T S J) H+, with S the covariance of the pixels' noise. Taken white, S = diag(s^2), and
J^T S J = sum_k s_k^2 J_k J_k^T. That holds for counting noise read pixel by pixel. Real
calibration images are not like that: the camera's optics, the rectification of the target's
image and the model's own mismatch leave a residual smooth over several pixels. A smooth residual
moves a fitted parameter whose Jacobian column is smooth too (a shift of the spot, a tilt of a
facet) as many white pixels cannot: where the residual is correlated over n pixels, a white
estimate of J^T S J is low by up to n times.

So the residual r, whitened by its pixels' noise std (z = r / s), is taken as a stationary field
per image: its correlation is the circulant R whose spectrum is the periodogram of z, averaged
over the images and over rings of equal |f| (isotropic; a ring holds enough frequencies for a
stable mean, the residual of one image does not), and J^T S J = (s J)^T R (s J), applied by FFT.
For white noise R is the identity (its spectrum flat) and the white estimate is recovered; for a
residual the model cannot explain, the Birge ratio's inflation (the residual's mean square over the
noise's, models/uncertainty.py) comes with it, at the frequencies where the residual lies.
What it does not see: the part of the residual that the fit itself has absorbed (at the optimum r
is orthogonal to J's columns: P of the pixels' degrees of freedom, all at the spot's frequencies;
not measured).
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor

CHUNK = 64  # Jacobian columns transformed at once (memory: CHUNK x N x H x W)


def ring_spectrum(residual: Tensor, unit_mean: float | None = None) -> Tensor:
    """(H, W) the correlation spectrum of a whitened residual (N, H, W): its periodogram
    |FFT|^2 / (H W) averaged over the images and over rings of equal rounded |f| (in cycles per
    image side). Its mean over the frequencies is the residual's mean square (Parseval); with
    `unit_mean` it is scaled to have that mean instead."""
    z = residual.detach().double().cpu()
    h, w = z.shape[-2:]
    power = (torch.fft.fft2(z).abs() ** 2).mean(0) / (h * w)  # (H, W)
    fy = torch.fft.fftfreq(h, dtype=torch.float64)[:, None] * h
    fx = torch.fft.fftfreq(w, dtype=torch.float64)[None, :] * w
    ring = torch.sqrt(fy**2 + fx**2).round().long().flatten()
    mean = torch.zeros(int(ring.max()) + 1, dtype=torch.float64).index_add_(0, ring, power.flatten())
    mean = mean / torch.bincount(ring).double()
    spectrum = mean[ring].reshape(h, w)
    if unit_mean is not None:
        spectrum = spectrum * unit_mean / spectrum.mean().clamp_min(1e-300)
    return spectrum


def correlated_gram(weighted: Tensor, shape: tuple[int, int, int], spectrum: Tensor) -> np.ndarray:
    """(Q, Q) A^T R A for A = `weighted` (N*H*W, Q): columns over the pixels of `shape` (N, H, W)
    images, R the circulant correlation of each image with `spectrum` (H, W) (`ring_spectrum`).
    With a flat spectrum of ones it is A^T A."""
    n, h, w = shape
    gain = spectrum.double()[:, : w // 2 + 1, None]  # rfft2's half: the spectrum is symmetric in f
    out = np.zeros((weighted.shape[1], weighted.shape[1]))
    for start in range(0, weighted.shape[1], CHUNK):
        block = weighted[:, start:start + CHUNK].double().reshape(n, h, w, -1)
        spread = torch.fft.irfft2(torch.fft.rfft2(block, dim=(1, 2)) * gain, s=(h, w), dim=(1, 2))
        columns = weighted.T @ spread.reshape(n * h * w, -1).to(weighted.dtype)
        out[:, start:start + block.shape[-1]] = columns.double().numpy()
    return 0.5 * (out + out.T)
