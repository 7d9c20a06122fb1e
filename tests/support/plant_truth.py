"""A plant run scored against the truth of the independent generator that made its images
(tests/support/paint_world.py `write_plant`: truth.json beside the PAINT folders).

Per heliostat: the effects its diagnosis named against those hidden (a tracking error always; a
canting, bump = registry `surface` or slope = `slope_error` on most), and the pointing recovered:
the RMS over the dataset's sun positions of the difference between the fitted kinematics' deviation
of the mirror normal from its ideal (helioflow's, the plant model's tracking) and the true deviation
(the generator's own kinematics with and without its joint offsets, of the mean facet normal with
and without its canting errors: a mean facet tilt points the spot as the kinematics do), in mrad.
Its σ: the fitted tracking's covariance (the model file's uncertainty) carried to the deviation,
sqrt(tr Σ_s) per sun position by central differences, RMS over them; a heliostat's pointing counts as
covered when its recovered pointing is at most twice that (a 2-D Gaussian error lies within twice the
RMS of its length 98 % of the time when it is isotropic).
The worlds are drawn again from the generator's seed (`--seed`, the demo's by default). The shared effects:
what plant/shared.json changed, against the camera and sun the generator used.

Run: python tests/support/plant_truth.py RESULTS_DIR PAINT_DIR [--plant plant] [--model drt] [--seed 11]
     [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # tests/: support.paint_world, run as a script
from helioflow.data.hdf5 import read_dataset  # noqa: E402
from helioflow.models.registry import load_model  # noqa: E402
from helioflow.physics.geometry import sun_vector as helioflow_sun  # noqa: E402
from helioflow.physics.heliostat import orientation  # noqa: E402
from support.paint_world import PLANT_DEMO, Scene, World, plant_worlds, rotation, sun_vector  # noqa: E402

EFFECT_OF = {"tracking": "tracking", "canting": "canting", "bump": "surface", "slope": "slope_error"}


def mean_normal(scene: Scene, canting_mrad: np.ndarray | None) -> np.ndarray:
    """(3,) unit mean facet normal in the heliostat frame, the facets tilted as the generator tilts them."""
    normals = scene.normal.copy()
    if canting_mrad is not None:
        e_axis = scene.half_e / np.linalg.norm(scene.half_e, axis=-1, keepdims=True)
        n_axis = scene.half_n / np.linalg.norm(scene.half_n, axis=-1, keepdims=True)
        for f in range(len(normals)):
            normals[f] = (rotation(e_axis[f], canting_mrad[f, 0] * 1e-3)
                          @ rotation(n_axis[f], canting_mrad[f, 1] * 1e-3) @ normals[f])
    mean = normals.mean(0)
    return mean / np.linalg.norm(mean)


def true_deviation(offset_enu_m, world: World, azimuth_deg, elevation_deg) -> np.ndarray:
    """(S, 3) true mean mirror normal minus the ideal one (ENU) of one heliostat, by the generator."""
    scene = Scene(world.target)
    scene.position = scene.position + np.asarray(offset_enu_m, float)
    true_normal, design = mean_normal(scene, world.canting_mrad), mean_normal(scene, None)
    out = []
    for az, el in zip(azimuth_deg, elevation_deg):
        sun = sun_vector(float(az), float(el))
        out.append(scene.mirror_rotation(sun, world.tracking_mrad) @ true_normal
                   - scene.mirror_rotation(sun, (0.0, 0.0)) @ design)
    return np.asarray(out)


def fitted_deviation(model, azimuth_deg, elevation_deg, aim_m, tracking_mrad: torch.Tensor | None = None) -> np.ndarray:
    """(S, 3) the fitted kinematics' mirror normal minus the ideal one (ENU), by helioflow (with the
    model's fitted tracking errors, or `tracking_mrad` (5,))."""
    h = model.heliostat.to("cpu", torch.float64)
    sun = helioflow_sun(torch.deg2rad(torch.as_tensor(azimuth_deg, dtype=torch.float64)),
                        torch.deg2rad(torch.as_tensor(elevation_deg, dtype=torch.float64)))
    aim = torch.as_tensor(aim_m, dtype=torch.float64)
    tracking = fitted_tracking(model) if tracking_mrad is None else tracking_mrad
    fitted = orientation(replace(h, tracking_error=tracking * 1e-3), sun, aim)[..., 2]
    ideal = orientation(replace(h, tracking_error=torch.zeros(5, dtype=torch.float64)), sun, aim)[..., 2]
    return (fitted - ideal).numpy()


def fitted_tracking(model) -> torch.Tensor:
    """(5,) the model's fitted tracking errors (mrad)."""
    return model.fitted.tensors["tracking"].detach().cpu().double().reshape(5)


def pointing_sigma(model, azimuth_deg, elevation_deg, aim_m, step_mrad: float = 0.01) -> float | None:
    """The σ of `fitted_deviation` (mrad): sqrt(tr Σ_s), Σ_s its (3, 3) covariance at each sun
    position from the fitted tracking's, RMS over the sun positions; None for a model without an
    uncertainty or without its 5 tracking entries."""
    u = model.fitted.uncertainty
    at = [] if u is None else [k for k, name in enumerate(u.names) if name.startswith("tracking.")]
    if len(at) != 5:
        return None
    tracking = fitted_tracking(model)
    columns = []
    for k in range(5):
        step = torch.zeros(5, dtype=torch.float64)
        step[k] = step_mrad
        plus, minus = (fitted_deviation(model, azimuth_deg, elevation_deg, aim_m, tracking + s * step) for s in (1, -1))
        columns.append((plus - minus) / (2 * step_mrad) * 1e3)  # (S, 3) mrad per mrad
    jacobian = np.stack(columns, -1)
    variance = np.einsum("sak,kl,sal->s", jacobian, np.asarray(u.covariance)[np.ix_(at, at)], jacobian)
    return float(np.sqrt(np.clip(variance, 0.0, None).mean()))


