"""Shading and blocking by a neighbour of known position (effect neighbour_shading): the power it
takes matches an independent numpy Monte Carlo (tests/support/paint_world.py, its own kinematics and ray
geometry) at every sun position, and the fast tracer matches the exact per-ray reference tracer."""

import math

import numpy as np
import pytest
import torch
from support.paint_world import Scene as World_scene
from support.paint_world import World, calibration_suns, trace_image, write_paint_folder

from helioflow.data.hdf5 import read_dataset
from helioflow.data.paint import import_paint
from helioflow.data.surfaces import read_heliostat
from helioflow.errors import ConfigError
from helioflow.physics.effects import resolve
from helioflow.physics.raytrace import trace
from helioflow.physics.reference import reference_trace
from helioflow.physics.scene import dataset_scene

NEIGHBOUR = (0.0, -3.5, 0.0)  # 3.5 m south of AA39: shades it at low sun
SUN = {"sunshape": {"kind": "gaussian", "sigma_mrad": 2.51}}


@pytest.fixture(scope="module")
def imported(tmp_path_factory):
    """AA39's PAINT folder with the neighbour published (AA40), imported: (dataset, heliostat)."""
    folder = tmp_path_factory.mktemp("neighbour")
    write_paint_folder(folder, World(neighbour_enu_m=NEIGHBOUR), n_images=2, rays=20_000, seed=0, neighbour="AA40")
    import_paint(folder, "AA39", folder / "data.h5", folder / "aa39.h5")
    return read_dataset(folder / "data.h5"), read_heliostat(folder / "aa39.h5").ideal()


def test_the_import_lists_the_neighbours_within_30_m(imported):
    ds, heliostat = imported
    (pivot,) = ds.attrs["neighbours_enu_m"]
    assert np.allclose(np.subtract(pivot, heliostat.position.numpy()), NEIGHBOUR, atol=0.01)


def test_the_power_a_neighbour_takes_matches_an_independent_monte_carlo(imported):
    ds, heliostat = imported
    scene = dataset_scene(heliostat.to("cpu", torch.float32), ds.attrs, (64, 64), 24, 0, False)
    suns = calibration_suns(16, 3)
    az, el = (torch.tensor([s[i] for s in suns], dtype=torch.float32) for i in (0, 1))
    with torch.no_grad():
        powers = [scene.simulate(e, {}, az, el, with_lost=True) for e in ({**SUN, "neighbour_shading": {}}, SUN)]
    shaded, clean = ((image.sum((-2, -1)) * scene.target.pixel_area + lost).numpy() for image, lost in powers)
    ours = 1.0 - shaded / clean
    world = World_scene("solar_tower_juelich_upper")
    theirs = np.array([1.0 - trace_image(world, World(neighbour_enu_m=NEIGHBOUR), a, e, 200_000,
                                         np.random.default_rng(i)).sum()
                       / trace_image(world, World(), a, e, 200_000, np.random.default_rng(i)).sum()
                       for i, (a, e) in enumerate(suns)])
    assert theirs.max() > 0.1 and (theirs < 0.01).sum() >= 4  # some sun positions shaded, others not
    assert np.abs(ours - theirs).max() < 0.03, np.round(np.stack((ours, theirs)), 3)


def test_fast_and_reference_tracer_agree_on_a_shaded_heliostat(imported):
    ds, heliostat = imported
    h = heliostat.to("cpu", torch.float64)
    scene = dataset_scene(h, ds.attrs, (64, 64), 24, 0, False)
    physics = resolve({**SUN, "neighbour_shading": {}}, h, 1000.0, scene.neighbours.double())
    az, el = math.radians(-5.0), math.radians(18.0)  # low sun from the south: a third shaded
    fast = trace(physics.heliostat, scene.target, torch.tensor([az]), torch.tensor([el]), physics.optics, rays=0,
                 splat="kernel", cells_per_side=32)[0].numpy()
    ref = reference_trace(physics.heliostat, scene.target, az, el, physics.optics, 600_000, seed=4)
    clean = trace(h, scene.target, torch.tensor([az]), torch.tensor([el]), resolve(SUN, h, 1000.0).optics, rays=0,
                  splat="kernel", cells_per_side=32)[0].numpy()
    assert fast.sum() < 0.9 * clean.sum()  # the neighbour takes a real share
    assert fast.sum() == pytest.approx(ref.sum(), rel=0.02)
    psnr = 10 * math.log10(max(fast.max(), ref.max()) ** 2 / np.mean((fast - ref) ** 2))
    assert psnr > 35.0, psnr


def test_a_model_with_neighbour_shading_needs_the_neighbours(imported):
    _, heliostat = imported
    with pytest.raises(ConfigError, match="needs the neighbours' positions"):
        resolve({"neighbour_shading": {}}, heliostat, 1000.0)
