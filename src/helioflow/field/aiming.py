"""Rule `optimise_aim`: aim points chosen on the ideal, the hybrid (calibrated) and the true field,
each judged on the true field, beside the field's default aiming (config field.optimise_aim).

For each sun design point every heliostat's spot is traced once aimed at the receiver centre, on a
receiver grid extended by the largest aim move (field.aim.SpotPatches), under three models:

    ideal   the model physics with every heliostat ideal (compose_field's ideal map, spot by spot)
    hybrid  the ideal spots, the measured heliostats' replaced by their models' spots: a physics
            model's fit traced on the receiver (compose.traced_spots), a learned spot carried there
            (compose.learned_spots, compose.hybrid_spot)
    truth   the world physics with every heliostat's true errors: the oracle, an upper bound

and field.aim.optimise chooses aim offsets on each. Every aiming -- `default` (field.aim) and the
three optimised ones -- is then applied to the true field and traced again at those aim points
(field_flux, shading and blocking at the new orientations), so what aim.json reports as `truth_*` is
what the plant would get, the spot-shift approximation included. The gap between `hybrid` and
`truth` is what the calibration still misses (on a field with unmeasured heliostats: what they cost).

aim.json, per design point and strategy (`default`, `ideal`, `hybrid`, `truth`):
    truth_peak_over_limit     the true map's peak flux / the limit
    truth_intercepted_w       power on the receiver in the true map (W)
    truth_spillage            share of the power reaching the receiver plane that misses the receiver
    truth_area_over_limit     share of the receiver's area where the true flux exceeds the limit
    intercept_of_bound        truth_intercepted_w / that of the `truth` strategy
    model_peak_over_limit     the peak / limit the strategy's own model promised (its shifted map)
    mean_aim_move_m           mean distance of the aim points from the default aiming (m)
plus `aim_points_m` per strategy: (N, 2) aim points on the receiver (right, up; m, from its centre).
With a target distribution (optimise_aim.target) the optimised aimings approach it instead of
maximising the power, and each row adds `truth_target_accuracy` and `model_target_accuracy`
(field.aim.target_accuracy: 1 - sum|F - T| / sum T, T the target carrying the reflected power).
"""

from __future__ import annotations

import dataclasses
import json
import logging
import math
import os
import time
from collections.abc import Callable
from typing import Any

import numpy as np
import torch
from torch import Tensor

from helioflow.device import resolve_device
from helioflow.errors import ConfigError
from helioflow.field.aim import AimResult, Goal, SpotPatches, limit_text, optimise, peak_over_limit, target_accuracy
from helioflow.field.compose import (
    Calibration,
    FieldScene,
    build_scene,
    hybrid_spot,
    learned_spots,
    load_calibrations,
    trace_field,
    traced_spots,
    without_fit,
)
from helioflow.field.figure import plot_aim_maps
from helioflow.field.margin import (
    covered,
    displacement_draws,
    optimise_with_margin,
    peak_quantile,
    pointing_covariances,
    tracking_covariance,
)
from helioflow.io import write_text_atomic
from helioflow.physics.field import flat_receiver
from helioflow.physics.geometry import sun_vector
from helioflow.physics.heliostat import Heliostat
from helioflow.physics.target import Target

log = logging.getLogger(__name__)

MODELS = ("ideal", "hybrid", "truth")
STRATEGIES = ("default", *MODELS)
MARGIN = "hybrid_margin"  # the hybrid's aiming that keeps the limit with keep_probability (field/margin.py)


def extended_receiver(receiver: Target, region: float) -> Target:
    """The receiver grown on every side by `region` of its half extent (rounded up to whole pixels),
    at the same pixel size: the grid on which a spot aimed at the centre is still whole when the aim
    moves to the edge of the aim region."""
    rows, cols = receiver.resolution
    pad_r, pad_c = math.ceil(region * rows / 2), math.ceil(region * cols / 2)
    pw, ph = receiver.pixel_size
    return flat_receiver(
        receiver.center, receiver.normal, receiver.width + 2 * pad_c * pw, receiver.height + 2 * pad_r * ph,
        (rows + 2 * pad_r, cols + 2 * pad_c),
    )


