"""Images whose noise is known, for the noise-floor tests (tests/diagnosis/test_noise.py) and
scripts/experiments/noise_floor.py: smooth spots, photon counting, and the cameras that carry the counted
image to the file (blur, rectification, 8 bits)."""

import numpy as np
import torch
from scipy.ndimage import gaussian_filter, map_coordinates

SIDE = 64


def spots(n: int, seed: int) -> torch.Tensor:
    """(n, 64, 64) smooth spots of peak 1 (Gaussians of 3-6 px at random places), float64."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[:SIDE, :SIDE] + 0.5
    images = []
    for _ in range(n):
        cx, cy, sx, sy = rng.uniform(20, 44), rng.uniform(20, 44), rng.uniform(3, 6), rng.uniform(3, 6)
        images.append(np.exp(-((x - cx) ** 2) / (2 * sx**2) - (y - cy) ** 2 / (2 * sy**2)))
    return torch.as_tensor(np.stack(images))


def counted(truth: torch.Tensor, photons_per_peak: float, seed: int) -> torch.Tensor:
    """truth (N, H, W, peak 1) as photon counts of `photons_per_peak` at the peak, back in its units:
    Gaussian noise of variance truth / photons_per_peak (photon noise, 0 where it is dark)."""
    g = torch.Generator().manual_seed(seed)
    return truth + (truth / photons_per_peak).sqrt() * torch.randn(truth.shape, generator=g, dtype=truth.dtype)


def blurred(images: torch.Tensor, sigma_px: float) -> torch.Tensor:
    """images (N, H, W) blurred by a Gaussian of `sigma_px`, with the same code path as nothing here:
    scipy's filter, not the noise model's FFT."""
    return torch.as_tensor(np.stack([gaussian_filter(i, sigma_px, mode="constant") for i in images.numpy()]))


def rectified(images: torch.Tensor) -> torch.Tensor:
    """images (N, H, W) resampled as a rectification does: bilinear interpolation on a grid turned by
    17 mrad, stretched by 1.3 % and shifted by a fraction of a pixel."""
    side = images.shape[-1]
    y, x = np.mgrid[:side, :side].astype(float) - side / 2
    a, s = 0.017, 1.013
    rows = s * (np.cos(a) * y - np.sin(a) * x) + side / 2 + 0.37
    cols = s * (np.sin(a) * y + np.cos(a) * x) + side / 2 + 0.21
    return torch.as_tensor(np.stack([map_coordinates(i, [rows, cols], order=1) for i in images.numpy()]))


def eight_bit(images: torch.Tensor) -> torch.Tensor:
    """Each image divided by its own peak and rounded to 255 grey levels (a PNG)."""
    peak = images.amax((-2, -1), keepdim=True)
    return torch.round(images.clamp_min(0) / peak * 255) / 255 * peak


CAMERAS = {  # noise that is not white: how the counted image reaches the file (resampling, then bits)
    "white, 8-bit": (lambda x: x, True),
    "blurred 0.5 px, 8-bit": (lambda x: blurred(x, 0.5), True),
    "blurred 1 px, 8-bit": (lambda x: blurred(x, 1.0), True),
    "blurred 1.5 px, 8-bit": (lambda x: blurred(x, 1.5), True),
    "rectified, 8-bit": (rectified, True),
    "blurred 1 px, rectified, float": (lambda x: rectified(blurred(x, 1.0)), False),
}
