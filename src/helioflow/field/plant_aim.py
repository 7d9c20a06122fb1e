"""Rule `plant_aim`: aim points on a plant's own receiver, chosen on its design and on its calibrated
heliostats, each judged on the calibrated plant (config plant.flux.optimise_aim).

The plant is rule plant_flux's (field.plant.load_plant): every heliostat of the PAINT directory at
its own pivot, the calibrated ones as their fits have them, under the same map effects. As in rule
optimise_aim (field.aiming), each heliostat's spot is traced once aimed at the receiver centre on a
receiver grown by the largest aim move, and field.aim.optimise chooses aim offsets on two models:

    ideal       every heliostat as designed: how a plant aims today
    calibrated  each calibrated heliostat by its fit (kinematics, canting, surface, slope error)

and, with `keep_probability`, `calibrated_margin`: the calibrated map's aiming that keeps the limit
with that probability under the calibrated heliostats' pointing sigma (their fits' tracking
covariance carried to the receiver, field/margin.py). A real plant has no truth to judge on: every
aiming -- `default` (plant.flux.aim) and the optimised ones -- is applied to the calibrated plant and
traced again at its aim points, the best knowledge the calibration gives. On a plant made by an
independent generator (examples/plant_world), scripts/experiments/plant_flux_truth.py --aim judges
the same aim points on the generator's own rays.

plant/aim/<plant>.json, per design point and strategy:
    calibrated_peak_over_limit    the calibrated map's peak flux / the limit at those aim points
    calibrated_intercepted_w      power on the receiver in that map (W)
    calibrated_spillage           share of the power reaching the receiver plane that misses the receiver
    calibrated_area_over_limit    share of the receiver's area over the limit
    model_peak_over_limit         what the strategy's own model (shifted spots) promised
    mean_aim_move_m               mean distance of the aim points from the default aiming (m)
    aim_points_m                  (N, 2) aim points (right, up; m from the receiver centre)
plus, with keep_probability, `model_peak_bound_over_limit` (calibrated, calibrated_margin),
`limit_fraction` and per design point `pointing_sigma_m` (as aim.json's).
With a target distribution (optimise_aim.target), also `calibrated_target_accuracy` and
`model_target_accuracy` (as aim.json's `truth_target_accuracy`, field.aiming).
"""

from __future__ import annotations

import dataclasses
import json
import logging
import os
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor

from helioflow.device import resolve_device
from helioflow.field.aim import Goal, limit_text
from helioflow.field.aiming import choose_aims, extended_receiver, judge, judge_aimings, margin_aim, promised
from helioflow.field.compose import trace_field
from helioflow.field.figure import plot_aim_maps
from helioflow.field.margin import pointing_covariances
from helioflow.field.plant import Plant, load_plant
from helioflow.io import write_text_atomic
from helioflow.physics.geometry import sun_vector

log = logging.getLogger(__name__)

MODELS = ("ideal", "calibrated")
STRATEGIES = ("default", *MODELS)
MARGIN = "calibrated_margin"


def plant_spots(plant: Plant, spec: dict, region: float, device: torch.device) -> dict[str, Tensor]:
    """{model: (S, N, He, We) W/m^2} every heliostat's spot aimed at the receiver centre on the
    receiver grown by `region` (aiming.extended_receiver), as designed (`ideal`) and as calibrated."""
    scene, n = plant.scene, len(plant.scene.names)
    centred = dataclasses.replace(scene, receiver=extended_receiver(scene.receiver, region),
                                  aims=scene.receiver.center.expand(n, 3).clone(), measured=list(range(n)))
    dni, cells = spec["dni_w_m2"], spec["settings"]["cells_per_side"]
    ideal = trace_field(centred, plant.effects, scene.true, dni, cells, device)[0]
    calibrated = trace_field(centred, plant.effects, plant.fitted, dni, cells, device, plant.slopes)[0]
    return {"ideal": ideal.asked_spots(), "calibrated": calibrated.asked_spots()}


