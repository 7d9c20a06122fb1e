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
Then the same floor when the measured spots carry an effect the model does not (issue "The floor must
not eat the model's error"): a shadow edge across each spot (60 % shaded beyond a logistic edge of
1 px at a random angle through the spot), a soiling gradient (4 % less per px downwards) and a spot
widened along x (a 2 px blur); printed: the floor over the error a perfect model (one that has the
effect) gets, which must stay within 25 % of 1, and the model's own error over it.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import torch
from scipy.ndimage import gaussian_filter1d

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "tests"))  # support.noise_images
from support.noise_images import CAMERAS, blurred, counted, eight_bit, spots  # noqa: E402

from helioflow.data.noise import measure_noise  # noqa: E402
from helioflow.diagnosis.noise import measured_noise, noise_floor  # noqa: E402
from helioflow.physics.scene import misplaced_flux  # noqa: E402

SIDE = 64
Y, X = np.mgrid[:SIDE, :SIDE] + 0.5


def _centroid(image: np.ndarray) -> tuple[float, float]:
    """(x, y) flux centroid (px) of one (H, W) image."""
    w = image / image.sum()
    return float((w * X).sum()), float((w * Y).sum())


def shaded(truth: torch.Tensor, seed: int) -> torch.Tensor:
    """Each (H, W) spot 60 % shaded beyond a logistic edge (1 px) at a random angle within 2 px of its centroid."""
    rng = np.random.default_rng(seed)
    out = []
    for image in truth.numpy():
        cx, cy = _centroid(image)
        angle = rng.uniform(0.0, np.pi)
        d = (X - cx) * np.cos(angle) + (Y - cy) * np.sin(angle) - rng.uniform(-2.0, 2.0)
        out.append(image * (1.0 - 0.6 / (1.0 + np.exp(-d))))
    return torch.as_tensor(np.stack(out))


def soiled(truth: torch.Tensor, seed: int) -> torch.Tensor:
    """Each spot dimmed by 4 % per px below its centroid (brighter above)."""
    return torch.as_tensor(np.stack([i * np.clip(1.0 - 0.04 * (Y - _centroid(i)[1]), 0.0, None)
                                     for i in truth.numpy()]))


def widened(truth: torch.Tensor, seed: int) -> torch.Tensor:
    """Each spot blurred along x by 2 px (a sag or astigmatism the model lacks)."""
    return torch.as_tensor(gaussian_filter1d(truth.numpy(), 2.0, axis=-1, mode="constant"))


HIDDEN = {"nothing": lambda truth, seed: truth, "shadow edge": shaded, "soiling gradient": soiled,
          "widened": widened}
HIDDEN_CAMERAS = ("white, 8-bit", "blurred 1.5 px, 8-bit", "rectified, 8-bit")

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
    print(f"\n{'hidden effect: floor / perfect':34s}" + "".join(f"{c:>24s}" for c in HIDDEN_CAMERAS))
    for effect, hide in HIDDEN.items():
        cells = []
        for camera in HIDDEN_CAMERAS:
            resample, quantise = CAMERAS[camera]
            ratios = []
            for seed in range(seeds):
                truth = spots(12, 1000 + seed)
                world = hide(truth, 3000 + seed)
                measured = resample(counted(world, 300.0, 2000 + seed))
                measured = eight_bit(measured) if quantise else measured
                perfect = float(misplaced_flux(resample(world), measured).mean())
                model = resample(truth)
                floor = float(noise_floor(model, measured, measured_noise(model, measured))[0].mean())
                ratios.append((floor / perfect, float(misplaced_flux(model, measured).mean()) / floor))
            r = np.array(ratios)
            cells.append(f"{r[:, 0].mean():.2f} ({r[:, 0].min():.2f}-{r[:, 0].max():.2f}) x{r[:, 1].mean():.1f}")
        print(f"{effect:34s}" + "".join(f"{c:>24s}" for c in cells))


if __name__ == "__main__":
    main()
