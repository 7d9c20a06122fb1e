"""Rule `plant_flux`: a plant's flux maps on its own receiver, every calibrated heliostat as its fit
has it, the rest ideal; what calibration changes in the plant's flux.

The field: every heliostat folder of the plant entry's PAINT directory that holds a
heliostat-properties.json, at its own pivot with its own facets (data.paint.read_heliostat_properties).
Two maps per sun design point (config plant.flux.sun), both traced by physics.field.field_flux
(shading, blocking and attenuation between all of them included) with the plant's model physics:

    ideal       every heliostat with its design geometry: what a plant computes today.
    calibrated  each calibrated heliostat (a dataset of the plant entry, its physics model
                config plant.model) with its fitted kinematics, canting and surface
                (physics.scene.with_tensors) and its own fitted slope error; the rest ideal.

The model physics: model.effects with the plant's model_effects, then plant.flux.effects over them
(blocking_shading and attenuation by default), "fit" values at the registry default
(compose.without_fit); tracking, canting and surface are each heliostat's own (its fit's, or none
for its design), whatever the list sets. Left out, and listed in flux.json's `left_out`: the camera
(it photographs the calibration target, it does not reflect) and mirror masks (soiling,
neighbour_shading: the field tracer has none; blocking_shading traces the neighbours). The sun is
the configured model's, not the calibration campaign's (the plant fit's shared sun belongs to the
days of the images).

The receiver: a flat plane through the outer corners of the tower file's receiver entry
(config plant.flux.receiver; data.paint.Tower.receiver).

flux.json: per design point the calibrated map's peak (kW/m^2), power on the receiver (kW) and
intercept; the ideal map scored against it (field.metrics.map_metrics: what the ideal model gets
wrong that calibration knows); per calibrated heliostat its spot's centroid on the receiver (right,
up; m) in both maps, the shift between them (m) and its on-receiver power in both (kW). `summary`:
their means over design points, the largest shift. flux.h5: schema SCHEMA (see `write_plant_flux`).
"""

from __future__ import annotations

import json
import logging
import math
import os
import time
from collections import Counter
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor

from helioflow.data.hdf5 import write_arrays
from helioflow.data.paint import PROPERTIES_FILE, Tower, read_heliostat_properties
from helioflow.data.synthetic import config_hash
from helioflow.device import resolve_device
from helioflow.errors import DataError
from helioflow.field.compose import FieldScene, aim_points, as_fitted, trace_field, without_fit
from helioflow.field.figure import plot_field_maps
from helioflow.field.margin import tracking_covariance
from helioflow.field.metrics import map_metrics, mean_metrics
from helioflow.io import write_text_atomic
from helioflow.models.registry import load_fitted_model
from helioflow.physics.effects import REGISTRY, TENSOR_EFFECTS
from helioflow.physics.field import BUDGET_TERMS, FieldFlux, flat_receiver
from helioflow.physics.heliostat import Heliostat

log = logging.getLogger(__name__)

SCHEMA = "helioflow.plant_flux/1"
MAPS = ("ideal", "calibrated")
LEFT_OUT = {"image": "it acts on the photograph of the calibration target, not on the receiver",
            "mirror mask": "the field tracer has no mirror masks (blocking_shading traces the neighbours)"}
POSITION_TOLERANCE_M = 0.01  # a fit's heliostat must stand where the plant's properties file puts it


def map_effects(effects: dict) -> tuple[dict, dict[str, str]]:
    """(the effect list the plant's maps trace, {left-out effect: why}) from a model effect list
    (module docstring)."""
    kept, left_out = {}, {}
    for name, params in effects.items():
        if REGISTRY[name].acts_on in LEFT_OUT:
            left_out[name] = LEFT_OUT[REGISTRY[name].acts_on]
        elif name not in TENSOR_EFFECTS:
            kept[name] = params
    # each heliostat's own tracking, canting and surface: its fit's (calibrated) or none (its design)
    return {**without_fit(kept), **{name: {} for name in TENSOR_EFFECTS}}, left_out


def plant_folders(paint_dir: str | os.PathLike) -> list[Path]:
    """The heliostat folders of a PAINT directory with a heliostat-properties.json, sorted."""
    return sorted(p.parent for p in Path(paint_dir).glob(f"*/{PROPERTIES_FILE}"))


