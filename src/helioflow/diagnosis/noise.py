"""The noise floor: the error that noise alone would leave between a perfect model and these images.

A diagnosis that cannot tell noise from a residual cannot say "explained". Two steps:

1. **The noise, measured in the measurements** (data/noise.py, `NoiseModel`): its level and its
   spatial correlation read in the residual of the fitted model at the spatial frequencies the
   predicted spot lacks (`residual_noise`: what the model misses lies where the spot's own power
   is, so it does not pass for noise), or Immerkær's operator per level of the local signal in the
   images themselves (white noise only) where that reads more (`measured_noise`).
2. **A parametric bootstrap**: the fitted model's images (each scaled to its measurement's sum)
   get noise of that level-dependent variance and that correlation (clipped at 0, as a camera's
   pixels are), and are scored against the noise-free model images exactly as the measurements
   are (misplaced flux).
   The mean over draws is what noise alone leaves, per image; `floor` is its mean over the scored
   images, the same average as the held-out error.

What it does not count: the model's own approximations are not noise (and data/noise.py's limits).
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import Tensor

from helioflow.data.noise import NoiseModel, measure_noise, residual_noise
from helioflow.physics.scene import misplaced_flux

DRAWS = 16  # bootstrap draws per image


def measured_noise(model_images: Tensor, measured: Tensor) -> NoiseModel:
    """The measurements' (N, H, W) noise (module doc, step 1), read in their residual against the
    fitted model's images (N, H, W; any scale: each is scaled to its measurement's sum), or the
    images' own operator's where that reads more noise at the model's levels: both read low where
    they fail (the operator on any correlated noise, the residual on noise blurred over 3 px, whose
    power lies where the spot's does), neither reads high (docs/diagnosis.md)."""
    model = _scaled(model_images, measured)
    candidates = [n for n in (residual_noise(measured, model), measure_noise(measured)) if n is not None]
    return max(candidates, key=lambda n: float((n.std(model) ** 2).mean()))


def _scaled(model_images: Tensor, measured: Tensor) -> Tensor:
    """The model's images (N, H, W), float64 on the CPU, each scaled to its measurement's sum."""
    model = model_images.detach().double().cpu()
    total = model.sum((-2, -1), keepdim=True).clamp_min(1e-30)
    return model * measured.detach().double().cpu().sum((-2, -1), keepdim=True) / total


def noise_floor(model_images: Tensor, measured: Tensor, noise: NoiseModel, seed: int = 0) -> tuple[np.ndarray, float]:
    """((N,) misplaced flux that noise alone leaves on each image, the standard error of their mean).

    Args:
        model_images: (N, H, W) the fitted model's images (any scale).
        measured: (N, H, W) the measurements they are compared with (their sums set the scale).
        noise: the measurements' noise model.
    """
    model = _scaled(model_images, measured)
    floor = 0.0 if bool((measured >= 0).all()) else -math.inf  # a camera that reports no negative pixel clips
    generator = torch.Generator().manual_seed(seed)
    draws = torch.stack([misplaced_flux(model, (model + noise.draw(model, generator)).clamp_min(floor))
                         for _ in range(DRAWS)])  # (DRAWS, N)
    per_image = draws.mean(0).numpy()
    return per_image, float(draws.mean(1).std() / np.sqrt(DRAWS))