def model_spots(
    spec: dict, scene: FieldScene, region: float, cals: list[Calibration], device: torch.device,
) -> dict[str, Tensor]:
    """{model: (S, N, He, We) W/m^2} every heliostat's spot aimed at the receiver centre on the
    extended receiver, under each of MODELS (module docstring); `cals`: the measured heliostats'
    calibrations (compose.load_calibrations), in scene.measured's order."""
    n = len(scene.names)
    centred = dataclasses.replace(
        scene, receiver=extended_receiver(scene.receiver, region), aims=scene.receiver.center.expand(n, 3).clone(),
        measured=list(range(n)),
    )
    dni, cells = spec["dni_w_m2"], spec["cells_per_side"]
    truth, _ = trace_field(centred, spec["world_effects"], scene.true, dni, cells, device)
    ideal, model_optics = trace_field(
        centred, without_fit(spec["model_effects"]), [h.ideal() for h in scene.true], dni, cells, device
    )
    hybrid = ideal.asked_spots().clone()
    traced = traced_spots(centred, scene.measured, cals, without_fit(spec["model_effects"]), dni, cells, device)
    for k, cal in zip(scene.measured, cals):
        if k in traced:
            hybrid[:, k] = traced[k][0]
            continue
        _, _, learned = learned_spots(centred, k, cal, spec)
        hybrid[:, k] = hybrid_spot(centred, k, cal, learned, ideal, model_optics)
    return {"ideal": ideal.asked_spots(), "hybrid": hybrid, "truth": truth.asked_spots()}


def judge(scene: FieldScene, effects: dict, heliostats: list[Heliostat], point: int, aims: Tensor,
          goal: Goal, spec: dict, device: torch.device, slope_error: dict[int, float] | None = None,
          ) -> tuple[dict[str, float], np.ndarray]:
    """`heliostats` under `effects` at design point `point`, aimed at `aims` ((N, 3) ENU, m), traced
    again (field_flux: shading and blocking at the new orientations): ({peak_over_limit, intercepted_w,
    spillage, area_over_limit, and with the goal's target target_accuracy}, the (H, W) flux map (W/m^2));
    the goal's tensors on `device`; spec: dni_w_m2, cells_per_side; slope_error as trace_field's."""
    one = dataclasses.replace(
        scene, aims=aims, azimuth=scene.azimuth[point:point + 1], elevation=scene.elevation[point:point + 1],
        measured=[],
    )
    flux, _ = trace_field(one, effects, heliostats, spec["dni_w_m2"], spec["cells_per_side"], device, slope_error)
    image = flux.flux[0]
    pw, ph = scene.receiver.pixel_size
    on = float(flux.budget["on_receiver"][0].sum())
    spilled = float(flux.budget["spilled"][0].sum())
    metrics = {
        "peak_over_limit": peak_over_limit(image, goal.limit),
        "intercepted_w": float(image.sum()) * pw * ph,
        "spillage": spilled / max(on + spilled, 1e-30),
        "area_over_limit": float((image > goal.limit).double().mean()),
    }
    if goal.target is not None:
        metrics["target_accuracy"] = target_accuracy(image, goal.target, on + spilled, pw * ph)
    return metrics, image.cpu().numpy()


def choose_aims(spots: dict[str, Tensor], start: Tensor, goal: Goal, settings: dict, receiver: Target
                ) -> tuple[dict[str, Tensor], dict[str, dict[str, float | None]]]:
    """({model: (N, 2) aim offsets (m)}, {model: what its own map promises (`promised`)}) optimised
    (field.aim.optimise) for `goal` on each model's (N, He, We) centre-aimed spots on the extended
    receiver, from the (N, 2) `start` offsets; settings: config optimise_aim (region, steps)."""
    chosen: dict[str, Tensor] = {}
    promises: dict[str, dict[str, float | None]] = {}
    for m, maps in spots.items():
        patches = SpotPatches.from_maps(maps, receiver.resolution, receiver.pixel_size)
        result = optimise(patches, start, goal.limit, region=settings["region"], steps=settings["steps"],
                          target=goal.target)
        chosen[m], promises[m] = result.offsets, promised(result, goal)
    return chosen, promises