def calibrated_heliostat(name: str, model_path: str | os.PathLike, design: Heliostat
                         ) -> tuple[Heliostat, float | None, Tensor | None]:
    """(the heliostat as its physics model's fit has it (float64), its fitted slope error (rad) or None
    where the model fits none, its (5, 5) tracking covariance (mrad^2; field.margin.tracking_covariance)
    or None); DataError naming the file when it holds no physics model or one fitted on a heliostat
    elsewhere than `design`."""
    model, heliostat, _ = load_fitted_model(model_path, "the plant's flux map")
    offset = float((heliostat.position.double().cpu() - design.position.double().cpu()).norm())
    if offset > POSITION_TOLERANCE_M:
        raise DataError(f"{model_path}: fitted on a heliostat {offset:.2f} m from {name}'s pivot in its "
                        f"{PROPERTIES_FILE}; refit it on this plant's data")
    fit = as_fitted(model)
    assert fit is not None  # load_fitted_model refuses a model without a fit
    return *fit, tracking_covariance(model.fitted.uncertainty)


@dataclass
class Plant:
    """A plant entry's field as rule plant_flux traces it (module docstring).

    Attributes:
        scene: every heliostat of the PAINT directory with its design geometry (scene.true), the
            receiver, the configured aim points, the design points; scene.measured: the calibrated ones.
        fitted: the N heliostats, each calibrated one as its fit has it, the rest as designed.
        slopes: {index: its fitted slope error (rad)} of the calibrated heliostats that fit one.
        tracking: per heliostat its (5, 5) fitted tracking covariance (mrad^2), or None.
        effects, left_out: the maps' effect list and what it leaves out, why (map_effects).
    """

    scene: FieldScene
    fitted: list[Heliostat]
    slopes: dict[int, float]
    tracking: list[Tensor | None]
    effects: dict
    left_out: dict[str, str]


def load_plant(spec: dict, device: torch.device) -> Plant:
    """The plant of a plant_flux spec (compose_plant's); DataError naming the file for a calibrated
    heliostat without a folder, a heliostat of another facet layout, or a fit made elsewhere."""
    settings = spec["settings"]
    tower = Tower(Path(spec["paint_dir"]) / "tower-measurements.json")
    folders = plant_folders(spec["paint_dir"])
    names = [f.name for f in folders]
    missing = [c["heliostat"] for c in spec["calibrated"] if c["heliostat"] not in names]
    if missing:
        raise DataError(f"{spec['paint_dir']}: calibrated heliostat {missing[0]} has no folder with a "
                        f"{PROPERTIES_FILE} there; heliostats: {', '.join(names) or 'none'}")
    design = [read_heliostat_properties(f / PROPERTIES_FILE, tower)[0] for f in folders]
    usual = Counter(h.n_facets for h in design).most_common(1)[0][0]
    odd = [(f, h) for f, h in zip(folders, design) if h.n_facets != usual]  # the field tracer batches one layout
    if odd:
        raise DataError(f"{odd[0][0] / PROPERTIES_FILE}: {odd[0][1].n_facets} facets, but the plant's other "
                        f"heliostats have {usual}; its flux map needs one facet layout for all of them")
    fitted, slopes = list(design), {}
    tracking: list[Tensor | None] = [None] * len(names)
    for c in spec["calibrated"]:
        k = names.index(c["heliostat"])
        fitted[k], own, tracking[k] = calibrated_heliostat(c["heliostat"], c["model_path"], design[k])
        if own is not None:
            slopes[k] = own
    plane = tower.receiver(settings["receiver"])
    receiver = flat_receiver(torch.tensor(plane.center, device=device), torch.tensor(plane.normal, device=device),
                             plane.width, plane.height, settings["resolution"])
    points = list(settings["sun"])
    az, el = (torch.tensor([math.radians(settings["sun"][p][k]) for p in points], dtype=torch.float64, device=device)
              for k in ("azimuth_deg", "elevation_deg"))
    calibrated = sorted(names.index(c["heliostat"]) for c in spec["calibrated"])
    scene = FieldScene(names, design, receiver, aim_points(receiver, settings["aim"], len(names)), points, az, el,
                       calibrated)
    effects, left_out = map_effects({**spec["effects"], **settings["effects"]})
    return Plant(scene, fitted, slopes, tracking, effects, left_out)


