"""The heliostat a physics fit (`drt`) found, written out for a user: heliostats/<dataset>.json.

What a calibration is for: the heliostat's own errors with how sure the fit is of each, in the
units a plant engineer reads them in (docs/outputs.md):

- surface: the deviation from the design along the facet normal (mm) on a regular grid over the
  heliostat, in the heliostat frame: x right, y up as seen facing the mirror at rest (m; at rest
  east and up), origin at the concentrator centre; rows from the top. Points between facets are
  null. The deviation is the shape the heliostat traces (each facet's mean height and mean tilt
  removed: those are the canting's and move nothing); its sigma is the B-spline's weights through
  the fit's covariance of that facet's control heights, sqrt(b^T C b);
- slope error (mrad), each facet's canting error (mrad, about its right and up axes, their mean
  removed: a common tilt is tracking) and the five tracking parameters (mrad), each with sigma;
- every other fitted scalar (the sun's width, the camera's gain ...) with its sigma;
- `determined` beside each: false where models/uncertainty.py reports the images do not determine
  it (its sigma is then an estimate of how far it may be off, not a confidence interval);
- `freedom`: what the fit freed and why (models/freedom.py), and `at_design`: what it kept at the
  design (its prior: a few images did not earn that freedom), which the JSON then leaves out.

Every value is the fit's own (models/uncertainty.py: the sandwich covariance, misfit-inflated).
"""

from __future__ import annotations

import json
import os
from typing import TYPE_CHECKING, cast

import numpy as np
import torch

from helioflow.errors import DataError
from helioflow.io import write_text_atomic
from helioflow.models.registry import load_model
from helioflow.models.uncertainty import FitUncertainty
from helioflow.physics.effects import REGISTRY, TENSOR_EFFECTS
from helioflow.physics.heliostat import Heliostat, bspline_basis

if TYPE_CHECKING:
    from helioflow.models.physical import RaytraceModel

TRACKING = REGISTRY["tracking"].parameters  # the five kinematic errors, in the tensor's order
GRID_STEP_M = 0.05  # spacing of the surface grid (m): 64 x 51 points over a 3.2 m x 2.6 m heliostat


def fitted_heliostat(model_path: str | os.PathLike, grid_step_m: float = GRID_STEP_M) -> dict:
    """The JSON of the module docstring for a physics model file with fitted heliostat tensors;
    DataError names the file when the model has none (a network, or `raytrace` without them)."""
    model, info = load_model(model_path)
    fitted = getattr(model, "fitted", None)
    tensors = getattr(fitted, "tensors", None)
    if not tensors and getattr(model, "freedom", None) is None:
        raise DataError(f"{model_path}: a {info['network']} model has no fitted heliostat tensors to write out "
                        "(only drt fits the heliostat)")
    if grid_step_m <= 0:
        raise DataError(f"grid_step_m = {grid_step_m}: expected a positive spacing in metres")
    model = cast("RaytraceModel", model)  # a physics model: it has a fit and its heliostat
    fitted, tensors = model.fitted, model.fitted.tensors
    assert model.heliostat is not None  # a fitted model keeps its heliostat
    u = fitted.uncertainty
    summary = None if u is None else u.as_json()  # every scalar with sigma, the misfit, the method
    effective = {k: TENSOR_EFFECTS[k].effective(v.detach().cpu().double()) for k, v in tensors.items()}
    out: dict = {"model": str(model_path), "network": info["network"],
                 "frame": "heliostat frame: x right, y up as seen facing the mirror at rest (east, up), m; "
                          "origin the concentrator centre",
                 "uncertainty": None if summary is None else {k: summary[k] for k in ("misfit", "structure", "method",
                                                                                  "refits")}}
    freedom = getattr(model, "freedom", None)
    out["freedom"] = None if freedom is None else freedom.as_json()
    slope = (fitted.effects.get("slope_error") or {}).get("sigma_mrad")
    has = {"tracking": "tracking" in effective, "canting": "canting" in effective or model.heliostat.n_facets == 1,
           "surface": "surface" in effective, "slope error": slope is not None}
    out["at_design"] = [q for q, fitted_here in has.items() if not fitted_here]
    if "surface" in effective:
        out["surface"] = surface_grid(model.heliostat, effective["surface"], u, grid_step_m)
    if slope is not None:
        out["slope_error_mrad"] = _scalar(u, "slope_error.sigma_mrad", float(slope))
    if "canting" in effective:
        out["canting_mrad"] = _tensor(u, "canting.facet_tilts_mrad", effective["canting"],
                                      "per facet [about its right axis, about its up axis], their mean removed")
    if "tracking" in effective:
        out["tracking_mrad"] = {p.name.removesuffix("_mrad"): _scalar(u, f"tracking.{p.name}", float(v))
                                for p, v in zip(TRACKING, effective["tracking"].tolist())}
    if summary is not None:  # u is not None
        listed = {"slope_error.sigma_mrad", *(f"tracking.{p.name}" for p in TRACKING)}
        out["other_fitted"] = {k: v for k, v in summary["scalars"].items() if k not in listed}
    return out


