"""The residual's correlation over pixels (models/correlated.py): the variance that smooth noise
gives a fitted parameter, against the scatter of many draws of that noise."""

import numpy as np
import pytest
import torch

from helioflow.data.noise import _spectral_gain, correlate
from helioflow.models.correlated import correlated_gram, ring_spectrum

N, H, W = 8, 32, 32


def _columns() -> torch.Tensor:
    """(N*H*W, 3) Jacobian columns of a Gaussian spot of 3 px: its shift in x and y, its width."""
    y, x = torch.meshgrid(torch.arange(H) - 15.5, torch.arange(W) - 15.5, indexing="ij")
    spot = torch.exp(-(x**2 + y**2) / 18.0)
    columns = [-x / 9 * spot, -y / 9 * spot, ((x**2 + y**2) / 27 - 2 / 3) * spot]
    return torch.stack([c.expand(N, H, W).flatten() for c in columns], 1).float()


def _noise(correlation_px: float, generator: torch.Generator) -> torch.Tensor:
    white = torch.randn(N, H, W, generator=generator, dtype=torch.float64)
    return correlate(white, correlation_px) if correlation_px else white


@pytest.mark.parametrize("correlation_px", [0.0, 1.0, 2.0])
def test_the_variance_of_a_fitted_shift_is_that_of_many_draws_of_the_noise(correlation_px):
    """J^T e over 1500 draws of noise blurred over b px scatters as the Gram matrix with the
    noise's own spectrum says, and as the one read in a single draw's residual says (within 20 %);
    the white estimate J^T J holds for white noise only: blurred over 1-2 px it is 8-25 times low."""
    jacobian = _columns()
    generator = torch.Generator().manual_seed(3)
    draws = np.array([(jacobian.double().T @ _noise(correlation_px, generator).flatten()).numpy()
                      for _ in range(1500)])
    scatter = np.diag(np.cov(draws.T))
    gain = _spectral_gain(H, W, correlation_px)
    exact = correlated_gram(jacobian, (N, H, W), torch.as_tensor(gain / gain.mean()))
    read = correlated_gram(jacobian, (N, H, W), ring_spectrum(_noise(correlation_px, generator)))
    white = np.diag((jacobian.double().T @ jacobian.double()).numpy())
    np.testing.assert_allclose(np.diag(exact), scatter, rtol=0.12)
    np.testing.assert_allclose(np.diag(read), scatter, rtol=0.2)
    if correlation_px == 0.0:
        np.testing.assert_allclose(white, scatter, rtol=0.12)
    else:
        assert np.all(white < scatter / 8)


def test_the_spectrum_keeps_the_residuals_mean_square_or_the_one_asked_for():
    """Parseval: the ring spectrum's mean is the residual's mean square; `unit_mean` rescales it."""
    residual = 3.0 * _noise(1.5, torch.Generator().manual_seed(0))
    spectrum = ring_spectrum(residual)
    assert float(spectrum.mean()) == pytest.approx(float((residual**2).mean()), rel=1e-9)
    assert float(ring_spectrum(residual, unit_mean=2.0).mean()) == pytest.approx(2.0, rel=1e-9)


def test_a_flat_spectrum_gives_the_plain_gram_matrix():
    jacobian = torch.randn(N * H * W, 70, generator=torch.Generator().manual_seed(1))  # more columns than a chunk
    gram = correlated_gram(jacobian, (N, H, W), torch.ones(H, W, dtype=torch.float64))
    np.testing.assert_allclose(gram, (jacobian.double().T @ jacobian.double()).numpy(), rtol=1e-5, atol=1e-2)
