"""Make this example: 12 camera images of the default config's `square` heliostat, traced by helioflow.

    .venv/bin/python examples/own_images/make_example.py    # from the repository root; a few seconds

The heliostat is config.yaml's `square` with its true errors (the `surfaces` rule's: 0.5 mm surface
deformation, 1 mrad tracking errors, seed 1) under config.yaml's world effects (Buie sun, CSR 0.1,
0.5 mrad slope error), at the sun of each timestamp of calibration.csv at the site below (the sun
that `helioflow import-images` computes from them). Each image is traced on the target of
workflow/variants/own_images.yaml (4 m x 4 m, centre 20 m up the tower, facing north), as a camera
would record it: 96 x 96 pixels, an exposure of 70-95 % of full scale, a 2 % background and noise,
16-bit greyscale PNG. The dataset the variant imports from it is what a plant's own camera gives:
relative grey levels, each image scaled differently.
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import torch
import yaml
from PIL import Image

from helioflow.config import HeliostatSpec
from helioflow.data.images import parse_timestamp, sun_position
from helioflow.data.surfaces import true_heliostat
from helioflow.data.synthetic import trace_images
from helioflow.physics.effects import resolve
from helioflow.physics.target import Target

HERE = Path(__file__).resolve().parent
REPO = HERE.parents[1]
SITE = {"latitude_deg": 50.9134, "longitude_deg": 6.3868, "altitude_m": 87.0}  # the solar tower Juelich
TARGET = {"center_m": [0.0, 0.0, 20.0], "normal": [0.0, 1.0, 0.0], "width_m": 4.0, "height_m": 4.0}
PIXELS = (96, 96)
TIMES = ["2023-03-21T09:00:00+01:00", "2023-03-21T12:30:00+01:00", "2023-03-21T16:00:00+01:00",
         "2023-05-10T08:30:00+02:00", "2023-05-10T11:00:00+02:00", "2023-05-10T15:30:00+02:00",
         "2023-05-10T18:00:00+02:00", "2023-06-21T10:00:00+02:00", "2023-06-21T13:30:00+02:00",
         "2023-06-21T17:00:00+02:00", "2023-09-15T10:30:00+02:00", "2023-09-15T16:30:00Z"]


def main() -> None:
    config = yaml.safe_load((REPO / "config.yaml").read_text())
    spec = HeliostatSpec.from_config("square", config["heliostats"]["square"])
    physics = resolve(config["world"]["effects"], true_heliostat(spec), config["dni_w_m2"])
    heliostat = physics.heliostat.to("cpu")
    az, el = sun_position([parse_timestamp(t, "TIMES") for t in TIMES], SITE)
    target = Target(torch.tensor(TARGET["center_m"]), torch.tensor(TARGET["normal"]), TARGET["width_m"],
                    TARGET["height_m"], PIXELS)
    images = trace_images(physics, heliostat, target, torch.tensor(np.radians(az), dtype=torch.float32),
                          torch.tensor(np.radians(el), dtype=torch.float32),
                          {"splat": "kernel", "rays": 0, "cells_per_side": 48}, seed=config["seed"]).numpy()
    rng = np.random.default_rng(2023)
    rows = []
    for i, (image, stamp) in enumerate(zip(images, TIMES)):
        exposure = rng.uniform(0.70, 0.95)
        grey = exposure * image / image.max() + 0.02 + rng.normal(0.0, 0.004, image.shape)
        name = f"cam_{i + 1:02d}.png"
        Image.fromarray(np.round(np.clip(grey, 0, 1) * 65535).astype(np.uint16)).save(HERE / "images" / name)
        rows.append({"file": name, "timestamp": stamp})
    with (HERE / "calibration.csv").open("w", newline="") as f:
        writer = csv.DictWriter(f, ["file", "timestamp"], lineterminator="\n")
        writer.writeheader()
        writer.writerows(rows)
    for row, a, e in zip(rows, az, el):
        print(f"{row['file']}  {row['timestamp']}  sun azimuth {a:7.2f}  elevation {e:6.2f}")


if __name__ == "__main__":
    main()