def write_fitted_heliostat(model_path: str | os.PathLike, output: str | os.PathLike,
                           figure: str | os.PathLike | None = None, grid_step_m: float = GRID_STEP_M) -> dict:
    """Rule `fitted_heliostat`: heliostats/<dataset>.json, written whole, and (with `figure`) its
    surface as a PNG (plot_surface)."""
    result = fitted_heliostat(model_path, grid_step_m)
    if figure is not None:
        plot_surface(result, figure)
    write_text_atomic(output, json.dumps(result, indent=1) + "\n")
    return result


def plot_surface(result: dict, path: str | os.PathLike) -> None:
    """The fitted surface's deviation (mm) and its sigma (mm) over the heliostat as seen facing the
    mirror, with the tracking, canting and slope error in the title; a heliostat without a fitted
    surface gets the title alone."""
    from helioflow.plotting import plt, save_figure

    surface = result.get("surface")
    fig, axes = plt.subplots(1, 2, figsize=(12, 5), layout="constrained")
    for ax, key, label in zip(axes, ("deviation_mm", "sigma_mm"), ("deviation from the design (mm)", "sigma (mm)")):
        if surface is None or surface.get(key) is None:
            ax.axis("off")
            continue
        values = np.array(surface[key], dtype=float)
        x, y, half = surface["x_m"], surface["y_m"], surface["grid_step_m"] / 2
        extent = (x[0] - half, x[-1] + half, y[-1] - half, y[0] + half)
        if key == "deviation_mm":
            limit = float(np.nanmax(np.abs(values))) or 1.0
            image = ax.imshow(values, extent=extent, cmap="RdBu_r", vmin=-limit, vmax=limit)
        else:  # a few points at a facet's corner may carry most of it: the colours end at the 95th percentile
            image = ax.imshow(values, extent=extent, cmap="viridis", vmin=0.0,
                              vmax=float(np.nanpercentile(values, 95)) or 1.0)
            label += f", colours to the 95th percentile (largest {np.nanmax(values):.2g})"
        fig.colorbar(image, ax=ax, label=label, shrink=0.8)
        ax.set_xlabel("right (m)")
        ax.set_ylabel("up (m)")
    fig.suptitle(_summary(result), fontsize=9)
    save_figure(fig, path)


def _summary(result: dict) -> str:
    """One line per fitted quantity: value +- sigma."""
    def pm(entry: dict) -> str:
        sigma = entry.get("sigma")
        return f"{entry['value']:.2f}" + ("" if sigma is None else f" +- {sigma:.2f}")

    lines = []
    if "tracking_mrad" in result:
        items = [f"{k} {pm(v)}" for k, v in result["tracking_mrad"].items()]
        lines += ["tracking (mrad): " + ", ".join(items[:3]), ", ".join(items[3:])]
    if "canting_mrad" in result:
        lines.append(f"canting RMS {result['canting_mrad']['rms']:.2f} mrad")
    if "slope_error_mrad" in result:
        lines.append(f"slope error {pm(result['slope_error_mrad'])} mrad")
    if "surface" in result:
        surface = result["surface"]
        undetermined = surface["not_determined_facets"]
        lines.append(f"surface RMS {surface['rms_mm']:.3f} mm"
                     + (f", not determined on facets {undetermined}" if undetermined else ""))
    if result.get("at_design"):
        lines.append("at the design (not determined by the images): " + ", ".join(result["at_design"]))
    return "\n".join(lines)


