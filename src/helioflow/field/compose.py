"""Rule `compose_field`: a heliostat field's flux maps on the receiver, truth, ideal and hybrid, for
each sun design point; their metrics against truth; the figure.

    truth   the world physics (world.effects with field.world_effects): every heliostat with its
            true geometry, made by the `surfaces` rule's function from its generated config entry
            (template + position + seed; helioflow.workflow.field_heliostats), shading, blocking
            and attenuation as the world has them (physics.field.field_flux).
    ideal   the model physics (model.effects with field.model_effects; a "fit" value takes the
            registry default: nothing is fitted here) with every heliostat ideal: what a plant
            computes today.
    hybrid  the ideal map without the measured heliostats' spots, plus for each measured heliostat
            its model's spot. A physics model (drt, raytrace) knows its heliostat: its spot is
            traced on the receiver with the fitted tracking, canting, surface and slope error, in
            one field trace beside the ideal neighbours (`traced_spots`). A learned model's spot is
            asked for at the equivalent calibration sun, carried from the calibration target to the
            receiver (physics.carry), and multiplied by what the calibration never saw, from the
            ideal map's budget and the model physics: (1 - shaded / incident) (1 - blocked /
            reflected) T(D_r) / T(D_c), T the model's atmospheric transmittance at the slant ranges
            to the receiver aim point and to the calibration target. Carrying a canted heliostat's
            spot misses how its facets' images close in between target and receiver (docs/field.md),
            which tracing the fit does not.

The carrying error: for every measured heliostat the true spot on the calibration target (traced
with the calibration dataset's own world effects and trace settings, no camera) is carried the
same way, with the truth budget's factors and the worlds' transmittances, and compared with the
heliostat's true spot on the receiver ("carried_truth" in the metrics): what carrying alone costs
a model that were perfect on the calibration target.

Outputs: flux.h5 (schema helioflow.field/1, see `write_flux`), metrics.json (see
`compose_field`), flux.png (field/figure.py).
"""

from __future__ import annotations

import json
import logging
import math
import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor

from helioflow.data.hdf5 import read_dataset, write_arrays
from helioflow.data.surfaces import HeliostatSpec, true_heliostat
from helioflow.data.synthetic import config_hash
from helioflow.device import resolve_device
from helioflow.errors import ConfigError, DataError
from helioflow.field.figure import plot_field_maps
from helioflow.field.metrics import map_metrics, mean_metrics, spot_metrics
from helioflow.io import write_text_atomic
from helioflow.models.base import SpotModel
from helioflow.models.registry import load_model
from helioflow.physics.carry import carry_spot, commanded_normal, core_spread, equivalent_sun
from helioflow.physics.effects import FIT, REGISTRY, TENSOR_EFFECTS, resolve
from helioflow.physics.field import BUDGET_TERMS, FieldFlux, FieldHeliostats, field_flux, flat_receiver
from helioflow.physics.geometry import azimuth_elevation, normalize, sun_vector
from helioflow.physics.heliostat import Heliostat
from helioflow.physics.raytrace import Optics, trace
from helioflow.physics.scene import effective_tensors, with_tensors
from helioflow.physics.target import Target

log = logging.getLogger(__name__)

SCHEMA = "helioflow.field/1"
MAPS = ("truth", "ideal", "hybrid")
SPOTS = ("truth", "ideal", "hybrid", "carried_truth")  # per measured heliostat


def aim_points(receiver: Target, aim: dict, n: int) -> Tensor:
    """(n, 3) ENU aim points (m). kind center: the receiver centre; kind vertical: heliostat i aims
    at level i mod `levels` of `levels` heights evenly spread over `spread` of the receiver height
    (fraction), centred, along the receiver's up axis."""
    centre = receiver.center.expand(n, 3).clone()
    if aim["kind"] == "center":
        return centre
    levels = aim["levels"]
    offsets = torch.arange(n, dtype=centre.dtype, device=centre.device) % levels / (levels - 1) - 0.5
    return centre + (aim["spread"] * receiver.height * offsets)[:, None] * receiver.axes()[1]