def _spot_place(spots: np.ndarray, receiver, pixel_area: float) -> tuple[np.ndarray, np.ndarray]:
    """(centroids (..., 2) right, up (m; NaN for a spot that misses the receiver), powers (...) W) of
    spots (..., H, W) W/m^2."""
    images = torch.as_tensor(spots)
    return receiver.centroid(images).numpy(), spots.sum((-2, -1)) * pixel_area


def compose_plant(spec: dict, flux_path: str | os.PathLike, figure_path: str | os.PathLike,
                  metrics_path: str | os.PathLike) -> dict:
    """The `plant_flux` rule for one plant entry: write flux.h5, flux.png and flux.json; return the metrics.

    Args:
        spec: {"plant": name, "paint_dir", "effects": the plant's model effects, "calibrated":
            [{"heliostat", "model_path"}], "settings": config plant.flux (receiver, resolution, aim, sun,
            effects, cells_per_side), "dni_w_m2", "device"} (helioflow.workflow.plant_flux_spec).
    """
    start = time.perf_counter()
    settings, device = spec["settings"], resolve_device(spec["device"])
    plant = load_plant(spec, device)
    scene, effects, dni, cells = plant.scene, plant.effects, spec["dni_w_m2"], settings["cells_per_side"]
    traced = {"ideal": trace_field(scene, effects, scene.true, dni, cells, device)[0],
              "calibrated": trace_field(scene, effects, plant.fitted, dni, cells, device, plant.slopes)[0]}
    metrics = _plant_metrics(scene, settings, traced, plant.left_out, effects)
    metrics["seconds"] = round(time.perf_counter() - start, 2)
    write_plant_flux(flux_path, scene, spec, traced, effects)
    write_text_atomic(metrics_path, json.dumps(metrics, indent=2) + "\n")
    sun_deg = np.degrees(torch.stack((scene.azimuth, scene.elevation), -1).cpu().numpy())
    receiver, n, m = scene.receiver, len(scene.names), len(scene.measured)
    plot_field_maps(figure_path, {m: traced[m].flux.cpu().numpy() for m in MAPS}, "calibrated", scene.points, sun_deg,
                    [{"ideal": metrics["design_points"][p]["ideal"]} for p in scene.points],
                    np.array([h.position.tolist() for h in scene.true]), scene.measured,
                    (receiver.width, receiver.height),
                    f"plant {spec['plant']}: {n} heliostats, {m} calibrated: ideal (design "
                    "geometry) and calibrated (fitted heliostats) on its receiver",
                    labels=("ideal (design)", "calibrated (fit)"))
    log.info("plant %s: %d heliostats, %d calibrated, %d design points in %.1f s", spec["plant"], n, m,
             len(scene.points), metrics["seconds"])
    return metrics


def _plant_metrics(scene: FieldScene, settings: dict, traced: dict[str, FieldFlux], left_out: dict,
                   effects: dict) -> dict:
    """The contents of flux.json (module docstring)."""
    receiver = scene.receiver
    pixel, area = receiver.pixel_size, receiver.pixel_area
    maps = {m: traced[m].flux.cpu().numpy() for m in MAPS}
    spots = {m: traced[m].asked_spots().cpu().numpy() for m in MAPS} if traced["ideal"].spots is not None else None
    rows: dict[str, dict[str, Any]] = {}
    for i, point in enumerate(scene.points):
        c = maps["calibrated"][i]
        on = float(c.sum()) * area
        reflected = {m: float(traced[m].budget["reflected"][i].sum()) for m in MAPS}
        row: dict[str, Any]
        row = {"sun_deg": [settings["sun"][point]["azimuth_deg"], settings["sun"][point]["elevation_deg"]],
               "calibrated": {"peak_flux_kw_m2": float(c.max()) / 1e3, "power_on_receiver_kw": on / 1e3,
                              "intercept": on / reflected["calibrated"]},
               "ideal": map_metrics(maps["ideal"][i], c, pixel, reflected["ideal"], on / reflected["calibrated"]),
               "heliostats": {}}
        if spots is not None:
            where = {m: _spot_place(spots[m][i], receiver, area) for m in MAPS}
            for j, k in enumerate(scene.measured):
                (ci, pi), (cc, pc) = (tuple(v[j] for v in where[m]) for m in MAPS)
                shift = float(np.hypot(*(cc - ci)))
                row["heliostats"][scene.names[k]] = {
                    "centroid_ideal_m": [round(float(v), 4) for v in ci],
                    "centroid_calibrated_m": [round(float(v), 4) for v in cc],
                    "shift_m": None if math.isnan(shift) else round(shift, 4),
                    "on_receiver_ideal_kw": float(pi) / 1e3, "on_receiver_calibrated_kw": float(pc) / 1e3}
        rows[point] = row
    moved = [(h["shift_m"], name, p) for p, r in rows.items() for name, h in r["heliostats"].items()
             if h["shift_m"] is not None]  # a spot that misses the receiver has no centroid
    worst = max(moved, default=None)
    return {
        "heliostats": len(scene.names),
        "calibrated": [scene.names[k] for k in scene.measured],
        "effects": effects,
        "left_out": left_out,
        "summary": {"ideal_against_calibrated": mean_metrics([r["ideal"] for r in rows.values()]),
                    "calibrated": mean_metrics([r["calibrated"] for r in rows.values()]),
                    "mean_spot_shift_m": float(np.mean([m[0] for m in moved])) if moved else None,
                    "largest_spot_shift": None if worst is None else
                    {"heliostat": worst[1], "design_point": worst[2], "shift_m": worst[0]}},
        "design_points": rows,
        "notes": {"ideal": "the ideal map scored against the calibrated one (field.metrics.map_metrics)",
                  "shift_m": "how far calibration moves the heliostat's spot centroid on the receiver",
                  "units": "flux kW/m^2, power kW, lengths m (centroids: right, up from the receiver centre)"},
    }


