"""How visible each heliostat's own hidden effect is in its calibration images, measured with the
independent generator itself (tests/support/paint_world.py), not with helioflow's tracer: the misplaced flux
between the images traced with and without the effect (the same tracking, sun, camera and random
rays: common random numbers, so that the difference is the effect's alone), noise-free, at the
dataset's 64 x 64 pixels, over the noise floor the diagnosis measured on that heliostat's images.
Below ~1 an effect moves less flux than the noise does: no criterion on the misplaced flux can name
it, and a fitted value must carry it alone.

    python scripts/experiments/plant_visibility.py RESULTS PAINT_DIR --seed S [--images 8] [--rays 500000]

RESULTS: the plant's results/<experiment> (diagnosis/<entry>_<heliostat>.json for the noise floor
and what was named), PAINT_DIR the generator's folder (truth.json), S the plant's seed.
"""

from __future__ import annotations

import argparse
import copy
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "tests"))  # support.paint_world
from support.paint_world import Scene, calibration_suns, camera, plant_worlds, trace_image  # noqa: E402
from support.plant_truth import EFFECT_OF  # noqa: E402

PIXELS = 64  # the dataset's image side (import-paint's)
NEGLIGIBLE = 1e-9  # mrad: a slope error that draws the same random numbers and does nothing


def without(world, kind: str):
    """The world with its own effect `kind` (canting, bump, slope) taken out; of a canting only its
    facets' tilts about their mean: the mean tilt points the spot as the kinematics do, and every
    fit takes it as tracking (before 2026-11-28 it counted as visible too)."""
    other = copy.deepcopy(world)
    if kind == "canting":
        other.canting_mrad = np.broadcast_to(world.canting_mrad.mean(0), world.canting_mrad.shape).copy()
    elif kind == "bump":
        other.bump = None
    elif kind == "slope":
        other.slope_mrad = NEGLIGIBLE
    return other


def pixels(flux: np.ndarray) -> np.ndarray:
    """(256, 256) -> (64, 64) summed, divided by its sum."""
    k = flux.shape[0] // PIXELS
    small = flux.reshape(PIXELS, k, PIXELS, k).sum((1, 3))
    return small / small.sum()


def visibility(world, kind: str, offset, n_images: int, rays: int, seed: int) -> float:
    """Mean misplaced flux (half L1 of the normalised images) between the world with and without its
    effect over `n_images` calibration suns."""
    scene = Scene(world.target)
    scene.position = scene.position + np.asarray(offset, float)
    out = []
    for az, el in calibration_suns(n_images, seed):
        a, b = (pixels(camera(trace_image(scene, w, az, el, rays, np.random.default_rng(seed)), w))
                for w in (world, without(world, kind)))
        out.append(0.5 * np.abs(a - b).sum())
    return float(np.mean(out))


def main() -> None:
    """Parse the command line and run the measurement the module docstring describes."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("results")
    ap.add_argument("paint_dir")
    ap.add_argument("--seed", type=int, required=True)
    ap.add_argument("--entry", default="plant")
    ap.add_argument("--images", type=int, default=8)
    ap.add_argument("--rays", type=int, default=500_000)
    args = ap.parse_args()
    truth = json.loads((Path(args.paint_dir) / "truth.json").read_text())
    worlds = plant_worlds(len(truth), args.seed)
    print("| heliostat | own effect | size | visibility (misplaced flux) | noise floor | over the floor | named "
          "| right |")
    print("|---|---|---|---|---|---|---|---|")
    for name, (offset, world) in worlds.items():
        kind = world.truth["hidden"][-1]
        if kind == "tracking":
            continue
        diagnosis = json.loads((Path(args.results) / "diagnosis" / f"{args.entry}_{name}.json").read_text())
        floor = diagnosis["noise_floor"]
        named = sorted({c.split(":")[0] for c in diagnosis["remaining"]["changes"]})
        right = named == sorted(EFFECT_OF[h] for h in world.truth["hidden"])
        size = {"canting": lambda: f"{np.sqrt(((world.canting_mrad - world.canting_mrad.mean(0)) ** 2).mean()):.2f} "
                               "mrad RMS about the mean",
                "bump": lambda: f"{world.bump[1]:.2f} mm", "slope": lambda: f"{world.slope_mrad:.2f} mrad"}[kind]()
        v = visibility(world, kind, offset, args.images, args.rays, args.seed)
        print(f"| {name} | {kind} | {size} | {v:.4f} | {floor:.4f} | {v / floor:.2f} | {', '.join(named)} | "
              f"{'yes' if right else 'no'} |", flush=True)


if __name__ == "__main__":
    main()