def without_fit(effects: dict) -> dict:
    """An effect list with every "fit" value replaced by the registry default (a per-facet tensor
    marked "fit" is left out: the heliostat's own values, zero for an ideal heliostat)."""
    out: dict[str, dict] = {}
    for name, params in (effects or {}).items():
        out[name] = {}
        for key, value in (params or {}).items():
            if value != FIT:
                out[name][key] = value
            elif not REGISTRY[name].parameter(key).array:
                out[name][key] = REGISTRY[name].parameter(key).default
    return out


@dataclass
class FieldScene:
    """The field: N heliostats, S design points, M measured heliostats.

    Attributes:
        names: N heliostat names; true: their true geometries (float64, ENU pivots).
        receiver: the receiver plane; aims: (N, 3) aim points (m).
        points: S design point names; azimuth, elevation: (S,) sun positions (rad).
        measured: M layout indices of the measured heliostats.
    """

    names: list[str]
    true: list[Heliostat]
    receiver: Target
    aims: Tensor
    points: list[str]
    azimuth: Tensor
    elevation: Tensor
    measured: list[int]


def build_scene(spec: dict, device: torch.device) -> FieldScene:
    """The field of a compose_field spec (helioflow.workflow.compose_field_params)."""
    h = spec["heliostats"]
    true = [
        true_heliostat(HeliostatSpec.from_config(name, {**spec["template"], "position_m": p, "seed": seed}))
        for name, p, seed in zip(h["names"], h["positions_m"], h["seeds"])
    ]
    r = spec["receiver"]
    receiver = flat_receiver(
        torch.tensor(r["center_m"], device=device),
        torch.tensor(r["normal"], device=device),
        r["width_m"],
        r["height_m"],
        r["resolution"],
    )
    missing = sorted(set(spec["measured"]) - set(h["names"]))
    if missing:
        raise ConfigError(f"field: measured heliostat {missing[0]!r} is not in the field")
    points = list(spec["sun"])
    az, el = (
        torch.tensor([math.radians(spec["sun"][p][k]) for p in points], dtype=torch.float64, device=device)
        for k in ("azimuth_deg", "elevation_deg")
    )
    return FieldScene(
        h["names"],
        true,
        receiver,
        aim_points(receiver, spec["aim"], len(true)),
        points,
        az,
        el,
        [h["names"].index(m) for m in spec["measured"]],
    )


def trace_field(
    scene: FieldScene, effects: dict, heliostats: list[Heliostat], dni: float, cells: int, device: torch.device,
    slope_error: dict[int, float] | None = None,
) -> tuple[FieldFlux, Optics]:
    """The field's flux maps and budgets (spots of the measured heliostats included) under one
    effect list, and its optics; `slope_error` {index: rad}: heliostats with their own slope error
    (the others take the effect list's)."""
    physics = [resolve(effects, h, dni) for h in heliostats]
    common = physics[0].optics.slope_error
    own = [slope_error.get(i, common) for i in range(len(heliostats))] if slope_error else None
    field = FieldHeliostats.stack(
        [p.heliostat.to(device, torch.float64) for p in physics], cells, torch.float64, own
    )
    with torch.no_grad():
        flux = field_flux(
            field,
            scene.receiver,
            scene.azimuth,
            scene.elevation,
            physics[0].optics,
            blocking_shading=physics[0].blocking_shading,
            aim_points=scene.aims,
            spots=scene.measured,
        )
    return flux, physics[0].optics


@dataclass
class Calibration:
    """One measured heliostat's calibration: its model, target and world.

    Attributes:
        model, scale: the learned model and its image scale (W/m^2 per normalised unit).
        target: the calibration target (float64) whose images the model predicts.
        world_effects, trace: the calibration dataset's world effects and trace settings.
        train_sun: (K, 3) unit sun vectors of the dataset's train split.
    """

    model: SpotModel
    scale: float
    target: Target
    world_effects: dict
    trace: dict
    train_sun: Tensor


