"""Image metrics of predicted against measured focal spots (numpy; the misplaced flux, in torch, is
physics.scene.misplaced_flux: the models choose their freedom by it too).

Conventions shared by every function here:

- Images are (H, W) arrays or (N, H, W) stacks, already divided by ONE scale for the whole
  dataset (the maximum of all its measured images), so that values lie in [0, ~1] and intensity
  errors count. Functions on stacks return (N,) arrays; on a single image, a float.
- Rows run down from the target's top edge, columns to the right (the dataset's convention).
- PSNR uses data range 1 and is capped at ``PSNR_MAX_DB`` (100 dB): an identical prediction
  (mean squared error 0, or float round-off of ~1e-15) scores 100 dB rather than infinity, so
  that split means stay finite and JSON stays standard. The cap lies far above anything a
  learnt model reaches (a 1e-5 RMS error is already 100 dB).
- Centroids are flux-weighted with negative values clipped to 0; an image with no positive flux
  has no centroid (NaN), and every metric derived from it is NaN.
"""

from __future__ import annotations

import numpy as np
import torch
from skimage.metrics import structural_similarity

from helioflow.physics.target import pixel_centroid

PSNR_MAX_DB = 100.0
_MSE_FLOOR = 10.0 ** (-PSNR_MAX_DB / 10.0)  # the MSE at which PSNR reaches the cap (data range 1)


def _pair(pred, meas) -> tuple[np.ndarray, np.ndarray, bool]:
    """(pred, meas) as float64 (N, H, W) stacks of equal shape, and whether the input was one image."""
    pred = np.asarray(pred, dtype=np.float64)
    meas = np.asarray(meas, dtype=np.float64)
    if pred.shape != meas.shape:
        raise ValueError(f"predicted images have shape {pred.shape}, measured {meas.shape}; expected equal shapes")
    if pred.ndim not in (2, 3):
        raise ValueError(f"images have shape {pred.shape}; expected (H, W) or (N, H, W)")
    single = pred.ndim == 2
    return (pred[None], meas[None], True) if single else (pred, meas, False)


def _out(values: np.ndarray, single: bool):
    return float(values[0]) if single else values


def psnr(pred, meas) -> float | np.ndarray:
    """Peak signal-to-noise ratio in dB with data range 1: 10 log10(1 / MSE), capped at 100 dB.

    Args:
        pred, meas: (H, W) or (N, H, W) images divided by the dataset's maximum.
    Returns:
        float (one image) or (N,) array, dB.
    """
    pred, meas, single = _pair(pred, meas)
    mse = np.mean((pred - meas) ** 2, axis=(1, 2))
    return _out(10.0 * np.log10(1.0 / np.maximum(mse, _MSE_FLOOR)), single)


def ssim(pred, meas) -> float | np.ndarray:
    """Structural similarity (scikit-image, data_range=1, 7x7 uniform window; smaller odd
    window for images under 7 pixels a side). 1 for identical images.

    Args:
        pred, meas: (H, W) or (N, H, W) images divided by the dataset's maximum.
    Returns:
        float (one image) or (N,) array, dimensionless, <= 1.
    """
    pred, meas, single = _pair(pred, meas)
    side = min(pred.shape[1:])
    win = min(7, side if side % 2 else side - 1)
    if win < 3:
        raise ValueError(f"images of shape {pred.shape[1:]} are too small for SSIM (need at least 3x3)")
    values = np.array([structural_similarity(p, m, data_range=1.0, win_size=win) for p, m in zip(pred, meas)])
    return _out(values, single)


def centroid_px(image) -> np.ndarray:
    """Flux-weighted centroid (row, col) in pixels, measured from the centre of pixel (0, 0)
    (physics.target.pixel_centroid, in float64).

    Args:
        image: (H, W) or (N, H, W); negative values are clipped to 0.
    Returns:
        (2,) or (N, 2) float array (row, col) in pixels; NaN where an image has no positive flux.
    """
    img = np.asarray(image, dtype=np.float64)
    if img.ndim not in (2, 3):
        raise ValueError(f"image has shape {img.shape}; expected (H, W) or (N, H, W)")
    return pixel_centroid(torch.from_numpy(img)).numpy()


def centroid_error_mrad(pred, meas, pixel_size_m, slant_range_m: float) -> float | np.ndarray:
    """Distance between the flux-weighted centroids of predicted and measured images on the
    target, as an angle seen from the heliostat.

    Args:
        pred, meas: (H, W) or (N, H, W) images.
        pixel_size_m: a pixel's size on the target in metres, a scalar or (row height, column
            width) — i.e. (target height / H, target width / W).
        slant_range_m: distance from the heliostat to the target centre, metres.
    Returns:
        float or (N,) array, mrad (distance in metres / slant range * 1000); NaN where either
        image has no positive flux.
    """
    pred, meas, single = _pair(pred, meas)
    dy, dx = np.broadcast_to(np.asarray(pixel_size_m, dtype=np.float64), (2,))
    delta = centroid_px(pred) - centroid_px(meas)  # (N, 2) pixels
    dist_m = np.hypot(delta[:, 0] * dy, delta[:, 1] * dx)
    return _out(dist_m / float(slant_range_m) * 1e3, single)


def flux_accuracy(pred, meas) -> float | np.ndarray:
    """1 - sum|pred - meas| / sum|meas| per image: 1 for a perfect prediction, 1 - |k - 1| for
    a prediction k times the measurement, 0 for an all-zero prediction (can go below 0).

    Args:
        pred, meas: (H, W) or (N, H, W) images (any common scale).
    Returns:
        float or (N,) array, dimensionless; NaN where the measured image is all zero.
    """
    pred, meas, single = _pair(pred, meas)
    ref = np.abs(meas).sum(axis=(1, 2))
    with np.errstate(invalid="ignore", divide="ignore"):
        values = 1.0 - np.abs(pred - meas).sum(axis=(1, 2)) / ref
    values[ref <= 0] = np.nan
    return _out(values, single)


METRICS = ("psnr", "ssim", "centroid_mrad", "flux_accuracy")


def image_metrics(pred, meas, pixel_size_m, slant_range_m: float) -> dict[str, float | np.ndarray]:
    """Every metric per image.

    Args:
        pred, meas: (N, H, W) (or (H, W)) images divided by the measured dataset's maximum.
        pixel_size_m, slant_range_m: as in :func:`centroid_error_mrad`.
    Returns:
        {"psnr": dB, "ssim": -, "centroid_mrad": mrad, "flux_accuracy": -}, each an (N,) float
        array (floats for a single image).
    """
    return {
        "psnr": psnr(pred, meas),
        "ssim": ssim(pred, meas),
        "centroid_mrad": centroid_error_mrad(pred, meas, pixel_size_m, slant_range_m),
        "flux_accuracy": flux_accuracy(pred, meas),
    }
