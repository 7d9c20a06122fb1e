"""What a fitted physics model (`drt`) recovered of a synthetic heliostat's true errors.

Compares the model file's fitted tensors with the heliostat file the dataset was traced from
(`surfaces/<heliostat>.h5`) and, for the slope error, with the dataset's world effects:

- tracking: each of the five parameters (mrad) and the largest error;
- pointing: the angle (mrad) between the true and the fitted mirror normal at the dataset's sun
  positions, RMS and largest: what the images see most directly (a single-azimuth scan points
  the mirror almost alike for a range of elevation offsets and northward pedestal tilts);
- surface: RMS error of the surface heights (the B-spline deformation sampled on a fine grid of
  equal cells over every facet, so each square metre counts alike) over their RMS amplitude, their
  correlation, and the correlation per facet (which facets came back);
- canting (several facets): RMS error and RMS of the true tilts (mrad);
- slope error: fitted and true sigma (mrad);
- how sure the fit said it was (models/uncertainty.py, where the model file holds it): sigma beside
  every fitted value, and `coverage` per quantity: the share of true values within the fit's 95 %
  interval (fitted +- 1.96 sigma; ~0.95 for a fit that reached its optimum and a right noise
  model), over the determined values, with how many were reported "not determined" and how many of
  those are off by more than their interval (a flag that was needed);
- PSNR (dB) per split, scored as the `evaluate` rule scores: the model as fitted, and the same model
  with the true heliostat in it (its tracking, canting and surface, and the world's slope error)
  instead of the fitted one. Their difference is what the remaining recovery error costs the
  predictions; where the true heliostat still falls short of the images, the model's other effects
  (sun shape, camera, ...) or its noise-free trace differ from the world's effects or the dataset's
  trace (a ray trace is noisy).
"""

from __future__ import annotations

import json
import os
from dataclasses import replace
from typing import TYPE_CHECKING, cast

import numpy as np
import torch

from helioflow.data.hdf5 import SPLITS, read_dataset
from helioflow.data.surfaces import read_heliostat
from helioflow.errors import DataError
from helioflow.io import write_text_atomic
from helioflow.models.registry import load_model
from helioflow.models.uncertainty import Z95, FitUncertainty
from helioflow.physics.effects.canting import zero_mean
from helioflow.physics.geometry import sun_vector
from helioflow.physics.heliostat import Heliostat, bspline_basis, orientation, without_planes
from helioflow.scoring.evaluation import scored_images
from helioflow.scoring.metrics import psnr

if TYPE_CHECKING:
    from helioflow.models.physical import RaytraceModel