def load_calibration(
    name: str, model_path: str | os.PathLike, dataset_path: str | os.PathLike, device: torch.device
) -> Calibration:
    """A measured heliostat's model and calibration dataset; DataError when they belong to another
    heliostat or the model cannot be steered by the sun position."""
    ds = read_dataset(dataset_path)
    if ds.attrs.get("heliostat") != name:
        raise DataError(
            f"{dataset_path}: a dataset of heliostat {ds.attrs.get('heliostat')!r}, expected {name!r}"
        )
    model, info = load_model(model_path, device)
    if Path(str(info.get("meta", {}).get("dataset", ""))).stem != Path(dataset_path).stem:
        raise DataError(
            f"{model_path}: trained on {info.get('meta', {}).get('dataset')!r}, not on {dataset_path}"
        )
    if not model.controllable:
        raise DataError(f"{model_path}: network {info['network']!r} cannot be steered by the sun position")
    rows, cols = ds.images.shape[1:]
    width, height = ds.attrs["target_size_m"]

    def t(v) -> Tensor:
        return torch.tensor(v, dtype=torch.float64, device=device)

    target = Target(
        t(ds.attrs["target_center_m"]),
        normalize(t(ds.attrs["target_normal"])),
        float(width),
        float(height),
        (rows, cols),
        t(ds.attrs["aim_point_m"]) if "aim_point_m" in ds.attrs else None,
    )
    train = ds.indices("train")
    train_sun = sun_vector(t(np.radians(ds.azimuth_deg[train])), t(np.radians(ds.elevation_deg[train])))
    return Calibration(
        model,
        float(info["scale"]),
        target,
        ds.attrs.get("world_effects") or {},
        ds.attrs.get("trace") or {"splat": "kernel"},
        train_sun,
    )


def load_calibrations(scene: FieldScene, model_paths: list[str], dataset_paths: list[str], device: torch.device
                      ) -> list[Calibration]:
    """The measured heliostats' calibrations (`load_calibration`), in scene.measured's order."""
    triples = zip(scene.measured, model_paths, dataset_paths)
    return [load_calibration(scene.names[k], m, d, device) for k, m, d in triples]


def _transmittance(optics: Optics, distance: Tensor) -> Tensor:
    return torch.ones_like(distance) if optics.transmittance is None else optics.transmittance(distance)


def _factors(flux: FieldFlux, k: int, optics_r: Optics, optics_c: Optics, d_r: Tensor, d_c: Tensor) -> Tensor:
    """(S,) what the calibration of heliostat k never saw: the unshaded share of
    its incident light, the unblocked share of its reflected light, and the change of atmospheric
    transmittance from the calibration target (optics_c, slant range d_c) to the receiver
    (optics_r, d_r), from a field budget."""
    b = {term: flux.budget[term][:, k] for term in BUDGET_TERMS}
    unshaded = 1 - b["shaded"] / b["incident"].clamp_min(1e-30)
    unblocked = 1 - b["blocked"] / b["reflected"].clamp_min(1e-30)
    return unshaded * unblocked * _transmittance(optics_r, d_r) / _transmittance(optics_c, d_c)


def _carry(images: Tensor, target: Target, scene: FieldScene, k: int, suns: Tensor, optics: Optics) -> Tensor:
    """(S, H, W) the target images (S, Hc, Wc) of heliostat k carried to the receiver, with the beam
    spread of `optics` (the model physics) for the blur the longer path adds."""
    position = scene.true[k].position.to(suns)
    spread = core_spread(optics.sun, optics.slope_error)
    return torch.stack(
        [
            carry_spot(image, target, scene.receiver, position, scene.aims[k], sun, spread)
            for image, sun in zip(images, suns)
        ]
    )


def equivalent_suns(scene: FieldScene, k: int, cal: Calibration) -> tuple[Tensor, Tensor]:
    """Heliostat k's equivalent calibration sun of each design point (physics.carry.equivalent_sun):
    (S, 3) unit vectors and (S, 2) their azimuth, elevation (rad); ConfigError where one is below the
    horizon."""
    name = scene.names[k]
    suns = sun_vector(scene.azimuth, scene.elevation)  # (S, 3)
    position = scene.true[k].position.to(suns)
    equivalent = torch.stack([equivalent_sun(position, scene.aims[k], s, cal.target.aim_point) for s in suns])
    az, el = azimuth_elevation(equivalent)
    for p, e in zip(scene.points, el.tolist()):
        if e <= 0:
            raise ConfigError(
                f"field: for heliostat {name} at design point {p!r} the equivalent calibration sun "
                f"is {math.degrees(e):.1f} deg below the horizon: no calibration image stands in "
                "for it (choose a higher design sun)"
            )
    return equivalent, torch.stack((az, el), -1)


