"""The noise floor on noise that is not white: how close each estimate comes to the error a perfect
model gets, over seeds (docs/diagnosis.md, "The noise floor").

    python scripts/experiments/noise_floor.py [--seeds 20]

Spots: 12 Gaussians of 3-6 px per seed on 64 x 64 images, photon noise of 300 photons at the peak,
then each camera of tests/support/noise_images.py (blur after the counting, rectification, 8-bit)
and two blurs beyond what the floor can see (2 and 3 px).
Printed per camera: the floor over the perfect model's error (mean, min - max over seeds) for the
images' own operator (`measure_noise`, model-free, white) and for the diagnosis' estimate
(`measured_noise`: the residual's spectrum, or the operator where it reads more), and the latter
for a model whose spots sit 2 px off (a mismatch 30x
the noise: it must not pass for noise), and the correlation length read (px).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "tests"))  # support.noise_images
from support.noise_images import CAMERAS, blurred, counted, eight_bit, spots  # noqa: E402

from helioflow.data.noise import measure_noise  # noqa: E402
from helioflow.diagnosis.noise import measured_noise, noise_floor  # noqa: E402
from helioflow.physics.scene import misplaced_flux  # noqa: E402

BEYOND = {  # noise blurred over more than the floor can see: its power lies where the spot's does
    "blurred 2 px, 8-bit": (lambda x: blurred(x, 2.0), True),
    "blurred 3 px, 8-bit": (lambda x: blurred(x, 3.0), True),
}


def main() -> None:
    """Parse the command line and run the measurement the module docstring describes."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=20)
    seeds = parser.parse_args().seeds
    torch.set_num_threads(1)
    print(f"{'camera':34s} {'operator':>18s} {'measured_noise':>18s} {'mismatched model':>18s} {'b (px)':>8s}")
    for name, (resample, quantise) in {**CAMERAS, **BEYOND}.items():
        rows = []
        for seed in range(seeds):
            truth = spots(12, 1000 + seed)
            perfect = resample(truth)
            measured = resample(counted(truth, 300.0, 2000 + seed))
            measured = eight_bit(measured) if quantise else measured
            actual = float(misplaced_flux(perfect, measured).mean())
            shifted = torch.roll(perfect, 2, dims=-1)
            noise = measured_noise(perfect, measured)
            rows.append((float(noise_floor(perfect, measured, measure_noise(measured))[0].mean()) / actual,
                         float(noise_floor(perfect, measured, noise)[0].mean()) / actual,
                         float(noise_floor(shifted, measured, measured_noise(shifted, measured))[0].mean()) / actual,
                         noise.correlation_px))
        r = np.array(rows)

        def cell(c: int) -> str:
            return f"{r[:, c].mean():.2f} ({r[:, c].min():.2f}-{r[:, c].max():.2f})"

        print(f"{name:34s} {cell(0):>18s} {cell(1):>18s} {cell(2):>18s} {r[:, 3].mean():8.2f}")


if __name__ == "__main__":
    main()
