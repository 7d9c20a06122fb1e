"""The noise floor (diagnosis/noise.py): the noise measured in images without a model, and the error
that noise alone leaves, against images whose noise is known."""

import numpy as np
import pytest
import torch

from helioflow.data.noise import measure_noise
from helioflow.diagnosis.noise import noise_floor
from helioflow.scoring.metrics import misplaced_flux

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


def noisy(truth: torch.Tensor, dark_var: float, per_signal_var: float, seed: int) -> torch.Tensor:
    """truth + Gaussian noise of variance dark_var + per_signal_var * signal (a background-subtracted
    camera: negative pixels kept)."""
    g = torch.Generator().manual_seed(seed)
    std = (dark_var + per_signal_var * truth).sqrt()
    return truth + std * torch.randn(truth.shape, generator=g, dtype=truth.dtype)


def test_the_noise_is_measured_at_every_signal_level_without_a_model():
    truth = spots(24, 0)
    measured = noisy(truth, 1e-4, 1e-3, 1)
    noise = measure_noise(measured)
    for level in (0.1, 0.3, 0.6, 0.9):  # photon-like noise: it grows with the signal
        expected = np.sqrt(1e-4 + 1e-3 * level)
        got = float(noise.std(torch.tensor([level], dtype=torch.float64)))
        assert got == pytest.approx(expected, rel=0.15), (level, got, expected)


def test_the_floor_is_the_error_that_noise_leaves_on_a_perfect_model():
    truth = spots(24, 2)
    measured = noisy(truth, 4e-5, 1e-3, 3)
    floor, standard_error = noise_floor(truth, measured, measure_noise(measured))
    actual = misplaced_flux(truth, measured).numpy()
    assert floor.mean() == pytest.approx(actual.mean(), rel=0.1)
    assert np.corrcoef(floor, actual)[0, 1] > 0.8  # per image too
    assert standard_error < 0.02 * floor.mean()


def test_the_floor_counts_8_bit_quantisation_and_no_noise_means_no_floor():
    truth = spots(16, 4)
    quantised = torch.round(truth * 255) / 255
    floor, _ = noise_floor(truth, quantised, measure_noise(quantised))
    actual = misplaced_flux(truth, quantised).numpy().mean()
    assert floor.mean() == pytest.approx(actual, rel=0.5)  # rounding is deterministic, the bootstrap's noise is not
    assert noise_floor(truth, truth, measure_noise(truth))[0].max() < 0.1 * actual  # noise-free: ~no floor


def test_a_residual_is_not_taken_for_noise():
    """A model that misses a real feature: the floor stays that of the noise, far below the error."""
    truth = spots(24, 5)
    measured = noisy(truth, 1e-6, 1e-3, 6)
    shifted = torch.roll(truth, 2, dims=-1)  # the model puts the spots 2 px off
    floor, _ = noise_floor(shifted, measured, measure_noise(measured))
    assert misplaced_flux(shifted, measured).mean() > 3 * floor.mean()
    assert floor.mean() == pytest.approx(noise_floor(truth, measured, measure_noise(measured))[0].mean(), rel=0.1)
