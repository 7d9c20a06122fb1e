"""Image metrics against answers known in closed form."""

import numpy as np
import pytest
import torch

from helioflow.physics.scene import misplaced_flux
from helioflow.scoring.metrics import (
    PSNR_MAX_DB,
    centroid_error_mrad,
    centroid_px,
    flux_accuracy,
    image_metrics,
    psnr,
    ssim,
)


def gaussian(h=48, w=48, row=23.5, col=23.5, sigma=3.0):
    r, c = np.mgrid[0:h, 0:w]
    return np.exp(-((r - row) ** 2 + (c - col) ** 2) / (2 * sigma**2))


def test_psnr_identical_images_is_capped_finite():
    img = gaussian()
    assert psnr(img, img) == PSNR_MAX_DB
    # float32 round-off (what a model's scale round trip gives) stays at the cap too
    assert psnr(img.astype(np.float32) * np.float32(1 + 1e-7), img) == pytest.approx(PSNR_MAX_DB, abs=1e-6)


@pytest.mark.parametrize("offset", [0.1, 0.01, 0.003])
def test_psnr_of_constant_offset(offset):
    img = gaussian()
    # MSE = offset^2 -> PSNR = -20 log10(offset)
    assert psnr(img + offset, img) == pytest.approx(-20 * np.log10(offset), rel=1e-9)


def test_psnr_stack_returns_per_image():
    img = gaussian()
    values = psnr(np.stack([img + 0.1, img + 0.01]), np.stack([img, img]))
    assert values.shape == (2,)
    np.testing.assert_allclose(values, [20.0, 40.0])


def test_ssim_identical_is_one_and_degrades():
    img = gaussian()
    assert ssim(img, img) == pytest.approx(1.0)
    assert ssim(gaussian(col=28.5), img) < 0.9
    np.testing.assert_allclose(ssim(np.stack([img, img]), np.stack([img, img])), [1.0, 1.0])


def test_centroid_of_delta_and_gaussian():
    delta = np.zeros((16, 16))
    delta[3, 11] = 5.0
    np.testing.assert_allclose(centroid_px(delta), [3.0, 11.0])
    np.testing.assert_allclose(centroid_px(gaussian(row=20.0, col=26.0)), [20.0, 26.0], atol=1e-6)
    assert np.isnan(centroid_px(np.zeros((4, 4)))).all()


def test_centroid_error_of_shifted_spot_in_mrad():
    meas = gaussian(row=20.5, col=20.5)
    pred = gaussian(row=23.5, col=24.5)  # shifted 3 rows, 4 columns -> 5 px
    # 0.02 m square pixels, 100 m away: 5 px = 0.1 m = 1 mrad
    assert centroid_error_mrad(pred, meas, 0.02, 100.0) == pytest.approx(1.0, rel=1e-6)
    # rectangular pixels: rows 0.04 m, columns 0.01 m -> hypot(0.12, 0.04) m at 50 m
    expected = np.hypot(3 * 0.04, 4 * 0.01) / 50.0 * 1e3
    assert centroid_error_mrad(pred, meas, (0.04, 0.01), 50.0) == pytest.approx(expected, rel=1e-6)
    assert centroid_error_mrad(meas, meas, 0.02, 100.0) == pytest.approx(0.0, abs=1e-9)


@pytest.mark.parametrize("k", [0.5, 0.9, 1.0, 1.3])
def test_flux_accuracy_of_scaled_image(k):
    img = gaussian()
    assert flux_accuracy(k * img, img) == pytest.approx(1 - abs(k - 1))
    assert flux_accuracy(np.zeros_like(img), img) == pytest.approx(0.0)


def test_image_metrics_per_image():
    meas = np.stack([gaussian(), gaussian(row=18.5)])
    pred = np.stack([gaussian(), 0.5 * gaussian(row=18.5)])
    out = image_metrics(pred, meas, 0.01, 10.0)
    assert set(out) == {"psnr", "ssim", "centroid_mrad", "flux_accuracy"}
    assert all(v.shape == (2,) for v in out.values())
    assert out["psnr"][0] == PSNR_MAX_DB and out["ssim"][0] == pytest.approx(1.0)
    np.testing.assert_allclose(out["centroid_mrad"], [0.0, 0.0], atol=1e-9)
    np.testing.assert_allclose(out["flux_accuracy"], [1.0, 0.5])


def test_shape_mismatch_raises():
    with pytest.raises(ValueError, match="shape"):
        psnr(np.zeros((4, 4)), np.zeros((4, 5)))


def test_misplaced_flux_ignores_scale_and_counts_moved_flux():
    a = torch.zeros(1, 8, 8)
    a[0, 2, 2] = 1.0
    b = torch.zeros(1, 8, 8)
    b[0, 5, 5] = 3.0
    assert float(misplaced_flux(a, 7 * a)) == pytest.approx(0.0, abs=1e-12)
    assert float(misplaced_flux(a, b)) == pytest.approx(1.0)  # no overlap: all of the flux misplaced
