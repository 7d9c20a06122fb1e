"""What the first-order footprints cost (raytrace.splat_footprints: per image the reference ray's
footprint and its change across the heliostat, four convolutions summed): a kernel trace of AA39 (16 sun
positions at once, 16 and 48 cells per side, forward) against git revision 5e23a2f's splat (the mean
ray's footprint per facet), alternated in one process so that the ratio is measured under one load.
A measurement script, not a test.

Run: python scripts/experiments/splat_cost.py [--against 5e23a2f] [--dataset D.h5 --heliostat H.h5]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "tests"))  # support.paint_world
from footprint_centroids import SUNS, alternated, imported_aa39, raytrace_of  # noqa: E402
from support.paint_world import World  # noqa: E402

from helioflow.data.hdf5 import read_dataset  # noqa: E402
from helioflow.data.surfaces import read_heliostat  # noqa: E402
from helioflow.physics import raytrace  # noqa: E402
from helioflow.physics.scene import dataset_scene  # noqa: E402


def per_facet(revision: str, n_facets: int):
    """A variant for `alternated`: the kernel splat of `revision` (one footprint per facet, the mean
    ray's) behind today's call."""
    then = raytrace_of(revision)

    def install():
        raytrace._splat_kernel = lambda c, target, optics, reference: then._splat_kernel(c, target, optics, n_facets)
    return install


def main() -> None:
    """Parse the command line and run the measurement the module docstring describes."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--against", default="5e23a2f")
    ap.add_argument("--dataset", help="a dataset (HDF5) instead of AA39: its first 16 sun positions, with --heliostat")
    ap.add_argument("--heliostat", help="the dataset's heliostat (HDF5), traced from its design")
    args = ap.parse_args()
    torch.set_num_threads(2)
    if args.dataset:
        ds, heliostat = read_dataset(args.dataset), read_heliostat(args.heliostat).ideal()
        az, el = (torch.as_tensor(a[:16]).float() for a in (ds.azimuth_deg, ds.elevation_deg))
    else:
        ds, heliostat = imported_aa39(World())
        az, el = (torch.tensor([s[i] for s in SUNS] * 2) for i in (0, 1))
    today = raytrace._splat_kernel
    splats = {"first order": lambda: setattr(raytrace, "_splat_kernel", today),
              "one footprint": per_facet(args.against, heliostat.n_facets)}
    effects = {"sunshape": {"kind": "gaussian", "sigma_mrad": 3.3}, "slope_error": {"sigma_mrad": 1.5}}

    def report(label: str, t: dict) -> None:
        print(f"{label}: " + ", ".join(f"{k} {v:.3f} s" for k, v in t.items())
              + f"  (ratio {t['first order'] / t['one footprint']:.2f})", flush=True)

    for cells in (16, 48):
        scene = dataset_scene(heliostat, ds.attrs, (64, 64), cells, 50_000, False)
        with torch.no_grad():
            t = alternated(lambda: scene.simulate(effects, {}, az, el), splats, 5)
        report(f"kernel trace, {heliostat.n_facets} facets, 16 suns, {cells} cells", t)


if __name__ == "__main__":
    main()
