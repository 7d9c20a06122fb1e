"""The noise floor (diagnosis/noise.py): the noise measured in images without a model, and the error
that noise alone leaves, against images whose noise is known."""

import numpy as np
import pytest
import torch
from support.noise_images import CAMERAS, blurred, counted, eight_bit, spots

from helioflow.data.noise import measure_noise, residual_noise
from helioflow.diagnosis.noise import measured_noise, noise_floor
from helioflow.physics.scene import misplaced_flux


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


@pytest.mark.parametrize("camera", CAMERAS)
def test_the_floor_of_noise_that_is_not_white_is_the_error_a_perfect_model_gets(camera):
    """Photon noise blurred after the counting, resampled, quantised: the floor read in the residual
    of the true spots (as the camera resamples them, not quantised) is within 20 % of the error those
    spots get, on each of three seeds (over 20 seeds: docs/diagnosis.md; the images' own operator,
    Immerkaer's, reads 0.3-0.7 of it on these cases, 0.07 without quantisation)."""
    resample, quantise = CAMERAS[camera]
    for seed in range(3):
        truth = spots(12, 20 + seed)
        perfect = resample(truth)
        measured = resample(counted(truth, 300.0, 40 + seed))
        measured = eight_bit(measured) if quantise else measured
        actual = misplaced_flux(perfect, measured).numpy().mean()
        floor, _ = noise_floor(perfect, measured, measured_noise(perfect, measured))
        assert floor.mean() == pytest.approx(actual, rel=0.2), (camera, seed, floor.mean(), actual)


def test_the_correlation_of_blurred_noise_is_measured():
    truth = spots(12, 7)
    noise = measured_noise(blurred(truth, 1.0), blurred(counted(truth, 300.0, 8), 1.0))
    assert noise.correlation_px == pytest.approx(1.0, rel=0.25)
    assert noise.white_share < 0.1  # float images: no quantisation
    white = measured_noise(truth, counted(truth, 300.0, 9))
    assert white.correlation_px == 0.0 and white.white_share == 1.0


def test_a_model_that_misses_a_feature_does_not_raise_the_floor_of_correlated_noise():
    """The residual's mismatch lies at the spot's frequencies: it does not pass for noise."""
    truth = blurred(spots(12, 10), 1.0)
    measured = eight_bit(blurred(counted(spots(12, 10), 300.0, 11), 1.0))
    shifted = torch.roll(truth, 2, dims=-1)
    right, _ = noise_floor(truth, measured, measured_noise(truth, measured))
    wrong, _ = noise_floor(shifted, measured, measured_noise(shifted, measured))
    assert misplaced_flux(shifted, measured).mean() > 10 * wrong.mean()
    assert wrong.mean() <= 1.1 * right.mean()


def test_noise_free_images_have_no_residual_noise():
    truth = spots(6, 12)
    assert residual_noise(truth, truth) is None
