"""A plant's flux maps (rule plant_flux, plant/flux/<plant>.h5) scored against the true flux on the
receiver, traced by the independent generator that made the plant's calibration images
(tests/support/paint_world.py: each heliostat with its hidden tracking, canting, bump and slope error, under
the generator's sun, without its camera), aiming at the receiver centre as the maps do.

The generator knows no atmosphere and no neighbours: score maps made without attenuation and
blocking (the plant_demo variant's `plant.flux.effects: {}`). Its rays aim from the concentrator's
origin, helioflow's from the pivot (data.paint): a small difference of the two codes, left in.

Per design point: each map's flux accuracy against the truth (1 - sum|P - T| / sum T) and per
heliostat the distance of its spot's centroid from the true spot's (m), ideal and calibrated.

With --aim, instead: the aim points of rule plant_aim (plant/aim/<plant>.json) judged on the truth:
per design point and aiming, the generator's heliostats aimed at them, the true map's peak over the
limit, the power on the receiver (W), the spillage (the share of the reflected power that misses
it, from a second trace on a plane three times the receiver's size) and the share of the receiver's
area over the limit; with a target distribution in the aim JSON, also each aiming's target accuracy
on the truth (field.aim.target_accuracy).

Run: python scripts/experiments/plant_flux_truth.py RESULTS_DIR PAINT_DIR [--plant plant] [--seed 11]
     [--rays 2000000] [--aim [AIM_JSON]] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "tests"))  # support.paint_world
from support.paint_world import PLANT_DEMO, PNG_SIDE, Scene, plant_worlds, trace_image  # noqa: E402

from helioflow.data.hdf5 import read_arrays  # noqa: E402
from helioflow.data.paint import resample_area  # noqa: E402
from helioflow.field.aim import limit_map, limit_text, target_accuracy, target_shares  # noqa: E402
from helioflow.field.plant import MAPS, SCHEMA  # noqa: E402
from helioflow.physics.geometry import plane_axes  # noqa: E402
from helioflow.scoring.metrics import centroid_px, flux_accuracy  # noqa: E402


class _Plane:
    """The receiver as the generator's Scene.target: centre, normal, size and the aim point."""

    def __init__(self, center, normal, width, height):
        self.center, self.normal, self.width, self.height = center, normal, width, height
        self.aim = center


def true_spots(arrays: dict, attrs: dict, worlds: dict, rays: int, dni_w_m2: float, seed: int,
               aims: np.ndarray | None = None, scale: float = 1.0) -> np.ndarray:
    """(S, N, H, W) true flux (W/m^2) of every heliostat on the receiver grid of a plant flux file
    (its arrays and attributes, field.plant.write_plant_flux), by the generator.

    Args:
        aims: (S, N, 2) aim points (right, up; m from the receiver centre), or None: the centre.
        scale: the traced plane's size over the receiver's, about the same centre (>1 to count spillage).
    """
    centre, normal = np.asarray(attrs["receiver_center_m"]), np.asarray(attrs["receiver_normal"])
    width, height = (scale * s for s in attrs["receiver_size_m"])
    rows, cols = arrays["ideal"].shape[1:]
    right, up = (a.numpy() for a in plane_axes(torch.as_tensor(normal)))
    rng = np.random.default_rng(seed)
    out = np.zeros((len(arrays["design_points"]), len(arrays["heliostats/names"]), rows, cols))
    for j, name in enumerate(arrays["heliostats/names"]):
        offset, world = worlds[str(name)]
        world.camera = (0.0, 0.0)  # the receiver is not photographed
        scene = Scene(world.target)
        scene.position = scene.position + np.asarray(offset, float)
        scene.target, scene.right, scene.up = _Plane(centre, normal, width, height), right, up
        area = 4 * float((np.linalg.norm(scene.half_e, axis=-1) * np.linalg.norm(scene.half_n, axis=-1)).sum())
        for i, (az, el) in enumerate(zip(arrays["sun/azimuth_deg"], arrays["sun/elevation_deg"])):
            if aims is not None:
                scene.target.aim = centre + aims[i, j, 0] * right + aims[i, j, 1] * up
            hits = trace_image(scene, world, float(az), float(el), rays, rng)  # (256, 256) sum of cos(incidence)
            flux_png = hits * dni_w_m2 * area / rays / (width / PNG_SIDE * height / PNG_SIDE)  # W/m^2
            out[i, j] = resample_area(flux_png, (rows, cols))  # the mean over each map pixel
    return out