def score(results: Path, paint_dir: Path, plant: str, model_name: str, seed: int,
          canting_rms_mrad: tuple[float, float] = (0.5, 1.0)) -> dict:
    """The run in `results` against the plant in `paint_dir` (drawn by plant_worlds with `seed` and
    `canting_rms_mrad`): per heliostat and over the plant (module docstring)."""
    truth = json.loads((paint_dir / "truth.json").read_text())
    worlds = plant_worlds(len(truth), seed, canting_rms_mrad=canting_rms_mrad)
    if any(worlds[n][1].truth["hidden"] != t["hidden"] for n, t in truth.items()):
        raise SystemExit(f"{paint_dir}/truth.json was not drawn with seed {seed}: give the plant's --seed")
    rows = []
    for name, t in truth.items():
        dataset = f"{plant}_{name}"
        ds = read_dataset(results / "datasets" / f"{dataset}.h5")
        model, _ = load_model(results / "models" / dataset / f"{model_name}.pt")
        diagnosis = json.loads((results / "diagnosis" / f"{dataset}.json").read_text())
        named = sorted({c.split(":")[0] for c in diagnosis["remaining"]["changes"]})
        hidden = sorted(EFFECT_OF[h] for h in t["hidden"])
        d_true = true_deviation(t["offset_enu_m"], worlds[name][1], ds.azimuth_deg, ds.elevation_deg)
        d_fit = fitted_deviation(model, ds.azimuth_deg, ds.elevation_deg, ds.attrs["target_center_m"])
        recovered = float(np.sqrt((np.linalg.norm(d_fit - d_true, axis=1) ** 2).mean()) * 1e3)
        sigma = pointing_sigma(model, ds.azimuth_deg, ds.elevation_deg, ds.attrs["target_center_m"])
        rows.append({"heliostat": name, "hidden": hidden, "named": named, "right": named == hidden,
                     "true_pointing_mrad": round(float(np.sqrt((np.linalg.norm(d_true, axis=1) ** 2).mean()) * 1e3), 3),
                     "pointing_recovered_mrad": round(recovered, 3),
                     "pointing_sigma_mrad": None if sigma is None else round(sigma, 4),
                     "pointing_covered": None if sigma is None else bool(recovered <= 2.0 * sigma)})
    shared_path = results / "plant" / "shared.json"
    shared = json.loads(shared_path.read_text())[plant] if shared_path.exists() else None
    return {"heliostats": rows,
            "named_right": sum(r["right"] for r in rows) / len(rows),
            "pointing_recovered_rms_mrad": round(float(np.sqrt(np.mean([r["pointing_recovered_mrad"] ** 2
                                                                          for r in rows]))), 3),
            "canting_named": (sum("canting" in r["named"] for r in rows if "canting" in r["hidden"])
                              / max(1, sum("canting" in r["hidden"] for r in rows))),
            "pointing_over_sigma_median": (None if any(r["pointing_sigma_mrad"] is None for r in rows) else round(
                float(np.median([r["pointing_recovered_mrad"] / r["pointing_sigma_mrad"] for r in rows])), 3)),
            "pointing_covered": (None if any(r["pointing_covered"] is None for r in rows)
                                 else sum(r["pointing_covered"] for r in rows) / len(rows)),
            "shared_changes": None if shared is None else shared["changes"],
            "shared_values": None if shared is None else {
                n: v for s in shared["shared"] for n, v in s["values"].items()}}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("results")
    ap.add_argument("paint_dir")
    ap.add_argument("--plant", default="plant")
    ap.add_argument("--model", default="drt")
    ap.add_argument("--seed", type=int, default=PLANT_DEMO["seed"], help="the seed plant_worlds drew the plant with")
    ap.add_argument("--canting-rms-mrad", type=float, nargs=2, default=(0.5, 1.0),
                    help="the range plant_worlds drew the cantings' RMS from")
    ap.add_argument("--json")
    args = ap.parse_args()
    out = score(Path(args.results), Path(args.paint_dir), args.plant, args.model, args.seed,
                tuple(args.canting_rms_mrad))
    print("| heliostat | hidden | named | right | true pointing (mrad) | fitted - true (mrad RMS) | its σ (mrad) |")
    print("|---|---|---|---|---|---|---|")
    for r in out["heliostats"]:
        print(f"| {r['heliostat']} | {', '.join(r['hidden'])} | {', '.join(r['named']) or 'none'} | "
              f"{'yes' if r['right'] else 'no'} | {r['true_pointing_mrad']} | {r['pointing_recovered_mrad']} | "
              f"{r['pointing_sigma_mrad']} |")
    covered = "not known" if out["pointing_covered"] is None else f"{out['pointing_covered']:.0%}"
    print(f"named right: {out['named_right']:.0%}; pointing recovered to {out['pointing_recovered_rms_mrad']} mrad "
          "RMS, "
          f"within 2 sigma on {covered} (recovered / sigma median {out['pointing_over_sigma_median']}: a sigma far "
          f"above the error covers without telling how well the pointing is known); canting named on "
          f"{out['canting_named']:.0%} of those with one; shared changes: {out['shared_changes']} "
          f"{out['shared_values'] or ''}")
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
