"""The plant fit (diagnosis/shared.py) over several independent plants: what it names as shared and
the camera blur it finds, per seed, against the truth (tests/support/paint_world.py `plant_worlds`: one
Gaussian sun the model is told, one camera it is not, background 3 % of the peak, blur 1.5 px).

Run: python scripts/experiments/shared_cases.py [--seeds 3 4 5] [--heliostats 6] [--images 16]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "tests"))  # support.paint_world
from support.paint_world import plant_worlds, write_plant  # noqa: E402

from helioflow.data.paint import import_paint  # noqa: E402
from helioflow.diagnosis.shared import plant_shared  # noqa: E402
from helioflow.workflow import plant_settings  # noqa: E402

BELIEVED = {"sunshape": {"kind": "gaussian", "sigma_mrad": 2.51}}
TRUE_BLUR_PX, RAYS, HELD_OUT = 1.5, 300_000, 0.25


def run(seed: int, n: int, n_images: int, folder: Path) -> dict:
    """shared.json's entry for one plant of `n` heliostats drawn with `seed`."""
    truth = write_plant(folder, plant_worlds(n, seed), n_images, RAYS, seed)
    ids = [str(100_000 + i) for i in range(n_images)]
    held = list(np.random.default_rng(seed).choice(ids, round(HELD_OUT * n_images), replace=False))
    entries = []
    for name in truth:
        import_paint(folder, name, folder / f"{name}.h5", folder / f"{name}_geometry.h5", holdout=held, dataset=name)
        entries.append({"heliostat": name, "dataset_path": str(folder / f"{name}.h5"),
                        "heliostat_path": str(folder / f"{name}_geometry.h5"), "effects": BELIEVED})
    settings = {**plant_settings({})["shared"], "fit_images": n_images - len(held), "heldout_images": len(held)}
    spec = {"settings": settings, "device": "cpu", "plants": {"plant": entries}}
    return plant_shared(spec, folder / "shared.json")["plant"]


def main() -> None:
    """Parse the command line and run the measurement the module docstring describes."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[3, 4, 5])
    ap.add_argument("--heliostats", type=int, default=6)
    ap.add_argument("--images", type=int, default=16)
    args = ap.parse_args()
    print("| seed | shared changes | camera blur (px, true 1.5) | (blur - true) / sigma | heliostats kept by the level "
          "| plant held-out error: model -> shared | s |")
    print("|---|---|---|---|---|---|---|")
    for seed in args.seeds:
        start = time.time()
        with tempfile.TemporaryDirectory() as tmp:
            out = run(seed, args.heliostats, args.images, Path(tmp))
        values = {n: v for s in out["shared"] for n, v in s["values"].items()}
        blur = values.get("camera.blur_px")
        words = "-" if blur is None else f"{blur['value']:.3f} +- {blur['sigma']:.3f}"
        pull = "-" if blur is None else f"{(blur['value'] - TRUE_BLUR_PX) / blur['sigma']:+.1f}"
        kept = "-" if blur is None else f"{sum(a['kept'] for a in blur['alone'].values())} of {len(blur['alone'])}"
        print(f"| {seed} | {', '.join(out['changes']) or 'none'} | {words} | {pull} | {kept} | "
              f"{out['heldout_error']['model']:.4f} -> {out['heldout_error']['shared']:.4f} | "
              f"{time.time() - start:.0f} |",
              flush=True)


if __name__ == "__main__":
    main()
