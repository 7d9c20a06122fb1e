"""A mask on the mirror (Optics.mirror_mask; the soiling effect): the same physics in the fast tracer,
the linearised trace and the reference tracer, and the power it takes is the mask's mean."""

import math

import numpy as np
import pytest
import torch

from helioflow.physics.effects import resolve
from helioflow.physics.heliostat import ideal_heliostat
from helioflow.physics.raytrace import trace
from helioflow.physics.reference import reference_trace
from helioflow.physics.scene import LinearisedScene, Scene
from helioflow.physics.target import Target

SOILED = {"sunshape": {"kind": "gaussian", "sigma_mrad": 1.0}, "soiling": {"gradient": 0.6}}
CLEAN = {"sunshape": {"kind": "gaussian", "sigma_mrad": 1.0}}


def heliostat(dtype=torch.float64):
    """2 x 2 flat facets canted at 40 m, 40 m from the target (its spot shows each facet's image)."""
    return ideal_heliostat(rows=2, cols=2, width=1.2, height=1.0, gap=0.02, position=(0.0, 40.0, 0.0),
                           canting_focal_distance=40.0, control_points=5, dtype=dtype)


def target(dtype=torch.float64) -> Target:
    return Target(torch.tensor([0.0, 0.0, 8.0], dtype=dtype), torch.tensor([0.0, 1.0, 0.0], dtype=dtype), 4.0, 4.0,
                  (48, 48))


def test_soiling_takes_its_mean_from_the_power_and_dims_the_lower_part_of_each_facets_image():
    h, tg = heliostat(), target()
    az, el = torch.tensor([0.3]), torch.tensor([0.7])
    soiled, clean = (trace(resolve(e, h, 1000.0).heliostat, tg, az, el, resolve(e, h, 1000.0).optics, rays=0,
                           splat="kernel", cells_per_side=24)[0] for e in (SOILED, CLEAN))
    # reflectance falls linearly from 1 at the top edge to 0.4 at the bottom: its mean is 0.7
    assert float(soiled.sum() / clean.sum()) == pytest.approx(0.7, abs=0.005)
    rows = torch.arange(48, dtype=torch.float64)[:, None]

    def centroid_row(image) -> float:
        return float((image * rows).sum() / image.sum())

    assert centroid_row(soiled) < centroid_row(clean) - 0.2  # the spot's flux moves up (rows count downwards)


def test_the_fast_the_linearised_and_the_reference_tracer_agree_on_a_soiled_mirror():
    """Fast (kernel) vs the exact per-ray reference: PSNR > 40 dB (the reference's noise); the
    linearised trace vs the fast one: > 60 dB (the same physics, hits linearised)."""
    h, tg = heliostat(), target()
    az, el = math.radians(15.0), math.radians(40.0)
    physics = resolve(SOILED, h, 1000.0)
    fast = trace(physics.heliostat, tg, torch.tensor([az]), torch.tensor([el]), physics.optics, rays=0,
                 splat="kernel", cells_per_side=32)[0].numpy()
    ref = (reference_trace(physics.heliostat, tg, az, el, physics.optics, 400_000, seed=1)
           + reference_trace(physics.heliostat, tg, az, el, physics.optics, 400_000, seed=2)) / 2

    def psnr(a, b) -> float:
        return 10 * math.log10(max(a.max(), b.max()) ** 2 / np.mean((a - b) ** 2))

    assert psnr(fast, ref) > 40.0, psnr(fast, ref)
    assert fast.sum() == pytest.approx(ref.sum(), rel=0.01)
    scene = Scene(heliostat(torch.float32), target(torch.float32), 1000.0, cells_per_side=16)
    sun = torch.tensor([15.0, 40.0]), torch.tensor([40.0, 25.0])
    with torch.no_grad():
        exact = scene.simulate(SOILED, {}, *sun)
        linear = LinearisedScene.of(scene, SOILED, {}, *sun).simulate(SOILED, {}, *sun)
    assert float(((linear - exact) ** 2).mean()) < 1e-6 * float(exact.max()) ** 2  # > 60 dB