def surface_grid(heliostat: Heliostat, heights_mm: torch.Tensor, uncertainty: FitUncertainty | None,
                 step_m: float) -> dict:
    """The deviation (mm) and its sigma on a regular grid of `step_m` over the heliostat's facets.

    Args:
        heliostat: the design geometry (facet_translation (F, 3), facet_size (F, 2), m).
        heights_mm: (F, C, C) control heights as the heliostat takes them (mm), rows along up (top
            first), columns along right (physics.heliostat.deformation).
        uncertainty: the fit's covariance over "surface.control_heights_mm[f, i, j]" (None, or
            one without those entries: sigma_mm None and determined false).
    Returns:
        x_m (X,), y_m (Y,, top first), deviation_mm and sigma_mm (Y, X) with null off the facets,
        facet (Y, X) index (-1 off the facets), rms_mm over the facets, not_determined_facets.
    """
    centre = heliostat.facet_translation[:, :2].detach().cpu().double().numpy()  # (F, 2) right, up
    size = heliostat.facet_size.detach().cpu().double().numpy()  # (F, 2) width, height
    low, high = (centre - size / 2).min(0), (centre + size / 2).max(0)
    x = _axis(low[0], high[0], step_m)
    y = _axis(low[1], high[1], step_m)[::-1]  # top first, as the rows of an image
    xx, yy = np.meshgrid(x, y)
    facet = np.full(xx.shape, -1)
    for f in range(len(centre)):
        inside = (np.abs(xx - centre[f, 0]) <= size[f, 0] / 2) & (np.abs(yy - centre[f, 1]) <= size[f, 1] / 2)
        facet[inside & (facet < 0)] = f
    c = heights_mm.shape[-1]
    heights = heights_mm.numpy()
    deviation, sigma = np.full(xx.shape, np.nan), np.full(xx.shape, np.nan)
    names = [] if uncertainty is None else uncertainty.names
    undetermined = set() if uncertainty is None else set(uncertainty.undetermined)
    not_determined = []
    for f in range(len(centre)):
        at = facet == f
        if not at.any():
            continue
        s_right = (xx[at] - centre[f, 0]) / size[f, 0] + 0.5
        s_down = 0.5 - (yy[at] - centre[f, 1]) / size[f, 1]
        b_down, b_right = bspline_basis(s_down, c)[0], bspline_basis(s_right, c)[0]  # (G, C) each
        weights = np.einsum("gi,gj->gij", b_down, b_right).reshape(len(s_right), c * c)  # (G, C*C)
        deviation[at] = weights @ heights[f].reshape(-1)
        entries = [f"surface.control_heights_mm[{f}, {i}, {j}]" for i in range(c) for j in range(c)]
        if uncertainty is not None and entries[0] in names:
            index = [names.index(e) for e in entries]
            block = uncertainty.covariance[np.ix_(index, index)]
            sigma[at] = np.sqrt(np.clip(np.einsum("gi,ij,gj->g", weights, block, weights), 0.0, None))
            if any(e in undetermined for e in entries):
                not_determined.append(f)
    on = facet >= 0
    return {"grid_step_m": step_m, "x_m": _rounded(x), "y_m": _rounded(y),
            "deviation_mm": _rounded(deviation), "sigma_mm": None if np.isnan(sigma).all() else _rounded(sigma),
            "facet": facet.tolist(), "rms_mm": round(float(np.sqrt(np.mean(deviation[on] ** 2))), 5),
            "not_determined_facets": not_determined,
            "determined": not np.isnan(sigma).all() and not not_determined}


def _axis(low: float, high: float, step: float) -> np.ndarray:
    """Cell centres of step-wide cells covering [low, high] symmetrically."""
    n = max(1, int(np.ceil((high - low) / step - 1e-9)))
    return (low + high) / 2 + (np.arange(n) - (n - 1) / 2) * step


def _scalar(u: FitUncertainty | None, name: str, value: float) -> dict:
    """{value, sigma, determined} of one fitted scalar (sigma None without a covariance)."""
    if u is None or name not in u.names:
        return {"value": round(value, 5), "sigma": None, "determined": None}
    k = u.index(name)
    return {"value": round(value, 5), "sigma": round(float(u.sigma[k]), 5), "determined": name not in u.undetermined}


def _tensor(u: FitUncertainty | None, prefix: str, values: torch.Tensor, layout: str) -> dict:
    """{values, sigma, determined (per entry)} of one heliostat tensor, in its shape."""
    names = [f"{prefix}[{', '.join(map(str, i))}]" for i in np.ndindex(*values.shape)]
    out = {"layout": layout, "values": _rounded(values.numpy()), "rms": round(float(values.pow(2).mean().sqrt()), 5)}
    if u is None or names[0] not in u.names:
        return {**out, "sigma": None, "determined": None}
    index = [u.index(n) for n in names]
    return {**out, "sigma": _rounded(u.sigma[index].reshape(values.shape)),
            "determined": np.array([n not in u.undetermined for n in names]).reshape(values.shape).tolist()}


def _rounded(a: np.ndarray) -> list:
    """An array as nested lists of floats (5 significant decimals), NaN as null."""
    return [_rounded(row) for row in a] if np.ndim(a) > 1 else [None if not np.isfinite(v) else round(float(v), 5)
                                                                  for v in a]