def write_plant_flux(path: str | os.PathLike, scene: FieldScene, spec: dict, traced: dict[str, FieldFlux],
                     effects: dict) -> None:
    """flux.h5 (schema helioflow.plant_flux/1):

        ideal, calibrated               (S, H, W) float32 flux (W/m^2), rows top first
        design_points                   (S,) names;  sun/azimuth_deg, sun/elevation_deg (S,)
        heliostats/names, position_m, aim_m, calibrated   (N,), (N, 3), (N, 3), (N,) bool
        budget/<ideal|calibrated>/<term>                  (S, N) power budget terms (W), physics.field.BUDGET_TERMS
        spots/names                                       (M,) the calibrated heliostats
        spots/<ideal|calibrated>                          (S, M, H, W) float32 their spots in either map
    root attributes: plant, receiver geometry, the traced effects, config_hash.
    """
    flags = np.zeros(len(scene.names), dtype=bool)
    flags[scene.measured] = True
    settings = spec["settings"]
    arrays = {m: traced[m].flux.cpu().numpy().astype(np.float32) for m in MAPS}
    arrays.update({
        "design_points": np.array(scene.points, dtype=str),
        "sun/azimuth_deg": np.array([settings["sun"][p]["azimuth_deg"] for p in scene.points], dtype=np.float64),
        "sun/elevation_deg": np.array([settings["sun"][p]["elevation_deg"] for p in scene.points], dtype=np.float64),
        "heliostats/names": np.array(scene.names, dtype=str),
        "heliostats/position_m": np.array([h.position.tolist() for h in scene.true], dtype=np.float64),
        "heliostats/aim_m": scene.aims.cpu().numpy(),
        "heliostats/calibrated": flags,
        "spots/names": np.array([scene.names[k] for k in scene.measured], dtype=str),
    })
    if scene.measured:
        arrays.update({f"spots/{m}": traced[m].asked_spots().cpu().numpy().astype(np.float32) for m in MAPS})
    arrays.update({f"budget/{m}/{term}": traced[m].budget[term].cpu().numpy() for m in MAPS for term in BUDGET_TERMS})
    r = scene.receiver
    attrs = {"plant": spec["plant"], "receiver_center_m": r.center.tolist(), "receiver_normal": r.normal.tolist(),
             "receiver_size_m": [r.width, r.height], "effects": effects,
             "units": {"maps": "W/m^2", "budget": "W", "angles": "deg", "lengths": "m"},
             "conventions": "ENU frame (m, origin at the tower base); maps: rows from the receiver's top edge, "
                            "columns to the right as seen from the field",
             "config_hash": config_hash(spec)}
    write_arrays(path, arrays, attrs, SCHEMA, units={m: "W/m^2" for m in MAPS})