def judge_aimings(chosen: dict[str, Tensor], promises: dict[str, dict[str, float | None]], start: Tensor,
                  receiver: Target, prefix: str, maps: dict[str, list[np.ndarray]], moves: dict[str, list[np.ndarray]],
                  margin: dict[str, Any], plain: str, with_margin: str,
                  judge_at: Callable[[Tensor], tuple[dict[str, float], np.ndarray]]) -> dict[str, dict[str, Any]]:
    """One design point's row of an aim JSON, in the order of `maps` (the strategies): each strategy's
    (N, 2) aim offsets (m) turned into ENU aim points and judged (`judge_at`: (N, 3) aim points -> metrics,
    (H, W) map), its metrics prefixed `prefix`_, what its own model promised, its mean aim move from
    `start` and its aim points; its map and offsets appended to `maps` and `moves` (the figure's). With a
    `margin` (margin_aim's), the `plain` aiming's and the `with_margin` one's bounds and the latter's
    limit fraction are added."""
    right, up = receiver.axes()
    row: dict[str, dict[str, Any]] = {}
    for s in maps:
        metrics, image = judge_at(receiver.center + chosen[s][:, :1] * right + chosen[s][:, 1:] * up)
        maps[s].append(image)
        moves[s].append(chosen[s].cpu().numpy())
        row[s] = {**{f"{prefix}_{k}": v for k, v in metrics.items()}, **promises[s],
                  "mean_aim_move_m": float((chosen[s] - start).norm(dim=-1).mean()),
                  "aim_points_m": chosen[s].tolist()}
    if margin:
        row[plain]["model_peak_bound_over_limit"], row[with_margin]["model_peak_bound_over_limit"] = margin["bound"]
        row[with_margin]["limit_fraction"] = margin["limit_fraction"]
    return row


def promised(result: AimResult | None, goal: Goal) -> dict[str, float | None]:
    """The aim JSON's model_* entries of an aiming: its own model's peak over the limit and, with a
    target, its target accuracy; None for an aiming no model chose (`default`)."""
    keys = ("peak_over_limit", "target_accuracy") if goal.target is not None else ("peak_over_limit",)
    return {f"model_{k}": None if result is None else getattr(result, k) for k in keys}


def margin_aim(spots: Tensor, start: Tensor, plain: Tensor, goal: Goal, settings: dict, covariances: Tensor,
               receiver: Target, seed: int) -> tuple[Tensor, dict[str, float | None], dict[str, Any]]:
    """((N, 2) aim offsets (m) that keep the limit with settings["keep_probability"] under the (N, 2, 2)
    pointing covariances (m^2) on the receiver (field/margin.py), what its own map promises (`promised`),
    {"bound": (the peak's bound / limit at the `plain` offsets, at the chosen ones), "limit_fraction",
    "pointing_sigma_m": median and max RMS displacement (m) over the heliostats with one, their count})
    for one model's (N, He, We) centre-aimed spots."""
    patches = SpotPatches.from_maps(spots, receiver.resolution, receiver.pixel_size)
    probability = settings["keep_probability"]
    draws = displacement_draws(covariances, settings["draws"], seed=seed)
    result, bound, fraction = optimise_with_margin(patches, start, goal.limit, draws, probability,
                                                   region=settings["region"], steps=settings["steps"],
                                                   target=goal.target)
    sigma = covariances.diagonal(dim1=-2, dim2=-1).sum(-1).sqrt()  # (N,) RMS displacement (m)
    known = sigma[sigma > 0]
    return result.offsets, promised(result, goal), {
        "bound": (peak_quantile(patches, plain, draws, probability, goal.limit), bound),
        "limit_fraction": fraction,
        "pointing_sigma_m": {"median": float(known.median()) if len(known) else 0.0, "max": float(sigma.max()),
                             "heliostats": len(known)}}


