"""The spot's second moments: helioflow's tracer against tests/support/paint_world.py's independent Monte Carlo.

AA39 (the PAINT design), no tracking error, a Gaussian sun (and optionally a slope error); per sun
position the model's image (`dataset_scene(...).simulate`, kernel splat on `--cells` cells per side)
and the Monte Carlo's (8e6 rays, its 256 x 256 histogram area-averaged to 64 x 64 as the PAINT import
does), both as float images. Prints each one's variance per axis (px^2) and the difference: how much
wider or narrower the model draws the spot than a camera would see it.

Run: python scripts/experiments/spot_moments.py [--cells 16 48] [--slope-mrad 1.5]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "tests"))  # support.paint_world
from support.paint_world import Scene, World, calibration_suns, trace_image, write_paint_folder  # noqa: E402

from helioflow.data.hdf5 import read_dataset  # noqa: E402
from helioflow.data.paint import import_paint, resample_area  # noqa: E402
from helioflow.data.surfaces import read_heliostat  # noqa: E402
from helioflow.physics.scene import dataset_scene  # noqa: E402


def moments(image: np.ndarray) -> tuple[float, float]:
    """Variance (px^2) of the image's column and row."""
    w = image / image.sum()
    rows, cols = np.indices(image.shape)
    mc, mr = (cols * w).sum(), (rows * w).sum()
    return float(((cols - mc) ** 2 * w).sum()), float(((rows - mr) ** 2 * w).sum())


def main() -> None:
    """Parse the command line and run the measurement the module docstring describes."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cells", type=int, nargs="+", default=[16, 48])
    ap.add_argument("--slope-mrad", type=float, default=0.0)
    ap.add_argument("--suns", type=int, default=3)
    args = ap.parse_args()
    world = World(tracking_mrad=(0.0, 0.0), sun=("gaussian", 2.51), slope_mrad=args.slope_mrad)
    effects = {"sunshape": {"kind": "gaussian", "sigma_mrad": 2.51}}
    if args.slope_mrad:
        effects["slope_error"] = {"sigma_mrad": args.slope_mrad}
    with tempfile.TemporaryDirectory() as tmp:
        write_paint_folder(Path(tmp), world, n_images=1, rays=1000, seed=0)  # the geometry, imported
        import_paint(Path(tmp), "AA39", Path(tmp) / "data.h5", Path(tmp) / "aa39.h5")
        ds = read_dataset(Path(tmp) / "data.h5")
        heliostat = read_heliostat(Path(tmp) / "aa39.h5").ideal().to("cpu", torch.float32)
    suns = calibration_suns(args.suns, 0)
    scene = Scene(world.target)
    theirs, noise = [], []  # per sun: the 4 draws' summed image's variances, and their standard error
    for az, el in suns:
        draws = [resample_area(trace_image(scene, world, az, el, 2_000_000, np.random.default_rng(k)), (64, 64))
                 for k in range(4)]
        theirs.append(moments(sum(draws)))
        noise.append(np.std([moments(d) for d in draws], axis=0, ddof=1) / 2)  # over 4 draws: / sqrt(4)
    print("cells  sun   model col / row px^2   Monte Carlo col / row   model - Monte Carlo  (+- Monte Carlo noise)")
    for cells in args.cells:
        model = dataset_scene(heliostat, ds.attrs, (64, 64), cells, 0, False)
        for i, (az, el) in enumerate(suns):
            with torch.no_grad():
                image = model.simulate(effects, {}, torch.tensor([az]), torch.tensor([el]))[0].double().numpy()
            ours = moments(image)
            print(f"{cells:5d} {i:4d}   {ours[0]:8.3f} {ours[1]:8.3f}        {theirs[i][0]:8.3f} {theirs[i][1]:8.3f}"
                  f"        {ours[0] - theirs[i][0]:+.3f} {ours[1] - theirs[i][1]:+.3f}"
                  f"  (+- {noise[i][0]:.3f} {noise[i][1]:.3f})")


if __name__ == "__main__":
    main()
