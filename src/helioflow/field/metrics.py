"""Metrics of receiver flux maps against the truth map (pure numpy), for rule `compose_field`.

Maps are (H, W) flux in W/m^2 on the receiver. Against the truth map T, a map P scores:

    flux_accuracy     1 - sum|P - T| / sum|T| (1 = exact; metrics.flux_accuracy)
    psnr_db           PSNR with both maps divided by max(T) (data range 1, capped at 100 dB)
    peak_flux_error   (max P - max T) / max T, signed (> 0: the map promises a hotter peak)
    centroid_error_m  distance between the flux-weighted centroids on the receiver (m)
    power_error       (sum P - sum T) / sum T, signed
plus, for whole maps, the map's own intercept: power on the receiver / power reflected (the
reflected power of the map's own budget), and its difference to the truth's intercept.
"""

from __future__ import annotations

import numpy as np

from helioflow.scoring.metrics import centroid_px, flux_accuracy, psnr

SPOT_METRICS = ("flux_accuracy", "psnr_db", "peak_flux_error", "centroid_error_m", "power_error")
MAP_METRICS = (*SPOT_METRICS, "peak_flux_kw_m2", "power_on_receiver_kw", "intercept", "intercept_error")


def spot_metrics(pred: np.ndarray, truth: np.ndarray, pixel_size_m: tuple[float, float]) -> dict[str, float]:
    """SPOT_METRICS of one (H, W) map or spot against the truth (module docstring).

    Args:
        pred, truth: (H, W) flux (W/m^2).
        pixel_size_m: (width, height) of a receiver pixel (m).
    """
    pred, truth = np.asarray(pred, dtype=np.float64), np.asarray(truth, dtype=np.float64)
    peak = float(truth.max())
    if not peak > 0:
        raise ValueError("the truth map holds no flux; nothing to compare with")
    offset = (centroid_px(pred) - centroid_px(truth)) * np.array(pixel_size_m[::-1])  # (row, col) in m
    return {
        "flux_accuracy": float(flux_accuracy(pred, truth)),
        "psnr_db": float(psnr(pred / peak, truth / peak)),
        "peak_flux_error": float(pred.max()) / peak - 1.0,
        "centroid_error_m": float(np.hypot(*offset)),
        "power_error": float(pred.sum() / truth.sum()) - 1.0,
    }


def map_metrics(
    pred: np.ndarray,
    truth: np.ndarray,
    pixel_size_m: tuple[float, float],
    reflected_w: float,
    truth_intercept: float,
) -> dict[str, float]:
    """MAP_METRICS of a whole receiver map: SPOT_METRICS plus its peak (kW/m^2), power on the
    receiver (kW), intercept (on the receiver / `reflected_w`, the map's own reflected power in W)
    and intercept minus `truth_intercept`."""
    on_receiver = float(np.sum(pred)) * pixel_size_m[0] * pixel_size_m[1]
    intercept = on_receiver / reflected_w
    return {
        **spot_metrics(pred, truth, pixel_size_m),
        "peak_flux_kw_m2": float(np.max(pred)) / 1e3,
        "power_on_receiver_kw": on_receiver / 1e3,
        "intercept": intercept,
        "intercept_error": intercept - truth_intercept,
    }


def mean_metrics(rows: list[dict[str, float]]) -> dict[str, float]:
    """Mean of each metric over rows (design points, or heliostats and design points); signed
    errors are averaged as they are, with their mean absolute value beside them (`..._abs`)."""
    out = {}
    for key in rows[0]:
        values = np.array([r[key] for r in rows], dtype=np.float64)
        out[key] = float(values.mean())
        if key.endswith("_error") and key != "centroid_error_m":
            out[f"{key}_abs"] = float(np.abs(values).mean())
    return out
