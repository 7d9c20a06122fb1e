"""The diagnosis' error rates over seeds (docs/diagnosis.md, "Error rates"): false alarms on images
with nothing hidden and noise that is not white, and the power on small effects.

    python scripts/experiments/error_rates.py [--seeds 20] [--cases blurred rectified white canting tracking slope]

Each seed: a PAINT folder of AA39 (24 images of 400 000 rays, 8-bit, 6 held out) made by the
independent Monte Carlo of tests/support/paint_world.py under the Gaussian sun the model believes,
imported and diagnosed as tests/diagnosis/test_diagnose_independent.py does (max_effects 1).

- Nothing hidden but the camera's way of writing the image: `blurred`, a 1.5 px blur after the
  counting (the noise smooth over pixels; the model knows the camera's blur: it blurs the spot
  too); `rectified`, resampled onto a turned camera grid and back; `white`, as counted. An alarm:
  any change named (counted per candidate, and for the whole verdict), or what remains not
  explained down to the noise.
- A small effect hidden, drawn per seed (white camera): `canting`, facet tilts of 0.3 mrad RMS
  about their mean; `tracking`, both joint offsets 0.5 mrad with random signs; `slope`, a slope
  error of 0.5 mrad. Found: the effect named (chosen, or as the confounded partner of the chosen
  change); wrong: another change named instead.
Printed per seed and as rates.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from collections import Counter
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "tests"))
from support.paint_world import World, write_paint_folder  # noqa: E402

from helioflow.data.paint import import_paint  # noqa: E402
from helioflow.diagnosis.diagnose import diagnose_dataset  # noqa: E402
from helioflow.workflow import DIAGNOSIS_DEFAULTS  # noqa: E402

N_IMAGES, HELD_OUT, RAYS = 24, 6, 400_000
BELIEVED = {"sunshape": {"kind": "gaussian", "sigma_mrad": 2.51}}
CAMERAS = {  # nothing hidden: camera -> (the world, the camera the model knows)
    "white": (World(), {}),
    "blurred": (World(counted_blur_px=1.5), {"camera": {"blur_px": 1.5}}),
    "rectified": (World(rectified=True), {}),
}
EFFECTS = ("canting", "tracking", "slope")  # a small effect hidden (module doc); its registry name:
REGISTRY_NAME = {"canting": "canting", "tracking": "tracking", "slope": "slope_error"}


def small_effect(effect: str, seed: int) -> World:
    """The world of seed `seed` hiding a small `effect` (module doc)."""
    rng = np.random.default_rng(1000 + seed)
    if effect == "canting":
        tilts = rng.normal(0.0, 1.0, (4, 2))
        tilts -= tilts.mean(0)
        return World(canting_mrad=tilts * 0.3 / np.sqrt((tilts ** 2).mean()))
    if effect == "tracking":
        return World(tracking_mrad=tuple(0.5 * rng.choice([-1.0, 1.0], 2)))
    return World(slope_mrad=0.5)


def diagnose_seed(world: World, known: dict, seed: int, root: Path) -> dict:
    """The diagnosis JSON of one folder of `world` made from `seed`, the model the believed sun and
    the `known` camera."""
    folder = root / f"seed{seed}"
    write_paint_folder(folder, world, n_images=N_IMAGES, rays=RAYS, seed=seed)
    ids = [str(100_000 + i) for i in range(N_IMAGES)]
    held = list(np.random.default_rng(seed).choice(ids, HELD_OUT, replace=False))
    import_paint(folder, "AA39", folder / "data.h5", folder / "aa39.h5", holdout=held, dataset=f"seed{seed}")
    settings = {**DIAGNOSIS_DEFAULTS, "fit_images": N_IMAGES - HELD_OUT, "heldout_images": HELD_OUT, "max_effects": 1}
    return diagnose_dataset(folder / "data.h5", folder / "aa39.h5", {**BELIEVED, **known}, settings,
                            folder / "diagnosis.json", None, folder / "ledger.json")


def named_in(result: dict) -> tuple[list[str], set[str]]:
    """(the changes named, those and their confounded partners)."""
    named = [r for r in result["ranking"] if r["meaningful"]]
    partners = {c["effect"].split(":")[0] for r in named for c in r["confounded_with"]}
    return [r["changes"] for r in named], {r["changes"] for r in named} | partners


def main() -> None:
    """Parse the command line and run the measurement the module docstring describes."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--cases", nargs="+", default=[*CAMERAS, *EFFECTS], choices=[*CAMERAS, *EFFECTS])
    args = parser.parse_args()
    for case in args.cases:
        per_candidate, alarms, found, wrong = Counter(), 0, 0, 0
        with tempfile.TemporaryDirectory() as tmp:
            for seed in range(args.seeds):
                world, known = CAMERAS[case] if case in CAMERAS else (small_effect(case, seed), {})
                result = diagnose_seed(world, known, seed, Path(tmp))
                named, with_partners = named_in(result)
                remaining = result["remaining"]
                per_candidate.update(named)
                alarms += bool(named) or not remaining["explained"]
                if case in EFFECTS:
                    found += REGISTRY_NAME[case] in with_partners
                    wrong += bool(named) and REGISTRY_NAME[case] not in with_partners
                print(f"{case} seed {seed}: named {named or 'nothing'}, before {result['heldout_error']:.4f}, "
                      f"held-out {remaining['error']:.4f}, floor {result['noise_floor']:.4f}, "
                      f"{remaining['over_noise']:.2f} x noise and resolution, "
                      f"correlation {result['noise']['model']['correlation_px']} px", flush=True)
        rates = ", ".join(f"{c} {n}/{args.seeds}" for c, n in per_candidate.most_common()) or "none"
        if case in CAMERAS:
            print(f"{case}: verdict alarms {alarms}/{args.seeds}; changes named per candidate: {rates}", flush=True)
        else:
            print(f"{case}: found {found}/{args.seeds}, another change named instead {wrong}/{args.seeds}; "
                  f"named per candidate: {rates}", flush=True)


if __name__ == "__main__":
    main()
