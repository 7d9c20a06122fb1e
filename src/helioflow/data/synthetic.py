"""Synthetic calibration datasets: trace a heliostat's focal spots for many sun positions (rule `trace`)."""

from __future__ import annotations

import hashlib
import json
import logging
import math
import os

import numpy as np
import torch

from helioflow import __version__
from helioflow.data.hdf5 import CalibrationDataset, write_dataset
from helioflow.data.splits import assign_splits
from helioflow.data.surfaces import read_heliostat
from helioflow.device import resolve_device
from helioflow.errors import DataError
from helioflow.physics.effects import Physics, resolve
from helioflow.physics.geometry import normalize
from helioflow.physics.heliostat import canting_focal_distance
from helioflow.physics.raytrace import trace
from helioflow.physics.sun import rms_radius
from helioflow.physics.target import Target

log = logging.getLogger(__name__)

FILL_THRESHOLD = 0.1  # a pixel is "in the spot" above this fraction of the image's peak
MIN_FILL = 0.10  # the window is sized so that at least this fraction of pixels is in the spot
CONVENTIONS = (
    "ENU frame (x east, y north, z up; m; origin at the tower base); sun azimuth 0 = south, +90 = east, "
    "-90 = west; elevation above the horizon; images[i, r, c]: row r from the top edge of the target "
    "window, column c to the right as seen from the field; flux in W/m^2 for the DNI in attribute dni_w_m2"
)