def learned_spots(scene: FieldScene, k: int, cal: Calibration, spec: dict) -> tuple[Tensor, Tensor, Tensor]:
    """Heliostat k's learned spots on the calibration target at the equivalent sun of each design point:
    (S, 3) equivalent sun vectors, (S, 2) their azimuth, elevation (rad) (`equivalent_suns`), (S, Hc,
    Wc) flux (W/m^2)."""
    equivalent, az_el = equivalent_suns(scene, k, cal)
    az, el = az_el.unbind(-1)
    generator = torch.Generator().manual_seed(spec["seed"])
    with torch.no_grad():
        learned = cal.model.predict(
            torch.rad2deg(az).float().cpu(), torch.rad2deg(el).float().cpu(), generator
        )
    return equivalent, az_el, learned.to(device=scene.aims.device, dtype=torch.float64) * cal.scale


def hybrid_spot(scene: FieldScene, k: int, cal: Calibration, learned: Tensor, ideal: FieldFlux,
                optics: Optics) -> Tensor:
    """(S, H, W) heliostat k's hybrid spot on the receiver (W/m^2): its learned target spots (S, Hc, Wc)
    carried there with the model physics `optics`, times what the calibration never saw, from the
    ideal field's budget (module docstring)."""
    suns = sun_vector(scene.azimuth, scene.elevation)
    position = scene.true[k].position.to(suns)
    d_r, d_c = (scene.aims[k] - position).norm(), (cal.target.aim_point - position).norm()
    factor = _factors(ideal, k, optics, optics, d_r, d_c)
    return _carry(learned, cal.target, scene, k, suns, optics) * factor[:, None, None]


def as_fitted(model: SpotModel) -> tuple[Heliostat, float | None] | None:
    """(the heliostat (float64, CPU) with a physics model's fitted tracking, canting and surface, its
    fitted slope error (rad) or None where the fit has none); None for a model that is not a fitted
    physics model (a network)."""
    heliostat, fitted = getattr(model, "heliostat", None), getattr(model, "fitted", None)
    if heliostat is None or fitted is None:
        return None
    tensors = {k: v.detach().cpu().double() for k, v in fitted.tensors.items()}
    slope = (fitted.effects.get("slope_error") or {}).get("sigma_mrad")
    own = float(slope) * 1e-3 if isinstance(slope, (int, float)) else None
    return with_tensors(heliostat.to("cpu", torch.float64), effective_tensors(tensors)), own


def traced_spots(scene: FieldScene, measured: list[int], cals: list[Calibration], effects: dict, dni: float,
                 cells: int, device: torch.device) -> dict[int, tuple[Tensor, Tensor]]:
    """{layout index: ((S, H, W) W/m^2, (S,) W)} the receiver spots and reflected powers of the
    heliostats `measured` (layout indices, their calibrations `cals`) whose model is a fitted
    physics model (`as_fitted`): one
    field trace under the model physics `effects` (no "fit" values) with those heliostats as fitted
    and every other one ideal, so shading and blocking are the tracer's. Every heliostat in
    `measured` must be among the scene's asked spots (scene.measured)."""
    geometry, slopes, fits = [h.ideal() for h in scene.true], {}, []
    for k, cal in zip(measured, cals):
        fit = as_fitted(cal.model)
        if fit is None:
            continue
        geometry[k], own = fit
        fits.append(k)
        if own is not None:
            slopes[k] = own
    if not fits:
        return {}
    own_tensors = {**effects, **{name: {} for name in TENSOR_EFFECTS}}  # each heliostat's own (fitted or none)
    flux, _ = trace_field(scene, own_tensors, geometry, dni, cells, device, slopes)
    spots = flux.asked_spots()
    return {k: (spots[:, scene.measured.index(k)], flux.budget["reflected"][:, k]) for k in fits}


