"""The model's own resolution: the misplaced flux between helioflow's spot and an independent Monte
Carlo of the same physics when the images hold almost no noise (diagnosis/diagnose.py,
MODEL_RESOLUTION; docs/diagnosis.md, "False alarms").

    python scripts/experiments/model_resolution.py [--seeds 2] [--images 12]

Per camera (as counted, blurred 1.5 px after the counting, rectified) and seed: PAINT folders of
AA39 from tests/support/paint_world.py with nothing hidden, once at 400 000 rays per image and once at
8 000 000 (8-bit both), imported; the model (the ideal heliostat under the world's Gaussian sun,
the camera's blur where it has one) traced on the diagnosis' fit scene and on one with twice the
cells and eight times the rays. The 8M images keep 1/sqrt(20) of the 400k images' noise, so the
resolution is sqrt(e_8M^2 - (d / sqrt(20))^2), e_8M the model's error on them and d the misplaced
flux between the two folders' images.
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "tests"))
from support.paint_world import World, write_paint_folder  # noqa: E402

from helioflow.data.hdf5 import read_dataset  # noqa: E402
from helioflow.data.paint import import_paint  # noqa: E402
from helioflow.data.surfaces import read_heliostat  # noqa: E402
from helioflow.physics.scene import dataset_scene, misplaced_flux  # noqa: E402
from helioflow.workflow import DIAGNOSIS_DEFAULTS  # noqa: E402

FEW, MANY = 400_000, 8_000_000
SUN = {"sunshape": {"kind": "gaussian", "sigma_mrad": 2.51}}
CAMERAS = {"white": (World(), {}), "blurred": (World(counted_blur_px=1.5), {"camera": {"blur_px": 1.5}}),
           "rectified": (World(rectified=True), {})}


def images(world: World, rays: int, seed: int, n_images: int, folder: Path):
    """(the imported images (N, H, W) / their largest, the dataset) of one PAINT folder."""
    write_paint_folder(folder, world, n_images=n_images, rays=rays, seed=seed)
    import_paint(folder, "AA39", folder / "data.h5", folder / "aa39.h5", dataset=folder.name)
    ds = read_dataset(folder / "data.h5")
    return torch.as_tensor(ds.images).float() / float(ds.images.max()), ds


def main() -> None:
    """Parse the command line and run the measurement the module docstring describes."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=2)
    parser.add_argument("--images", type=int, default=12)
    args = parser.parse_args()
    cells, fit_rays = DIAGNOSIS_DEFAULTS["cells_per_side"], DIAGNOSIS_DEFAULTS["fit_rays"]
    with tempfile.TemporaryDirectory() as tmp:
        for camera, (world, known) in CAMERAS.items():
            for seed in range(args.seeds):
                few, _ = images(world, FEW, seed, args.images, Path(tmp) / f"{camera}{seed}few")
                many, ds = images(world, MANY, seed, args.images, Path(tmp) / f"{camera}{seed}many")
                heliostat = read_heliostat(Path(tmp) / f"{camera}{seed}many" / "aa39.h5").ideal()
                sun = torch.as_tensor(ds.azimuth_deg).float(), torch.as_tensor(ds.elevation_deg).float()
                errors = []
                for c, r in ((cells, fit_rays), (2 * cells, 8 * fit_rays)):
                    scene = dataset_scene(heliostat, ds.attrs, tuple(ds.images.shape[1:]), c, r, True)
                    with torch.no_grad():
                        pred, lost = scene.simulate({**SUN, **known}, {}, *sun, with_lost=True)
                    errors.append(float(misplaced_flux(pred, many, lost).mean()))
                noise_many = float(misplaced_flux(many, few).mean()) / math.sqrt(MANY / FEW)
                resolution = [math.sqrt(max(e * e - noise_many ** 2, 0.0)) for e in errors]
                print(f"{camera} seed {seed}: model vs {MANY:,}-ray images {errors[0]:.4f} "
                      f"(finer model {errors[1]:.4f}), "
                      f"their own noise {noise_many:.4f}: resolution {resolution[0]:.4f} (finer {resolution[1]:.4f})",
                      flush=True)


if __name__ == "__main__":
    main()