def recovery(model_path: str | os.PathLike, heliostat_path: str | os.PathLike, dataset_path: str | os.PathLike,
             device: str = "cpu") -> dict:
    """The comparison described in the module docstring, as a JSON-able dict; the model predicts
    on `device` (cpu | cuda | auto), the comparisons are made on the CPU."""
    model, info = load_model(model_path, device)
    tensors = getattr(getattr(model, "fitted", None), "tensors", None)
    if not tensors:
        raise DataError(f"{model_path}: a {info['network']} model has no fitted heliostat tensors to compare")
    model = cast("RaytraceModel", model)  # a physics model: it has a fit
    tensors = {k: v.cpu() for k, v in tensors.items()}
    true = read_heliostat(heliostat_path).to("cpu", torch.float64)
    ds = read_dataset(dataset_path)
    out: dict = {}
    if "tracking" in tensors:
        fitted = tensors["tracking"].double()
        truth = true.tracking_error * 1e3
        out["tracking_mrad"] = {"fitted": _rounded(fitted), "true": _rounded(truth),
                                "max_error": round(float((fitted - truth).abs().max()), 4)}
        angle = pointing_angles_mrad(true, fitted, ds.azimuth_deg, ds.elevation_deg, ds.attrs["target_center_m"],
                                     reference_mrad=truth)
        out["pointing_error_mrad"] = {"rms": round(float(angle.pow(2).mean().sqrt()), 4),
                                      "max": round(float(angle.max()), 4)}
    if "surface" in tensors:
        fitted, truth = surface_heights(tensors["surface"].double()), surface_heights(true.control_heights * 1e3)
        error, amplitude = float((fitted - truth).pow(2).mean().sqrt()), float(truth.pow(2).mean().sqrt())
        out["surface_mm"] = {"rms_true": round(amplitude, 4), "rms_error_over_rms_true": round(error / amplitude, 4),
                             "correlation": _correlation(fitted, truth),
                             "facet_correlation": [_correlation(f, t) for f, t in zip(fitted, truth)]}
    if "canting" in tensors:
        fitted, truth = tensors["canting"].double(), true.canting_error * 1e3
        out["canting_mrad"] = {"rms_true": round(float(truth.pow(2).mean().sqrt()), 4),
                               "rms_error": round(float((fitted - truth).pow(2).mean().sqrt()), 4)}
    effects = {e: dict(p or {}) for e, p in model.fitted.effects.items()}
    slope = effects.get("slope_error", {}).get("sigma_mrad")
    if slope is not None:
        world = (ds.attrs.get("world_effects") or {}).get("slope_error") or {}
        out["slope_error_mrad"] = {"fitted": slope, "true": world.get("sigma_mrad", 0.0)}
        effects["slope_error"]["sigma_mrad"] = out["slope_error_mrad"]["true"]
    if model.fitted.uncertainty is not None:
        out.update(_with_sigma(out, model.fitted.uncertainty, true))
    fitted_psnr = _split_psnr(model, info, ds, model_path, dataset_path)
    true_tensors = {"tracking": true.tracking_error * 1e3, "canting": true.canting_error * 1e3,
                    "surface": true.control_heights * 1e3}
    model.fitted = replace(model.fitted, effects=effects,
                           tensors={k: true_tensors[k].to(model.device, v.dtype) for k, v in tensors.items()})
    out["psnr_db"] = {"fitted": fitted_psnr,
                      "true_heliostat": _split_psnr(model, info, ds, model_path, dataset_path)}
    return out


def write_recovery(model_path: str | os.PathLike, heliostat_path: str | os.PathLike,
                   dataset_path: str | os.PathLike, output: str | os.PathLike, device: str = "cpu") -> dict:
    """Rule `recovery`: the comparison as recovery/<dataset>.json (written whole), the JSON the
    command prints without --output."""
    result = recovery(model_path, heliostat_path, dataset_path, device)
    write_text_atomic(output, json.dumps(result, indent=1) + "\n")
    return result


def _with_sigma(out: dict, uncertainty: FitUncertainty, true) -> dict:
    """The recovery's entries with sigma beside each fitted value, and "coverage": per quantity the
    share of true values (as the model defines them: canting without its mean, control heights
    without each facet's plane) within the fit's 95 % interval (module docstring)."""
    truths = {"tracking.": true.tracking_error.double() * 1e3,
              "canting.": zero_mean(true.canting_error.double() * 1e3),
              "surface.": without_planes(true.control_heights.double() * 1e3),
              "slope_error.sigma_mrad": torch.tensor([float(out.get("slope_error_mrad", {}).get("true", 0.0))])}
    keys = {"tracking.": "tracking_mrad", "canting.": "canting_mrad", "surface.": "surface_mm",
            "slope_error.sigma_mrad": "slope_error_mrad"}
    coverage, updated = {}, {}
    for prefix, truth in truths.items():
        at = [k for k, n in enumerate(uncertainty.names) if n.startswith(prefix)]
        if len(at) != truth.numel() or keys[prefix] not in out:  # a partly fitted tensor: no truth per entry
            continue
        names = [uncertainty.names[k] for k in at]
        fitted, sigma = uncertainty.values[at], uncertainty.sigma[at]
        truth = truth.flatten().numpy()
        inside = np.abs(fitted - truth) <= Z95 * sigma
        flagged = np.array([n in uncertainty.undetermined for n in names])
        entry = dict(out[keys[prefix]])
        entry["sigma"] = (_rounded(torch.as_tensor(sigma)) if prefix in ("tracking.", "slope_error.sigma_mrad")
                          else {"rms": round(float(np.sqrt(np.mean(sigma**2))), 5),
                                "max": round(float(sigma.max()), 5)})
        if prefix == "slope_error.sigma_mrad":
            entry["sigma"] = entry["sigma"][0]
        entry["not_determined"] = int(flagged.sum())
        updated[keys[prefix]] = entry
        coverage[keys[prefix]] = {
            "within_95": None if flagged.all() else round(float(inside[~flagged].mean()), 4),
            "determined": int((~flagged).sum()),
            "not_determined": int(flagged.sum()),
            "not_determined_and_outside": int((flagged & ~inside).sum()),
            "within_95_if_all_trusted": round(float(inside.mean()), 4)}
    updated["coverage"] = coverage
    updated["uncertainty"] = {k: uncertainty.as_json()[k] for k in ("misfit", "structure", "structured_beyond",
                                                                     "facet_structure", "correlations")}
    return updated


