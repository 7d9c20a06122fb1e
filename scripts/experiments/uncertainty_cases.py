"""How sure helioflow's fits are, checked on data it did not make (tests/support/paint_world.py's independent
Monte Carlo of the real AA39 heliostat, 8-bit PNGs imported with `source: paint`), and whether the
images `plan` recommends teach the fit more than others.

Per case and seed: 40 calibrations of one world (a tracking error always, and one spread effect
whose parametrisation helioflow shares: sun width, slope error or camera blur), split in the order
they were taken into 8 taken so far, 24 candidates and 8 held out. The model (the believed Gaussian
sun, tracking fitted, the case's spread fitted) is fitted on the 8 with its uncertainty, then:

- coverage: is the true spread within its 95 % interval, and each held-out image's measured
  centroid within the 95 % interval of the predicted one (the prediction's sigma from the
  covariance and the measured centroid's own noise, from the images' noise model, together)?
- planning: 4 more images chosen by `plan` among the candidates (d_optimal; targeted at the worst
  determined parameters; and targeted at the centroids predicted at the held-out images' sun
  positions, which an ephemeris knows in advance: "predictions"), 4 drawn at random (3 draws, their
  mean), and the next 4 in time;
  each refitted with the 8 and scored: the sigma of the parameters that were worst determined (the
  3 whose sigma all 24 candidates would shrink most), the held-out error (misplaced flux, whose
  floor is the images' noise) and the held-out centroids' error about the true spots' (RMS, mrad:
  the prediction's own error, without the measurement's noise).

`--known 3`: the first fit has only the first 3 of the 8 (same candidates, same held-out images):
few images, where the tracking's parameters are confounded and the prediction itself is uncertain,
so that the next images can move the held-out error.

Run: python scripts/experiments/uncertainty_cases.py [--seeds 1 2 3] [--known 8] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "tests"))  # support.paint_world
from support.paint_world import Scene, World, trace_image, write_paint_folder  # noqa: E402

from helioflow.data.hdf5 import read_dataset  # noqa: E402
from helioflow.data.noise import measure_noise  # noqa: E402
from helioflow.data.paint import import_paint, resample_area  # noqa: E402
from helioflow.data.surfaces import read_heliostat  # noqa: E402
from helioflow.models.physics_fit import (  # noqa: E402
    FitSettings,
    Measurements,
    fit_effects,
    initial_tensors,
    spot_spread,
    with_uncertainty,
)
from helioflow.models.planning import image_information, plan  # noqa: E402
from helioflow.models.uncertainty import Z95, end_state  # noqa: E402
from helioflow.physics.effects import REGISTRY  # noqa: E402
from helioflow.physics.scene import dataset_scene, misplaced_flux  # noqa: E402

TAKEN, CANDIDATES, HELD_OUT, ADDED, RAYS = 8, 24, 8, 4, 400_000
RANDOM_DRAWS = 3  # random picks: the mean over this many draws
BELIEVED = {"sunshape": {"kind": "gaussian", "sigma_mrad": 2.51}}
TRACKING = {"tracking": {p.name: "fit" for p in REGISTRY["tracking"].parameters}}
CASES = {  # name: (world, the fitted spread: (effect, parameter, true value))
    "sun width": (World(tracking_mrad=(1.2, -0.9), sun=("gaussian", 3.3)), ("sunshape", "sigma_mrad", 3.3)),
    "slope error": (World(tracking_mrad=(1.2, -0.9), slope_mrad=1.5), ("slope_error", "sigma_mrad", 1.5)),
    "camera blur": (World(tracking_mrad=(1.2, -0.9), camera=(0.0, 1.5)), ("camera", "blur_px", 1.5)),
}
SETTINGS = FitSettings(steps=80, rounds=2, gauss_newton_steps=3, loss="shape")


def model_effects(spread: tuple[str, str, float]) -> dict:
    """The model's effects: the believed sun and a fitted tracking error, the case's spread freed too."""
    effect, name, _ = spread
    out = {**BELIEVED, **TRACKING}
    out[effect] = {**out.get(effect, {}), name: "fit"}
    return out


def centroid_noise_mrad(scene, images: torch.Tensor, slant_m: float) -> np.ndarray:
    """(N, 2) std (mrad, right / up) of each measured image's centroid from its pixels' noise (the
    noise model measured in the images): var c = sum (x - c)^2 s^2 / S^2."""
    std = measure_noise(images).std(images).double()
    u, v = scene.target.pixel_centres(torch.float64)
    c = scene.target.centroid(images.float()).double()
    total = images.double().sum((-2, -1))
    du = u[None, None, :] - c[:, 0, None, None]
    dv = v[None, :, None] - c[:, 1, None, None]
    out = [((d**2 * std**2).sum((-2, -1))).sqrt() / total for d in (du, dv)]
    return (torch.stack(out, 1) / slant_m * 1e3).numpy()


def true_centroids_mrad(world: World, suns: list[tuple[float, float]], scene, slant_m: float, seed: int) -> np.ndarray:
    """(N, 2) centroids (mrad, right / up) of the world's expected spots at `suns` (azimuth,
    elevation deg): 4e6 Monte Carlo rays each, not rounded to 8 bits, area-averaged as imported."""
    rng, images = np.random.default_rng([seed, 99]), []
    for azimuth, elevation in suns:
        flux = sum(trace_image(Scene(world.target), world, azimuth, elevation, 2_000_000, rng) for _ in range(2))
        images.append(resample_area(flux / flux.max(), scene.target.resolution))
    return (scene.target.centroid(torch.as_tensor(np.stack(images)).float()).double() / slant_m * 1e3).numpy()


def run_case(name: str, seed: int, root: Path, known: int = TAKEN) -> dict:
    """One case and seed; `known`: how many of the 8 images taken so far the first fit has (the
    first ones in time; fewer leave the prediction itself undetermined)."""
    world, spread = CASES[name]
    folder = root / f"{name.replace(' ', '_')}_{seed}"
    write_paint_folder(folder, world, n_images=TAKEN + CANDIDATES + HELD_OUT, rays=RAYS, seed=seed)
    ids = [str(100_000 + i) for i in range(TAKEN + CANDIDATES + HELD_OUT)]
    import_paint(folder, "AA39", folder / "data.h5", folder / "aa39.h5", holdout=ids[-HELD_OUT:], dataset=name)
    ds = read_dataset(folder / "data.h5")
    order = np.argsort([int(i) for i in ds.attrs["measurement_ids"]])  # the order they were taken in
    taken, pool, held = order[:known], order[TAKEN:TAKEN + CANDIDATES], order[TAKEN + CANDIDATES:]
    scale = float(ds.images[order[:TAKEN + CANDIDATES]].max())
    data = lambda index: Measurements(torch.as_tensor(ds.images[index]) / scale,  # noqa: E731
                                      torch.as_tensor(ds.azimuth_deg[index]).float(),
                                      torch.as_tensor(ds.elevation_deg[index]).float(), scale)
    heliostat = read_heliostat(folder / "aa39.h5").ideal()
    scene = dataset_scene(heliostat, ds.attrs, tuple(ds.images.shape[1:]), 16, 50_000, True)
    slant = float(np.linalg.norm(np.subtract(ds.attrs["target_center_m"], heliostat.position.numpy())))
    effects = model_effects(spread)

    def fitted(index, start=None):
        d = data(index)
        return with_uncertainty(scene, fit_effects(scene, effects, d, SETTINGS, start=start), d, "shape")

    truth = true_centroids_mrad(world, list(zip(ds.azimuth_deg[held].tolist(), ds.elevation_deg[held].tolist())),
                                scene, slant, seed)

    def heldout_errors(fit) -> dict[str, float]:
        """The fit's held-out error (misplaced flux, mean) and its held-out centroids' RMS error (mrad)
        about the true ones (no measurement noise in it), from one trace of the held-out suns."""
        d = data(held)
        with torch.no_grad():
            pred, lost = scene.simulate(fit.effects, fit.tensors, d.azimuth_deg, d.elevation_deg, with_lost=True)
        centroids = scene.target.centroid(pred).double().numpy() / slant * 1e3
        return {"heldout_error": float(misplaced_flux(pred, d.images, lost).mean()),
                "centroid_error": float(np.sqrt(((centroids - truth) ** 2).mean()))}

    t0 = time.time()
    first = fitted(taken)
    u = first.uncertainty
    k = u.index(f"{spread[0]}.{spread[1]}")
    d_held = data(held)
    spot = spot_spread(scene, first, d_held.azimuth_deg, d_held.elevation_deg, scale, "shape")
    measured = (scene.target.centroid(d_held.images.float()).double() / slant * 1e3).numpy()
    noise = centroid_noise_mrad(scene, d_held.images, slant)
    sigma = np.sqrt(spot["centroid_sigma_mrad"].numpy() ** 2 + noise**2)
    inside = np.abs(measured - spot["centroid_mrad"].numpy()) <= Z95 * sigma
    out = {"case": name, "seed": seed, "known": known, "spread": {"true": spread[2], "fitted": float(u.values[k]),
                                                   "sigma": float(u.sigma[k]),
                                                   "within_95": bool(abs(u.values[k] - spread[2]) <= Z95 * u.sigma[k])},
           "structure": u.structure, "undetermined": u.undetermined,
           "centroids": {"within_95": float(inside.mean()),
                         "prediction_sigma_mrad": float(spot["centroid_sigma_mrad"].mean()),
                         "measurement_sigma_mrad": float(noise.mean()),
                         "error_mrad": float(np.abs(measured - spot["centroid_mrad"].numpy()).mean())}}
    # planning: the information of each candidate at the first fit
    _, masks = initial_tensors(first.effects, scene.heliostat)
    d_pool = data(pool)
    state = end_state(scene, first, d_pool.azimuth_deg, d_pool.elevation_deg, scale, "shape", masks)
    information = image_information(state, first.fitted, masks, u)
    every = [p.sigma_after for p in plan(information, u, CANDIDATES)][-1]  # sigma after all candidates
    worst = np.argsort(-(u.sigma / np.maximum(every, 1e-12)))[:3]  # the parameters the candidates teach most about
    planned = {"plan": plan(information, u, ADDED),
               "plan, targeted": plan(information, u, ADDED, "targets", [u.names[i] for i in worst]),
               "plan, predictions": plan(information, u, ADDED, "predictions",
                                         predictions=spot["centroid_jacobian"].flatten(0, 1))}
    expected = {k: float(np.sqrt(np.mean(v[-1].sigma_after[worst] ** 2))) for k, v in planned.items()}
    picks = {**{k: [p.index for p in v] for k, v in planned.items()},
             **{f"random {i + 1}": list(np.random.default_rng([seed, i]).choice(CANDIDATES, ADDED, replace=False))
                for i in range(RANDOM_DRAWS)},
             "next in time": list(range(ADDED))}
    out["worst_determined"] = [u.names[i] for i in worst]
    out["sigma_worst_before"] = float(np.sqrt(np.mean(u.sigma[worst] ** 2)))
    out["sigma_worst_before_noise_only"] = float(np.sqrt(np.mean(u.sigma[worst] ** 2) / max(1.0, u.structure)))
    out.update({f"{k}_before": v for k, v in heldout_errors(first).items()})
    out["strategies"] = {}
    for strategy, chosen in picks.items():
        refit = fitted(np.concatenate([taken, pool[chosen]]), start=first)
        out["strategies"][strategy] = {"sun": [[round(float(ds.azimuth_deg[pool[i]]), 2),
                                                round(float(ds.elevation_deg[pool[i]]), 2)] for i in chosen],
                                       "sigma_worst": float(np.sqrt(np.mean(refit.uncertainty.sigma[worst] ** 2))),
                                       "sigma_worst_expected": expected.get(strategy),
                                       "structure": refit.uncertainty.structure,
                                       "sigma_worst_noise_only": float(np.sqrt(
                                           np.mean(refit.uncertainty.sigma[worst] ** 2)
                                           / max(1.0, refit.uncertainty.structure))),
                                       **heldout_errors(refit)}
    draws = [out["strategies"][f"random {i + 1}"] for i in range(RANDOM_DRAWS)]
    out["strategies"]["random"] = {k: float(np.mean([d[k] for d in draws]))
                                   for k in ("sigma_worst", "heldout_error", "centroid_error")}
    out["strategies"]["random"]["centroid_error_range"] = [min(d["centroid_error"] for d in draws),
                                                           max(d["centroid_error"] for d in draws)]
    out["seconds"] = round(time.time() - t0, 1)
    return out


def main() -> None:
    """Parse the command line and run the measurement the module docstring describes."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--cases", nargs="+", default=list(CASES))
    ap.add_argument("--root", default="/tmp/uncertainty_cases")
    ap.add_argument("--known", type=int, default=TAKEN, help=f"images the first fit has (of the {TAKEN} taken)")
    ap.add_argument("--json", help="write the results here")
    args = ap.parse_args()
    torch.set_num_threads(2)
    results = []
    for name in args.cases:
        for seed in args.seeds:
            results.append(run_case(name, seed, Path(args.root), args.known))
            print(json.dumps(results[-1]), flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1) + "\n")


if __name__ == "__main__":
    main()