def optimise_aim(
    spec: dict, model_paths: list[str], dataset_paths: list[str],
    json_path: str | os.PathLike, figure_path: str | os.PathLike,
) -> dict:
    """The `optimise_aim` rule: write aim.json and aim.png (module docstring); return aim.json's content.

    Args:
        spec: compose_field's parameters (helioflow.workflow.compose_field_params) with
            "optimise_aim": {limit_kw_m2, region, steps} (config field.optimise_aim).
        model_paths, dataset_paths: the measured heliostats' models and calibration datasets, in the
            order of spec["measured"] (as compose_field reads them).
    """
    start_time = time.perf_counter()
    settings = spec["optimise_aim"]
    if len(model_paths) != len(spec["measured"]) or len(dataset_paths) != len(spec["measured"]):
        raise ConfigError(
            f"optimise-aim: {len(spec['measured'])} measured heliostats, but {len(model_paths)} models "
            f"and {len(dataset_paths)} datasets"
        )
    device = resolve_device(spec["device"])
    scene = build_scene(spec, device)
    goal, region = Goal.from_settings(settings, scene.receiver.resolution, device), settings["region"]
    cals = load_calibrations(scene, model_paths, dataset_paths, device)
    spots = model_spots(spec, scene, region, cals, device)
    start = scene.receiver.to_plane(scene.aims)  # (N, 2) the default aiming
    wide = extended_receiver(scene.receiver, region)  # where the centre-aimed spots lie
    probability = settings.get("keep_probability")
    strategies = (*STRATEGIES, MARGIN) if probability is not None else STRATEGIES
    tracking: list[Tensor | None] = [None] * len(scene.names)
    for k, cal in zip(scene.measured, cals):
        tracking[k] = tracking_covariance(getattr(getattr(cal.model, "fitted", None), "uncertainty", None))
    points: dict[str, Any] = {}
    sigmas: dict[str, dict] = {}  # per design point: the calibrated heliostats' pointing sigma on the receiver
    maps: dict[str, list[np.ndarray]] = {s: [] for s in strategies}
    moves: dict[str, list[np.ndarray]] = {s: [] for s in strategies}
    for i, point in enumerate(scene.points):
        chosen, promises = choose_aims({m: spots[m][i] for m in MODELS}, start, goal, settings, scene.receiver)
        chosen["default"], promises["default"] = start, promised(None, goal)
        margin: dict[str, Any] = {}
        if probability is not None:  # the hybrid's map under its heliostats' pointing sigma
            sun = sun_vector(scene.azimuth[i], scene.elevation[i]).double()
            covariances = pointing_covariances([h.ideal() for h in scene.true], tracking, sun, scene.aims,
                                               scene.receiver)
            chosen[MARGIN], promises[MARGIN], margin = margin_aim(spots["hybrid"][i], start, chosen["hybrid"], goal,
                                                                  settings, covariances, scene.receiver, seed=i)
            known = covariances.diagonal(dim1=-2, dim2=-1).sum(-1) > 0
            offsets = wide.centroid(spots["truth"][i].double()) - wide.centroid(spots["hybrid"][i].double())
            share, _ = covered(covariances, offsets)
            margin["pointing_sigma_m"] |= {
                "truth_within_95": share,
                "truth_offset_rms_m": float(offsets[known].norm(dim=-1).pow(2).mean().sqrt()) if known.any() else 0.0}
        row = judge_aimings(chosen, promises, start, scene.receiver, "truth", maps, moves, margin, "hybrid", MARGIN,
                            lambda aims: judge(scene, spec["world_effects"], scene.true, i, aims, goal, spec, device))
        if margin:
            sigmas[point] = margin["pointing_sigma_m"]
        bound = row["truth"]["truth_intercepted_w"]
        for s in strategies:
            row[s]["intercept_of_bound"] = row[s]["truth_intercepted_w"] / bound
        points[point] = row
    result_json = {
        "limit_kw_m2": settings["limit_kw_m2"],
        **({"target": settings["target"]} if settings.get("target") is not None else {}),
        "region": region,
        "heliostats": len(scene.names),
        "measured": [scene.names[k] for k in scene.measured],
        "network": spec["network"],
        "design_points": points,
        **({"keep_probability": probability, "pointing_sigma_m": sigmas} if probability is not None else {}),
        "seconds": round(time.perf_counter() - start_time, 2),
        "notes": {
            "truth_*": "each strategy's aim points applied to the true field and traced there",
            "model_peak_over_limit": "what the strategy's own model (shifted spots) promised",
            "aim_points_m": "per heliostat (right, up) on the receiver from its centre (m)",
            **({"model_peak_bound_over_limit": f"the model's peak at that aiming under the calibrated heliostats' "
                                               f"pointing sigma: an upper bound (95 % confidence) of its "
                                               f"{probability:g} quantile over {settings['draws']} draws, / limit",
                "limit_fraction": "the fraction of the limit hybrid_margin was optimised under",
                "pointing_sigma_m": "per design point the calibrated heliostats' spot displacement on the receiver "
                                    "(RMS, m): median and max over them, how many have one, the share whose true "
                                    "spot's centroid lies in the 95 % ellipse about the model's, and the RMS of "
                                    "those offsets (m)"}
               if probability is not None else {}),
        },
    }
    write_text_atomic(json_path, json.dumps(result_json, indent=2) + "\n")
    plot_aim_maps(
        figure_path, maps, moves,
        scene.points, goal.limit, (scene.receiver.width, scene.receiver.height),
        f"{len(scene.names)} heliostats, {len(scene.measured)} measured with {spec['network']}: true flux "
        f"under each aiming, limit {limit_text(settings['limit_kw_m2'])}",
        ("default", "hybrid"),
    )
    log.info("optimise_aim: %d heliostats, %d design points in %.1f s", len(scene.names), len(scene.points),
             result_json["seconds"])
    return result_json