def optimise_plant_aim(spec: dict, json_path: str | os.PathLike, figure_path: str | os.PathLike) -> dict:
    """The `plant_aim` rule for one plant entry: write its aim JSON and figure (module docstring);
    return the JSON's content.

    Args:
        spec: rule plant_flux's spec (helioflow.workflow.plant_flux_spec) whose settings hold
            "optimise_aim": {limit_kw_m2, region, steps, keep_probability, draws}.
    """
    start_time = time.perf_counter()
    settings, device = spec["settings"]["optimise_aim"], resolve_device(spec["device"])
    plant = load_plant(spec, device)
    scene = plant.scene
    goal = Goal.from_settings(settings, scene.receiver.resolution, device)
    probability = settings.get("keep_probability")
    spots = plant_spots(plant, spec, settings["region"], device)
    judged = {"dni_w_m2": spec["dni_w_m2"], "cells_per_side": spec["settings"]["cells_per_side"]}
    start = scene.receiver.to_plane(scene.aims)  # (N, 2) the default aiming
    strategies = (*STRATEGIES, MARGIN) if probability is not None else STRATEGIES
    maps: dict[str, list[np.ndarray]] = {s: [] for s in strategies}
    moves: dict[str, list[np.ndarray]] = {s: [] for s in strategies}
    points: dict[str, Any] = {}
    sigmas: dict[str, dict] = {}
    for i, point in enumerate(scene.points):
        chosen, promises = choose_aims({m: spots[m][i] for m in MODELS}, start, goal, settings, scene.receiver)
        chosen["default"], promises["default"] = start, promised(None, goal)
        margin: dict[str, Any] = {}
        if probability is not None:
            sun = sun_vector(scene.azimuth[i], scene.elevation[i]).double()
            covariances = pointing_covariances(plant.fitted, plant.tracking, sun, scene.aims, scene.receiver)
            chosen[MARGIN], promises[MARGIN], margin = margin_aim(spots["calibrated"][i], start, chosen["calibrated"],
                                                                  goal, settings, covariances, scene.receiver, seed=i)
            sigmas[point] = margin["pointing_sigma_m"]
        points[point] = judge_aimings(
            chosen, promises, start, scene.receiver, "calibrated", maps, moves, margin, "calibrated", MARGIN,
            lambda aims: judge(scene, plant.effects, plant.fitted, i, aims, goal, judged, device, plant.slopes))
    result = {
        "plant": spec["plant"],
        "limit_kw_m2": settings["limit_kw_m2"],
        **({"target": settings["target"]} if settings.get("target") is not None else {}),
        "region": settings["region"],
        "heliostats": scene.names,
        "calibrated": [scene.names[k] for k in scene.measured],
        "effects": plant.effects,
        "design_points": points,
        **({"keep_probability": probability, "pointing_sigma_m": sigmas} if probability is not None else {}),
        "seconds": round(time.perf_counter() - start_time, 2),
        "notes": {
            "calibrated_*": "each strategy's aim points applied to the calibrated plant and traced there",
            "model_peak_over_limit": "what the strategy's own model (shifted spots) promised",
            "aim_points_m": "per heliostat, in `heliostats` order, (right, up) on the receiver from its centre (m)",
            "units": "flux limit kW/m^2, power W, lengths m",
        },
    }
    Path(json_path).parent.mkdir(parents=True, exist_ok=True)
    write_text_atomic(json_path, json.dumps(result, indent=2) + "\n")
    plot_aim_maps(
        figure_path, maps, moves,
        scene.points, goal.limit, (scene.receiver.width, scene.receiver.height),
        f"plant entry '{spec['plant']}': {len(scene.names)} heliostats, {len(scene.measured)} calibrated: the "
        f"calibrated plant's flux under each aiming, limit {limit_text(settings['limit_kw_m2'])}",
        ("default", "calibrated"),
    )
    log.info("plant_aim %s: %d heliostats, %d design points in %.1f s", spec["plant"], len(scene.names),
             len(scene.points), result["seconds"])
    return result