def pointing_angles_mrad(heliostat: Heliostat, tracking_mrad: torch.Tensor, azimuth_deg, elevation_deg,
                         aim_m, reference_mrad: torch.Tensor | None = None) -> torch.Tensor:
    """Angles (mrad) between the mirror normal with kinematic errors `tracking_mrad` ((5,) or (D, 5),
    TRACKING_PARAMETERS order) and with `reference_mrad` ((5,); default none: the ideal kinematics)
    at each of S sun positions (deg): (S,) or (D, S)."""
    h = heliostat.to("cpu", torch.float64)
    sun = sun_vector(torch.deg2rad(torch.as_tensor(azimuth_deg, dtype=torch.float64)),
                     torch.deg2rad(torch.as_tensor(elevation_deg, dtype=torch.float64)))
    aim = torch.as_tensor(aim_m, dtype=torch.float64)
    reference = torch.zeros(5, dtype=torch.float64) if reference_mrad is None else reference_mrad.double()
    ideal = orientation(replace(h, tracking_error=reference * 1e-3), sun, aim)[..., 2]  # (S, 3)
    draws = torch.as_tensor(tracking_mrad, dtype=torch.float64).reshape(-1, 5)
    normals = torch.stack([orientation(replace(h, tracking_error=t * 1e-3), sun, aim)[..., 2] for t in draws])
    angle = torch.linalg.cross(ideal.expand_as(normals), normals).norm(dim=-1).clamp(max=1.0).asin() * 1e3
    return angle.reshape(*torch.as_tensor(tracking_mrad).shape[:-1], len(sun))


def surface_heights(control_heights_mm: torch.Tensor, samples_per_side: int = 64) -> torch.Tensor:
    """(..., F, C, C) control heights (mm) -> (..., F, G, G) heights (mm) of the deformation at the
    centres of G x G equal cells of each facet."""
    basis = torch.as_tensor(bspline_basis((np.arange(samples_per_side) + 0.5) / samples_per_side,
                                          control_heights_mm.shape[-1])[0], dtype=control_heights_mm.dtype)
    return torch.einsum("ui,...fij,vj->...fuv", basis, control_heights_mm, basis)


def _split_psnr(model, info: dict, ds, model_path, dataset_path) -> dict[str, float]:
    """{split: mean PSNR (dB)} of the model's predictions on each non-empty split of `ds`."""
    predicted, measured, _ = scored_images(model, info, ds, model_path, dataset_path)
    return {split: round(float(np.mean(psnr(predicted[idx], measured[idx]))), 2)
            for split in SPLITS if len(idx := ds.indices(split))}


def _correlation(a: torch.Tensor, b: torch.Tensor) -> float | None:
    """Pearson correlation of two height fields; None where one is flat (it has none)."""
    x, y = a.flatten().numpy(), b.flatten().numpy()
    if x.std() == 0.0 or y.std() == 0.0:
        return None
    return round(float(np.corrcoef(x, y)[0, 1]), 4)


def _rounded(values: torch.Tensor) -> list[float]:
    return [round(float(v), 4) for v in values]