def sun_positions(sun: dict, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(azimuth_deg, elevation_deg), each (N,), from a dataset's `sun` section.

    scan: fixed azimuth, elevation in n equal steps from the first to the last value;
    hemisphere: n positions uniform in solid angle within the azimuth and elevation ranges
    (sin(elevation) uniform), drawn with `sun.seed` (default: the experiment seed);
    list: the given [azimuth, elevation] pairs.
    """
    if sun["kind"] == "scan":
        first, last = sun["elevation_deg"]
        el = np.linspace(first, last, sun["n"])
        return np.full_like(el, float(sun["azimuth_deg"])), el
    if sun["kind"] == "hemisphere":
        rng = np.random.default_rng(sun.get("seed", seed))
        west, east = sun["azimuth_deg"]
        az = rng.uniform(west, east, sun["n"])
        lo, hi = np.sin(np.radians(sun["elevation_deg"]))
        return az, np.degrees(np.arcsin(rng.uniform(lo, hi, sun["n"])))
    pos = np.asarray(sun["positions_deg"], dtype=float)
    return pos[:, 0], pos[:, 1]


def config_hash(spec: dict) -> str:
    """sha256 of the canonical JSON of a rule's parameters (what the output depends on)."""
    return hashlib.sha256(json.dumps(spec, sort_keys=True).encode()).hexdigest()


def trace_dataset(spec: dict, heliostat_path: str | os.PathLike, output_path: str | os.PathLike) -> CalibrationDataset:
    """Trace one calibration dataset and write it to `output_path` (atomically).

    Args:
        spec: the rule's parameters, built by helioflow.workflow.trace_params: dataset name, sun,
            splits, trace settings, window_m, target, world effects, dni_w_m2, seed, device.
        heliostat_path: the heliostat's true geometry (surfaces/{heliostat}.h5).
        output_path: datasets/{dataset}.h5.
    """
    device = resolve_device(spec["device"])
    az_deg, el_deg = sun_positions(spec["sun"], spec["seed"])
    physics = resolve(spec["world_effects"], read_heliostat(heliostat_path), spec["dni_w_m2"])
    heliostat = physics.heliostat.to(device)
    t = spec["target"]
    centre = torch.tensor(t["center_m"], dtype=torch.float32, device=device)
    normal = normalize(torch.tensor(t["normal"], dtype=torch.float32, device=device))
    az = torch.tensor(np.radians(az_deg), dtype=torch.float32, device=device)
    el = torch.tensor(np.radians(el_deg), dtype=torch.float32, device=device)
    settings = spec["trace"]
    window = spec["window_m"]
    if window == "auto":
        window = auto_window(physics, heliostat, centre, normal, az, el, settings)
        log.info("auto window: %.3f m", window)
    target = Target(centre, normal, window, window, tuple(t["resolution"]))
    images = trace_images(physics, heliostat, target, az, el, settings, spec["seed"])
    check_on_target(images, az_deg, el_deg, spec["dataset"])
    fill = (images > FILL_THRESHOLD * images.amax((-2, -1), keepdim=True)).double().mean((-2, -1)).cpu().numpy()
    log.info("fill fraction (pixels above %.0f%% of the peak): min %.3f, median %.3f", 100 * FILL_THRESHOLD,
             fill.min(), np.median(fill))
    if fill.min() < MIN_FILL:
        log.warning("%d images have less than %.0f%% of their pixels in the spot", (fill < MIN_FILL).sum(),
                    100 * MIN_FILL)
    dataset = CalibrationDataset(
        images=images.cpu().numpy().astype(np.float32),
        azimuth_deg=az_deg,
        elevation_deg=el_deg,
        split=assign_splits(az_deg, el_deg, spec["splits"], spec["seed"]),
        attrs={
            "dataset": spec["dataset"],
            "heliostat": spec["heliostat"],
            "source": "synthetic (helioflow trace)",
            "units": {"images": "W/m^2", "angles": "deg", "lengths": "m"},
            "conventions": CONVENTIONS,
            "world_effects": spec["world_effects"],
            "trace": settings,
            "dni_w_m2": spec["dni_w_m2"],
            "target_center_m": t["center_m"],
            "target_normal": normal.tolist(),
            "target_size_m": [window, window],
            "heliostat_position_m": heliostat.position.tolist(),
            "heliostat_mount": heliostat.mount,
            "canting_focal_distance_m": canting_focal_distance(heliostat),
            "fill_threshold": FILL_THRESHOLD,
            "fill_fraction_min": float(fill.min()),
            "seed": spec["seed"],
            "config_hash": config_hash(spec),
            "helioflow_version": __version__,
        },
        extras={"fill_fraction": fill},
    )
    write_dataset(output_path, dataset)
    return dataset


def check_on_target(images: torch.Tensor, az_deg: np.ndarray, el_deg: np.ndarray, dataset: str) -> None:
    """DataError when a traced image (S, H, W) holds no flux (or non-finite flux): its spot misses
    the target window, and the dataset would hold empty images."""
    empty = ~(images.flatten(1).isfinite().all(1) & (images.flatten(1).amax(1) > 0)).cpu().numpy()
    if empty.any():
        i = int(np.flatnonzero(empty)[0])
        raise DataError(f"dataset {dataset!r}: the spot misses the target window in {int(empty.sum())} of {len(empty)} "
                        f"images (first: sun azimuth {az_deg[i]:.2f} deg, elevation {el_deg[i]:.2f} deg); check the "
                        "heliostat's position_m, target.center_m and normal, and the dataset's window_m")


def trace_images(physics: Physics, heliostat, target: Target, az, el, settings: dict, seed: int,
                 batch: int = 16) -> torch.Tensor:
    """(S, H, W) measured images (world physics + camera), traced in batches of sun positions."""
    batches: list[torch.Tensor] = []
    with torch.no_grad():
        for i, start in enumerate(range(0, len(az), batch)):
            sl = slice(start, start + batch)
            batches.append(trace(heliostat, target, az[sl], el[sl], physics.optics, rays=settings.get("rays", 0),
                                splat=settings["splat"], cells_per_side=settings.get("cells_per_side", 32),
                                seed=seed + i))
            log.info("traced %d / %d sun positions", min(start + batch, len(az)), len(az))
    images = torch.cat(batches)
    return physics.camera.apply(images) if physics.camera is not None else images


def auto_window(physics: Physics, heliostat, centre, normal, az, el, settings: dict) -> float:
    """Side (m) of a square target window that holds every spot's region above FILL_THRESHOLD of
    its peak, with a 10 % margin: traced once at low cost over a generous window."""
    distance = float((centre - heliostat.position).norm())
    extent = float(heliostat.facet_translation[:, :2].abs().amax() * 2 + heliostat.facet_size.amax())
    spread = rms_radius(physics.optics.sun, physics.optics.slope_error) * distance
    pointing = float(heliostat.tracking_error.abs().sum() + heliostat.canting_error.abs().sum()) * 2 * distance
    first = 2.5 * (extent + 3 * spread) + 2 * pointing
    preview = {**settings, "rays": min(settings.get("rays", 0), 200_000), "cells_per_side": 16}
    target = Target(centre, normal, first, first, (96, 96))
    images = trace_images(physics, heliostat, target, az, el, preview, seed=0)
    u, v = target.pixel_centres(images.dtype, images.device)
    inside = images > FILL_THRESHOLD * images.amax((-2, -1), keepdim=True)
    half = torch.maximum((inside * u.abs()[None, None, :]).amax((-2, -1)),
                         (inside * v.abs()[None, :, None]).amax((-2, -1)))
    side = 2 * (float(half.max()) + target.pixel_size[0]) * 1.1
    if not math.isfinite(side) or not images.isfinite().all() or float(images.amax()) <= 0:
        raise DataError(f"window_m: auto could not size the target window: no flux reaches the target plane within "
                        f"{first:.1f} m of its centre; check the heliostat's position_m and target.center_m and normal")
    return math.ceil(side * 100) / 100