def judge_aims(results: Path, paint_dir: Path, plant: str, seed: int, rays: int, dni_w_m2: float,
               aim_path: Path | None = None) -> dict:
    """Rule plant_aim's aim points (plant/aim/<plant>.json, or `aim_path`) applied to the generator's heliostats:
    {design point: {aiming: truth_peak_over_limit, truth_intercepted_w, truth_spillage,
    truth_area_over_limit, calibrated_peak_over_limit (what helioflow's calibrated plant said)}}."""
    truth = json.loads((paint_dir / "truth.json").read_text())
    aim = json.loads((aim_path or results / "plant" / "aim" / f"{plant}.json").read_text())
    arrays, attrs = read_arrays(results / "plant" / "flux" / f"{plant}.h5", SCHEMA)
    points = [str(p) for p in arrays["design_points"]]
    order = [aim["heliostats"].index(str(n)) for n in arrays["heliostats/names"]]  # the flux file's order
    rows, cols = arrays["ideal"].shape[1:]
    limit = limit_map(aim["limit_kw_m2"], (rows, cols))
    limit = limit.numpy() if isinstance(limit, torch.Tensor) else limit  # W/m^2, one value or (H, W)
    width, height = attrs["receiver_size_m"]
    pixel_m2 = width / cols * height / rows
    shares = None if aim.get("target") is None else target_shares(aim["target"], (rows, cols))
    out: dict = {p: {} for p in points}
    for strategy in aim["design_points"][points[0]]:
        aims = np.array([np.asarray(aim["design_points"][p][strategy]["aim_points_m"])[order] for p in points])
        maps = true_spots(arrays, attrs, plant_worlds(len(truth), seed), rays, dni_w_m2, seed, aims).sum(1)
        wide = true_spots(arrays, attrs, plant_worlds(len(truth), seed), rays // 4, dni_w_m2, seed + 1, aims,
                          scale=3.0).sum(1)
        for i, point in enumerate(points):
            on_receiver, reflected = maps[i].sum() * pixel_m2, wide[i].sum() * 9 * pixel_m2
            out[point][strategy] = {
                "truth_peak_over_limit": round(float((maps[i] / limit).max()), 4),
                "truth_intercepted_w": round(float(on_receiver), 1),
                "truth_spillage": round(float(max(0.0, 1 - on_receiver / reflected)), 4),
                "truth_area_over_limit": round(float((maps[i] > limit).mean()), 4),
                "calibrated_peak_over_limit": round(aim["design_points"][point][strategy]
                                                    ["calibrated_peak_over_limit"], 4)}
            if shares is not None:
                out[point][strategy]["truth_target_accuracy"] = round(
                    target_accuracy(torch.as_tensor(maps[i]), shares, reflected, pixel_m2), 4)
    return {"limit_kw_m2": aim["limit_kw_m2"], **({"target": aim["target"]} if shares is not None else {}),
            "design_points": out}