def measured_spots(
    scene: FieldScene,
    k: int,
    j: int,
    cal: Calibration,
    truth: FieldFlux,
    ideal: FieldFlux,
    optics: dict[str, Optics],
    spec: dict,
    traced: tuple[Tensor, Tensor] | None = None,
) -> tuple[dict[str, Tensor], dict]:
    """Heliostat k's (the j-th measured) spots {SPOTS: (S, H, W) W/m^2} and its details: equivalent
    sun positions (deg), their angle to the nearest train image's sun (deg), the reflected power (W)
    the hybrid map books for it, and how its hybrid spot was made. `traced`: its fit's spot and
    reflected power traced on the receiver (`traced_spots`), a physics model's, which is then not
    asked for its target spots; None: its learned spot carried, its power from that spot."""
    device = scene.aims.device
    suns = sun_vector(scene.azimuth, scene.elevation)  # (S, 3)
    position = scene.true[k].position.to(suns)
    equivalent, az_el = equivalent_suns(scene, k, cal)
    az, el = az_el.unbind(-1)
    calibration = resolve(cal.world_effects, scene.true[k], spec["dni_w_m2"])
    with torch.no_grad():
        true_target = trace(
            calibration.heliostat.to(device, torch.float64),
            cal.target,
            az,
            el,
            calibration.optics,
            rays=cal.trace.get("rays", 0),
            splat=cal.trace["splat"],
            cells_per_side=cal.trace.get("cells_per_side", 32),
            seed=spec["seed"],
        )
    d_r, d_c = (scene.aims[k] - position).norm(), (cal.target.aim_point - position).norm()
    truth_factor = _factors(truth, k, optics["world"], calibration.optics, d_r, d_c)
    if traced is None:
        _, _, learned = learned_spots(scene, k, cal, spec)
        normals = torch.stack([commanded_normal(position, scene.aims[k], s) for s in suns])
        incidence = (normals * suns).sum(-1) / (normals * equivalent).sum(-1)
        unshaded = 1 - ideal.budget["shaded"][:, k] / ideal.budget["incident"][:, k]
        learned_w = learned.sum((-2, -1)) * cal.target.pixel_area
        hybrid, reflected = (hybrid_spot(scene, k, cal, learned, ideal, optics["model"]),
                             learned_w * incidence * unshaded / _transmittance(optics["model"], d_c))
    else:
        hybrid, reflected = traced
    spots = {
        "truth": truth.asked_spots()[:, j],
        "ideal": ideal.asked_spots()[:, j],
        "hybrid": hybrid,
        "carried_truth": _carry(true_target, cal.target, scene, k, suns, optics["model"])
        * truth_factor[:, None, None],
    }
    nearest = torch.rad2deg(torch.acos((equivalent @ cal.train_sun.T).clamp(-1, 1).amax(-1)))
    details = {
        "equivalent_sun_deg": torch.rad2deg(az_el).tolist(),
        "nearest_calibration_deg": nearest.tolist(),
        "reflected_w": reflected.tolist(),
        "hybrid_from": "carried learned spot" if traced is None else "traced fit",
    }
    return spots, details


