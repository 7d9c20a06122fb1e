"""What the exact footprint costs: a kernel trace of AA39 (16 sun positions at once, 16 and 48 cells
per side) and field flux maps (`python -m helioflow.bench field`'s fields of 1,000 and 10,000
heliostats), each with today's footprint and with that of a git revision, alternated in one process
so that the ratio is measured under one load. A measurement script, not a test.

Run: python scripts/experiments/footprint_cost.py [--against main] [--sizes 1000 10000]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "tests"))  # support.paint_world
from footprint_centroids import SUNS, alternated, footprint_of, imported_aa39  # noqa: E402
from support.paint_world import World  # noqa: E402

from helioflow import bench  # noqa: E402
from helioflow.physics import field, raytrace  # noqa: E402
from helioflow.physics.scene import dataset_scene  # noqa: E402


def installing(f):
    """A variant for `alternated`: `f` as the footprint of both tracers."""
    def install():
        raytrace.footprint = field.footprint = f
    return install


def main() -> None:
    """Parse the command line and run the measurement the module docstring describes."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--against", default="main")
    ap.add_argument("--sizes", type=int, nargs="+", default=[1000, 10000])
    args = ap.parse_args()
    torch.set_num_threads(2)
    footprints = {"now": installing(raytrace.footprint), args.against: installing(footprint_of(args.against))}
    ds, heliostat = imported_aa39(World())
    effects = {"sunshape": {"kind": "gaussian", "sigma_mrad": 3.3}, "slope_error": {"sigma_mrad": 1.5}}
    az, el = (torch.tensor([s[i] for s in SUNS] * 2) for i in (0, 1))
    with torch.no_grad():
        for cells in (16, 48):
            scene = dataset_scene(heliostat, ds.attrs, (64, 64), cells, 50_000, False)
            t = alternated(lambda: scene.simulate(effects, {}, az, el), footprints, 5)
            print(f"kernel trace, AA39, 16 suns, {cells} cells: " + ", ".join(f"{k} {v:.3f} s" for k, v in t.items())
                  + f"  (ratio {t['now'] / t[args.against]:.2f})", flush=True)
        for n in args.sizes:
            heliostats, receiver, physics, a, e = bench.field_scene(n)
            options = {"blocking_shading": physics.blocking_shading}
            field.field_flux(bench.field_scene(10)[0], receiver, a, e, physics.optics, **options)  # tables filled
            t = alternated(lambda: field.field_flux(heliostats, receiver, a, e, physics.optics, **options),
                           footprints, 2)
            print(f"field map, {n} heliostats: " + ", ".join(f"{k} {v:.2f} s" for k, v in t.items())
                  + f"  (ratio {t['now'] / t[args.against]:.2f})", flush=True)


if __name__ == "__main__":
    main()
