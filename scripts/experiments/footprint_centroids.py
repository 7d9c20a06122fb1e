"""Where the fast tracer puts a spot's centroid, against the reference tracer and an independent
Monte Carlo (tests/support/paint_world.py), on the real AA39 and the Jülich upper target: the kernel
footprint's far side (docs/physics.md, "The tracer"). A measurement script, not a test.

The ideal AA39, no tracking error, a Gaussian sun (3.3 mrad per axis; --sigma), at 8 sun positions
of a calibration year: centroids (mrad, right / up) of helioflow's kernel trace, its reference
tracer (2e6 rays each) and paint_world's Monte Carlo (4e6 rays, area-averaged to 64 x 64 as the
import does: uncertainty_cases.true_centroids_mrad). Prints each difference per sun position and
their means; --against REV also traces with the footprint of that git revision (e.g. main), in the
same process.

Run: python scripts/experiments/footprint_centroids.py [--sigma 3.3] [--against REV]
"""

from __future__ import annotations

import argparse
import importlib.util
import math
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "tests"))  # support.paint_world
from support.paint_world import World, calibration_suns, write_paint_folder  # noqa: E402
from uncertainty_cases import true_centroids_mrad  # noqa: E402

from helioflow.data.hdf5 import read_dataset  # noqa: E402
from helioflow.data.paint import import_paint  # noqa: E402
from helioflow.data.surfaces import read_heliostat  # noqa: E402
from helioflow.physics import raytrace  # noqa: E402
from helioflow.physics.reference import reference_trace  # noqa: E402
from helioflow.physics.scene import dataset_scene  # noqa: E402

SUNS = calibration_suns(8, 1)


def raytrace_of(revision: str):
    """The module helioflow.physics.raytrace as it was at a git revision."""
    source = subprocess.run(["git", "show", f"{revision}:src/helioflow/physics/raytrace.py"], check=True,
                            capture_output=True, text=True, cwd=Path(__file__).resolve().parents[2]).stdout
    path = Path(tempfile.mkdtemp()) / "raytrace_then.py"
    path.write_text(source)
    spec = importlib.util.spec_from_file_location("raytrace_then", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules["raytrace_then"] = module
    spec.loader.exec_module(module)
    return module


def footprint_of(revision: str):
    """raytrace.footprint as it was at a git revision."""
    return raytrace_of(revision).footprint


def alternated(run, variants: dict, repeats: int) -> dict[str, float]:
    """The least wall time (s) of `run()` per variant over `repeats` rounds, variants alternated so
    that their ratio is measured under one load; `variants` maps a name to a function that installs it."""
    times = {name: [] for name in variants}
    for _ in range(repeats):
        for name, install in variants.items():
            install()
            start = time.perf_counter()
            run()
            times[name].append(time.perf_counter() - start)
    return {name: min(t) for name, t in times.items()}


def imported_aa39(world: World):
    """(dataset, ideal heliostat) of AA39 as imported from PAINT: the target and geometry only."""
    folder = Path(tempfile.mkdtemp())
    write_paint_folder(folder, world, n_images=1, rays=10_000, seed=0)
    import_paint(folder, "AA39", folder / "data.h5", folder / "aa39.h5", holdout=[], dataset="geometry")
    return read_dataset(folder / "data.h5"), read_heliostat(folder / "aa39.h5").ideal()


def main() -> None:
    """Parse the command line and run the measurement the module docstring describes."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sigma", type=float, default=3.3, help="the Gaussian sun's sigma per axis (mrad)")
    ap.add_argument("--against", help="a git revision whose footprint is traced too")
    args = ap.parse_args()
    torch.set_num_threads(2)
    world = World(sun=("gaussian", args.sigma))
    ds, heliostat = imported_aa39(world)
    scene = dataset_scene(heliostat, ds.attrs, (64, 64), 16, 50_000, False)
    slant = float(np.linalg.norm(np.subtract(ds.attrs["target_center_m"], heliostat.position.numpy())))
    effects = {"sunshape": {"kind": "gaussian", "sigma_mrad": args.sigma}}
    az, el = (torch.tensor([s[i] for s in SUNS]) for i in (0, 1))

    def mrad(images) -> np.ndarray:
        return (scene.target.centroid(torch.as_tensor(np.asarray(images)).float()).double() / slant * 1e3).numpy()

    with torch.no_grad():
        fast = {"kernel": mrad(scene.simulate(effects, {}, az, el))}
        if args.against:
            now, raytrace.footprint = raytrace.footprint, footprint_of(args.against)
            fast[f"kernel at {args.against}"] = mrad(scene.simulate(effects, {}, az, el))
            raytrace.footprint = now
    physics = scene._physics(effects)
    h64 = physics.heliostat.to("cpu", torch.float64)
    reference = mrad([reference_trace(h64, scene.target, math.radians(a), math.radians(e), physics.optics, 2_000_000,
                                      seed=i) for i, (a, e) in enumerate(SUNS)])
    monte_carlo = true_centroids_mrad(world, SUNS, scene, slant, 5)
    np.set_printoptions(precision=4, suppress=True)
    for name, c in {**fast, "reference": reference}.items():
        print(f"{name} - Monte Carlo (mrad, right / up), per sun position:\n{c - monte_carlo}")
        print(f"  mean {np.round((c - monte_carlo).mean(0), 4)}")
    print(f"one pixel: {np.round(np.array(scene.target.pixel_size) / slant * 1e3, 3)} mrad")


if __name__ == "__main__":
    main()