def compose_field(
    spec: dict,
    model_paths: list[str],
    dataset_paths: list[str],
    flux_path: str | os.PathLike,
    figure_path: str | os.PathLike,
    metrics_path: str | os.PathLike,
) -> dict:
    """The `compose_field` rule: write flux.h5, flux.png and metrics.json; return the metrics.

    Args:
        spec: the rule's parameters (helioflow.workflow.compose_field_params).
        model_paths, dataset_paths: models/<heliostat>/<network>.pt and datasets/<heliostat>.h5 of
            the measured heliostats, in the order of spec["measured"].

    metrics.json: per design point the truth map's peak, power and intercept; for the ideal and
    hybrid maps every field_metrics.MAP_METRICS against truth; per measured heliostat its
    equivalent sun, the angle to the nearest calibration image, and SPOT_METRICS of its ideal,
    hybrid and carried-truth spots against its true spot. `summary` holds their means over
    design points (and measured heliostats); `seconds` the wall time.
    """
    start = time.perf_counter()
    if not (len(model_paths) == len(dataset_paths) == len(spec["measured"])):
        raise ConfigError(
            f"compose-field: {len(spec['measured'])} measured heliostats, but {len(model_paths)} "
            f"models and {len(dataset_paths)} datasets"
        )
    device = resolve_device(spec["device"])
    scene = build_scene(spec, device)
    dni, cells = spec["dni_w_m2"], spec["cells_per_side"]
    truth, world_optics = trace_field(scene, spec["world_effects"], scene.true, dni, cells, device)
    ideal, model_optics = trace_field(
        scene, without_fit(spec["model_effects"]), [h.ideal() for h in scene.true], dni, cells, device
    )
    optics = {"world": world_optics, "model": model_optics}
    collected: dict[str, list[Tensor]] = {s: [] for s in SPOTS}
    details = []
    cals = load_calibrations(scene, model_paths, dataset_paths, device)
    traced = traced_spots(scene, scene.measured, cals, without_fit(spec["model_effects"]), dni, cells, device)
    for j, (k, cal) in enumerate(zip(scene.measured, cals)):
        heliostat_spots, heliostat_details = measured_spots(scene, k, j, cal, truth, ideal, optics, spec,
                                                            traced.get(k))
        for s in SPOTS:
            collected[s].append(heliostat_spots[s])
        details.append(heliostat_details)
    stacked = {s: torch.stack(v, 1) for s, v in collected.items()}  # (S, M, H, W)
    flux = {
        "truth": truth.flux,
        "ideal": ideal.flux,
        "hybrid": (ideal.flux - ideal.asked_spots().sum(1) + stacked["hybrid"].sum(1)).clamp_min(0.0),
    }
    maps = {m: v.cpu().numpy() for m, v in flux.items()}
    spots = {s: v.cpu().numpy() for s, v in stacked.items()}
    metrics = _field_metrics(scene, spec, truth, ideal, maps, spots, details)
    metrics["seconds"] = round(time.perf_counter() - start, 2)
    write_flux(flux_path, scene, spec, maps, spots, details, {"truth": truth, "ideal": ideal})
    write_text_atomic(metrics_path, json.dumps(metrics, indent=2) + "\n")
    sun_deg = np.degrees(torch.stack((scene.azimuth, scene.elevation), -1).cpu().numpy())
    plot_field_maps(
        figure_path,
        maps,
        "truth",
        scene.points,
        sun_deg,
        [metrics["design_points"][p] for p in scene.points],
        np.array(spec["heliostats"]["positions_m"]),
        scene.measured,
        (scene.receiver.width, scene.receiver.height),
        f"{len(scene.names)} heliostats, {len(scene.measured)} measured with {spec['network']}: "
        "truth (world), ideal (model raytrace), hybrid (measured heliostats by their models + raytrace)",
    )
    log.info(
        "field: %d heliostats, %d design points in %.1f s",
        len(scene.names),
        len(scene.points),
        metrics["seconds"],
    )
    return metrics


def _field_metrics(
    scene: FieldScene, spec: dict, truth: FieldFlux, ideal: FieldFlux, maps: dict, spots: dict, details: list[dict]
) -> dict:
    """The contents of metrics.json (see compose_field)."""
    pixel = scene.receiver.pixel_size
    ideal_reflected = ideal.budget["reflected"].cpu()
    learned = np.sum([d["reflected_w"] for d in details], axis=0)  # (S,) W, the measured heliostats' own
    reflected = {
        "truth": truth.budget["reflected"].sum(-1).tolist(),
        "ideal": ideal_reflected.sum(-1).tolist(),
        "hybrid": (
            ideal_reflected.sum(-1) - ideal_reflected[:, scene.measured].sum(-1) + torch.as_tensor(learned)
        ).tolist(),
    }
    points: dict[str, dict[str, Any]] = {}
    for i, point in enumerate(scene.points):
        t = maps["truth"][i]
        on = float(t.sum()) * pixel[0] * pixel[1]
        row: dict[str, Any] = {
            "sun_deg": [spec["sun"][point]["azimuth_deg"], spec["sun"][point]["elevation_deg"]],
            "truth": {
                "peak_flux_kw_m2": float(t.max()) / 1e3,
                "power_on_receiver_kw": on / 1e3,
                "intercept": on / reflected["truth"][i],
            },
        }
        for m in MAPS[1:]:
            row[m] = map_metrics(maps[m][i], t, pixel, reflected[m][i], row["truth"]["intercept"])
        row["measured"] = {
            scene.names[k]: {
                "equivalent_sun_deg": d["equivalent_sun_deg"][i],
                "nearest_calibration_deg": d["nearest_calibration_deg"][i],
                "hybrid_from": d["hybrid_from"],
                **{s: spot_metrics(spots[s][i, j], spots["truth"][i, j], pixel) for s in SPOTS[1:]},
            }
            for j, (k, d) in enumerate(zip(scene.measured, details))
        }
        points[point] = row
    per_heliostat = [h for row in points.values() for h in row["measured"].values()]
    summary: dict[str, Any] = {m: mean_metrics([row[m] for row in points.values()]) for m in MAPS[1:]}
    summary["measured_heliostats"] = {s: mean_metrics([h[s] for h in per_heliostat]) for s in SPOTS[1:]}
    return {
        "network": spec["network"],
        "heliostats": len(scene.names),
        "measured": [scene.names[k] for k in scene.measured],
        "summary": summary,
        "design_points": points,
        "notes": {
            "carried_truth": "the true calibration-target spot carried to the receiver against the true "
            "receiver spot: the error that carrying alone adds",
            "units": "flux kW/m^2, power kW, errors relative (peak, power, intercept: absolute), "
            "centroid m, angles deg",
        },
    }