def score(results: Path, paint_dir: Path, plant: str, seed: int, rays: int, dni_w_m2: float) -> dict:
    """The plant's flux maps in `results` scored against the generator's own rays at each design point."""
    truth = json.loads((paint_dir / "truth.json").read_text())
    arrays, attrs = read_arrays(results / "plant" / "flux" / f"{plant}.h5", SCHEMA)
    spots = true_spots(arrays, attrs, plant_worlds(len(truth), seed), rays, dni_w_m2, seed)
    names = [str(n) for n in arrays["heliostats/names"]]
    rows, cols = arrays["ideal"].shape[1:]
    width, height = attrs["receiver_size_m"]
    pixel = np.array([height / rows, width / cols])  # (row, col) m
    out = {}
    for i, point in enumerate(str(p) for p in arrays["design_points"]):
        true_map = spots[i].sum(0)
        row = {m: {"flux_accuracy": round(float(flux_accuracy(arrays[m][i], true_map)), 4),
                   "power_error": round(float(arrays[m][i].sum() / true_map.sum() - 1), 4)} for m in MAPS}
        row["heliostats"] = {}
        for j, name in enumerate(str(n) for n in arrays["spots/names"]):
            true_centroid = centroid_px(spots[i, names.index(name)])
            row["heliostats"][name] = {
                m: round(float(np.linalg.norm((centroid_px(arrays[f"spots/{m}"][i, j]) - true_centroid) * pixel)), 4)
                for m in MAPS}
        out[point] = row
    centroid = {m: float(np.sqrt(np.mean([h[m] ** 2 for r in out.values() for h in r["heliostats"].values()])))
                for m in MAPS}
    return {"design_points": out,
            "mean_flux_accuracy": {m: round(float(np.mean([r[m]["flux_accuracy"] for r in out.values()])), 4)
                                   for m in MAPS},
            "spot_centroid_error_rms_m": {m: round(v, 4) for m, v in centroid.items()}}


def main() -> None:
    """Parse the command line and run the measurement the module docstring describes."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("results")
    ap.add_argument("paint_dir")
    ap.add_argument("--plant", default="plant")
    ap.add_argument("--seed", type=int, default=PLANT_DEMO["seed"], help="the seed plant_worlds drew the plant with")
    ap.add_argument("--rays", type=int, default=2_000_000, help="rays per heliostat and design point")
    ap.add_argument("--dni", type=float, default=1000.0, help="the config's dni_w_m2")
    ap.add_argument("--aim", nargs="?", const="", help="judge rule plant_aim's aim points on the truth instead: "
                                                       "RESULTS_DIR/plant/aim/<plant>.json, or this aim JSON")
    ap.add_argument("--json")
    args = ap.parse_args()
    if args.aim is not None:
        judged = judge_aims(Path(args.results), Path(args.paint_dir), args.plant, args.seed, args.rays, args.dni,
                            Path(args.aim) if args.aim else None)
        print(f"| design point | aiming | truth peak / limit ({limit_text(judged['limit_kw_m2'])}) | calibrated "
              "plant's peak / limit | truth on receiver (kW) | truth spillage | truth area over limit |"
              + (" truth target accuracy |" if "target" in judged else ""))
        print("|---" * (7 + ("target" in judged)) + "|")
        for point, row in judged["design_points"].items():
            for strategy, r in row.items():
                print(f"| {point} | {strategy} | {r['truth_peak_over_limit']:.3f} | "
                      f"{r['calibrated_peak_over_limit']:.3f} | {r['truth_intercepted_w'] / 1e3:.2f} | "
                      f"{r['truth_spillage']:.4f} | {r['truth_area_over_limit']:.4f} |"
                      + (f" {r['truth_target_accuracy']:.3f} |" if "truth_target_accuracy" in r else ""))
        if args.json:
            Path(args.json).write_text(json.dumps(judged, indent=1))
        return
    out = score(Path(args.results), Path(args.paint_dir), args.plant, args.seed, args.rays, args.dni)
    print("| design point | flux accuracy: ideal | calibrated | power error: ideal | calibrated |")
    print("|---|---|---|---|---|")
    for point, r in out["design_points"].items():
        print(f"| {point} | {r['ideal']['flux_accuracy']} | {r['calibrated']['flux_accuracy']} | "
              f"{r['ideal']['power_error']:+.4f} | {r['calibrated']['power_error']:+.4f} |")
    print(f"spot centroid error against the truth, RMS over heliostats and design points: "
          f"ideal {out['spot_centroid_error_rms_m']['ideal']} m, "
          f"calibrated {out['spot_centroid_error_rms_m']['calibrated']} m")
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
