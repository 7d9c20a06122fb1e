"""False alarms of the diagnosis on images with nothing hidden and noise that is not white, over
seeds (docs/diagnosis.md, "False alarms").

    python scripts/experiments/false_alarms.py [--seeds 10] [--cameras blurred rectified]

Each seed: a PAINT folder of AA39 (24 images of 400 000 rays, 8-bit, 6 held out) made by the
independent Monte Carlo of tests/paint_world.py under the Gaussian sun the model believes, nothing
else hidden but the camera's way of writing the image (`blurred`: a 1.5 px blur after the counting,
the noise smooth over pixels, and the model knows the camera's blur: it blurs the spot too;
`rectified`: resampled onto a turned camera grid and back; `white`: as counted), imported and diagnosed as tests/diagnosis/test_diagnose_independent.py does (max_effects
1). An alarm: any change named (per candidate, and for the whole verdict), or what remains not
explained down to the noise. Printed per seed and as rates.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from collections import Counter
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "tests"))
from paint_world import World, write_paint_folder  # noqa: E402

from helioflow.data.paint import import_paint  # noqa: E402
from helioflow.diagnosis.diagnose import diagnose_dataset  # noqa: E402
from helioflow.workflow import DIAGNOSIS_DEFAULTS  # noqa: E402

N_IMAGES, HELD_OUT, RAYS = 24, 6, 400_000
BELIEVED = {"sunshape": {"kind": "gaussian", "sigma_mrad": 2.51}}
CAMERAS = {  # camera: (the world, the camera the model knows)
    "white": (World(), {}),
    "blurred": (World(counted_blur_px=1.5), {"camera": {"blur_px": 1.5}}),
    "rectified": (World(rectified=True), {}),
}


def diagnose_seed(world: World, known: dict, seed: int, root: Path) -> dict:
    """The diagnosis JSON of one nothing-hidden folder of `world` made from `seed`, the model the
    believed sun and the `known` camera."""
    folder = root / f"seed{seed}"
    write_paint_folder(folder, world, n_images=N_IMAGES, rays=RAYS, seed=seed)
    ids = [str(100_000 + i) for i in range(N_IMAGES)]
    held = list(np.random.default_rng(seed).choice(ids, HELD_OUT, replace=False))
    import_paint(folder, "AA39", folder / "data.h5", folder / "aa39.h5", holdout=held, dataset=f"seed{seed}")
    figures = {k: folder / f"{k}.png" for k in ("signatures", "ranking", "residuals", "location", "ledger")}
    settings = {**DIAGNOSIS_DEFAULTS, "fit_images": N_IMAGES - HELD_OUT, "heldout_images": HELD_OUT, "max_effects": 1}
    return diagnose_dataset(folder / "data.h5", folder / "aa39.h5", {**BELIEVED, **known}, settings, folder / "diagnosis.json",
                            figures, folder / "ledger.json")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--cameras", nargs="+", default=["blurred", "rectified"], choices=list(CAMERAS))
    args = parser.parse_args()
    for camera in args.cameras:
        per_candidate, alarms = Counter(), 0
        with tempfile.TemporaryDirectory() as tmp:
            for seed in range(args.seeds):
                result = diagnose_seed(*CAMERAS[camera], seed, Path(tmp))
                named = [r["changes"] for r in result["ranking"] if r["meaningful"]]
                remaining = result["remaining"]
                per_candidate.update(named)
                alarms += bool(named) or not remaining["explained"]
                print(f"{camera} seed {seed}: named {named or 'nothing'}, held-out {remaining['error']:.4f}, "
                      f"floor {result['noise_floor']:.4f}, {remaining['over_noise']:.2f} x the noise, "
                      f"correlation {result['noise']['model']['correlation_px']} px", flush=True)
        rates = ", ".join(f"{c} {n}/{args.seeds}" for c, n in per_candidate.most_common()) or "none"
        print(f"{camera}: verdict alarms {alarms}/{args.seeds}; per candidate: {rates}", flush=True)


if __name__ == "__main__":
    main()