def write_flux(
    path: str | os.PathLike,
    scene: FieldScene,
    spec: dict,
    maps: dict,
    spots: dict,
    details: list[dict],
    budgets: dict[str, FieldFlux],
) -> None:
    """flux.h5 (schema helioflow.field/1):

        truth, ideal, hybrid            (S, H, W) float32 flux (W/m^2), rows top first
        design_points                   (S,) names;  sun/azimuth_deg, sun/elevation_deg (S,)
        heliostats/names, position_m, aim_m, measured   (N,), (N, 3), (N, 3), (N,) bool
        budget/<truth|ideal>/<term>     (S, N) power budget terms (W), physics.field.BUDGET_TERMS
        measured/names                  (M,)
        measured/<truth|ideal|hybrid|carried_truth>   (S, M, H, W) float32 spots of the measured heliostats
        measured/equivalent_sun_deg     (M, S, 2) azimuth, elevation of the equivalent calibration sun
    root attributes: receiver geometry, network, world and model effects, config_hash.
    """
    measured = np.zeros(len(scene.names), dtype=bool)
    measured[scene.measured] = True
    arrays = {m: maps[m].astype(np.float32) for m in MAPS}
    arrays.update(
        {
            "design_points": np.array(scene.points, dtype=str),
            "sun/azimuth_deg": np.array(
                [spec["sun"][p]["azimuth_deg"] for p in scene.points], dtype=np.float64
            ),
            "sun/elevation_deg": np.array(
                [spec["sun"][p]["elevation_deg"] for p in scene.points], dtype=np.float64
            ),
            "heliostats/names": np.array(scene.names, dtype=str),
            "heliostats/position_m": np.array(spec["heliostats"]["positions_m"], dtype=np.float64),
            "heliostats/aim_m": scene.aims.cpu().numpy(),
            "heliostats/measured": measured,
            "measured/names": np.array([scene.names[k] for k in scene.measured], dtype=str),
            "measured/equivalent_sun_deg": np.array(
                [d["equivalent_sun_deg"] for d in details], dtype=np.float64
            ),
        }
    )
    arrays.update({f"measured/{s}": spots[s].astype(np.float32) for s in SPOTS})
    arrays.update(
        {
            f"budget/{m}/{term}": f.budget[term].cpu().numpy()
            for m, f in budgets.items()
            for term in BUDGET_TERMS
        }
    )
    r = spec["receiver"]
    attrs = {
        "receiver_center_m": r["center_m"],
        "receiver_normal": scene.receiver.normal.tolist(),
        "receiver_size_m": [r["width_m"], r["height_m"]],
        "network": spec["network"],
        "world_effects": spec["world_effects"],
        "model_effects": spec["model_effects"],
        "units": {"maps": "W/m^2", "budget": "W", "angles": "deg", "lengths": "m"},
        "conventions": "ENU frame (m, origin at the tower base); maps: rows from the receiver's top edge, "
        "columns to the right as seen from the field",
        "config_hash": config_hash(spec),
    }
    write_arrays(path, arrays, attrs, SCHEMA, units={m: "W/m^2" for m in MAPS})
