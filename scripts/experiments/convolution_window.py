"""What computing only the target's window of the splat's convolution saves (raytrace.convolve with
`window`: a circular FFT of the shortest fast length free of wrap-around, instead of the full linear
convolution cut afterwards): a kernel trace of a dataset's first 16 sun positions with its backward
through a tracking error, the full convolution and the window alternated in one process so that the
ratio is measured under one load, and the largest difference of their images. A measurement script,
not a test.

Run: python scripts/experiments/convolution_window.py [--dataset results/default/datasets/sanity_check.h5
     --heliostat results/default/surfaces/square.h5] [--repeats 5]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch

from helioflow.data.hdf5 import read_dataset
from helioflow.data.surfaces import read_heliostat
from helioflow.physics import raytrace
from helioflow.physics.scene import dataset_scene


def full_then_cut(images, kernels, window=None):
    """The convolution as it was: the full linear convolution, then the window cut out of it."""
    full = (images.shape[-2] + kernels.shape[-2] - 1, images.shape[-1] + kernels.shape[-1] - 1)
    size = tuple(raytrace._fft_size(n) for n in full)
    spectrum = (torch.fft.rfft2(images, s=size) * torch.fft.rfft2(kernels, s=size)).sum(1)
    out = torch.fft.irfft2(spectrum, s=size)[..., : full[0], : full[1]]
    (r0, rows), (c0, cols) = window or ((0, full[0]), (0, full[1]))
    return out[..., r0 : r0 + rows, c0 : c0 + cols]


def main() -> None:
    """Parse the command line and run the measurement the module docstring describes."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--dataset", default="results/default/datasets/sanity_check.h5")
    ap.add_argument("--heliostat", default="results/default/surfaces/square.h5")
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
    torch.set_num_threads(1)
    ds = read_dataset(args.dataset)
    scene = dataset_scene(read_heliostat(args.heliostat).ideal(), ds.attrs, tuple(ds.images.shape[1:]), 16, 50000, True)
    az, el = torch.tensor(ds.azimuth_deg[:16]).float(), torch.tensor(ds.elevation_deg[:16]).float()
    effects = {"sunshape": {"kind": "buie", "csr": 0.1}}
    variants = {"full convolution": full_then_cut, "window": raytrace.convolve}
    seconds, images = {name: [] for name in variants}, {}
    for _ in range(args.repeats):
        for name, convolve in variants.items():
            raytrace.convolve = convolve
            tracking = {"tracking": torch.tensor([0.5, -0.3, 0.2, 0.1, -0.4], requires_grad=True)}
            start = time.perf_counter()
            image = scene.simulate(effects, tracking, az, el)
            image.square().sum().backward()
            seconds[name].append(time.perf_counter() - start)
            images[name] = image.detach()
    for name, times in seconds.items():
        print(f"{name}: trace + backward of 16 images {np.median(times):.3f} s (median of {args.repeats})")
    ratio = np.median(seconds["window"]) / np.median(seconds["full convolution"])
    difference = float((images["window"] - images["full convolution"]).abs().max() / images["window"].abs().max())
    print(f"window / full: {ratio:.2f}; largest difference {difference:.1e} of the peak")


if __name__ == "__main__":
    main()
