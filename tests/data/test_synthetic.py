"""Synthetic calibration datasets (rule `trace`): file contents, determinism, energy, sun positions,
and a clear DataError for a bad heliostat file."""

import copy
from pathlib import Path

import h5py
import numpy as np
import pytest
import torch

from helioflow.config import load_config
from helioflow.data.hdf5 import SPLITS, read_dataset
from helioflow.data.surfaces import HeliostatSpec, true_heliostat, write_heliostat
from helioflow.data.synthetic import MIN_FILL, config_hash, sun_positions, trace_dataset
from helioflow.errors import DataError
from helioflow.physics.geometry import normalize, sun_vector
from helioflow.workflow import surfaces_params, trace_params

TINY = Path(__file__).resolve().parents[1] / "workflow" / "tiny_config.yaml"


@pytest.fixture(scope="module")
def tiny():
    return load_config(TINY)


def _heliostat_file(directory: Path, config: dict, name: str, **overrides) -> Path:
    params = surfaces_params(config, name)
    params.update(overrides)
    spec = HeliostatSpec.from_config(params.pop("name"), params)
    path = directory / f"{name}.h5"
    write_heliostat(path, true_heliostat(spec), spec)
    return path


@pytest.fixture(scope="module")
def heliostat(tiny, tmp_path_factory):
    """The tiny config's 1 m x 1 m heliostat `small` with its seeded deformation and tracking errors."""
    return _heliostat_file(tmp_path_factory.mktemp("surfaces"), tiny, "small")


def _spec(config, dataset="scan", resolution=(32, 32), **changes):
    spec = trace_params(config, dataset)
    spec["target"]["resolution"] = list(resolution)
    spec.update(changes)
    return spec


@pytest.fixture(scope="module")
def traced(tiny, heliostat, tmp_path_factory):
    spec = _spec(tiny)
    out = tmp_path_factory.mktemp("datasets") / "scan.h5"
    returned = trace_dataset(spec, heliostat, out)
    return spec, out, returned


def test_the_written_dataset_reads_back_complete(traced):
    spec, path, returned = traced
    ds = read_dataset(path)
    assert ds.images.shape == (6, 32, 32) and ds.images.dtype == np.float32
    np.testing.assert_array_equal(ds.images, returned.images)
    np.testing.assert_allclose(ds.elevation_deg, np.linspace(20.0, 70.0, 6))
    np.testing.assert_allclose(ds.azimuth_deg, np.full(6, 10.0))
    # splits: elevation above 65 deg is extrapolation; 20 % of the rest (interior only) interpolation
    assert set(ds.split) <= set(SPLITS)
    np.testing.assert_array_equal(ds.split == "extrapolation", ds.elevation_deg > 65.0)
    assert (ds.split == "interpolation").sum() == 1
    assert ds.split[0] == "train"
    a = ds.attrs
    assert a["units"] == {"images": "W/m^2", "angles": "deg", "lengths": "m"}
    assert (a["dataset"], a["heliostat"], a["seed"], a["dni_w_m2"]) == ("scan", "small", 7, 1000.0)
    assert a["config_hash"] == config_hash(spec) and len(a["config_hash"]) == 64
    assert a["world_effects"] == spec["world_effects"] and a["trace"] == spec["trace"]
    side = a["target_size_m"][0]
    assert side > 0 and a["target_size_m"] == [side, side]
    fill = ds.extras["fill_fraction"]
    assert fill.shape == (6,) and ((fill > 0) & (fill <= 1)).all()
    assert a["fill_fraction_min"] == pytest.approx(fill.min())
    assert fill.min() >= MIN_FILL  # the auto window keeps every spot at >= 10 % of the pixels
    with h5py.File(path) as f:
        assert f["images"].attrs["units"] == "W/m^2"
        assert f["sun/elevation_deg"].attrs["units"] == "deg"


def test_images_are_finite_non_negative_flux(traced):
    images = read_dataset(traced[1]).images
    assert np.isfinite(images).all() and images.min() >= 0.0
    assert (images.max((1, 2)) > 100.0).all()  # a real spot in W/m^2 in every image


def test_config_hash_follows_the_spec(tiny):
    assert config_hash(_spec(tiny)) == config_hash(copy.deepcopy(_spec(tiny)))
    assert config_hash(_spec(tiny)) != config_hash(_spec(tiny, seed=8))


def test_same_spec_gives_bit_identical_images(tiny, tmp_path):
    """Bilinear splatting draws random rays: a fixed seed still gives identical files' images."""
    path = _heliostat_file(tmp_path, tiny, "small_grid")
    spec = _spec(tiny, "sky", window_m=2.0)
    a = trace_dataset(spec, path, tmp_path / "a.h5")
    b = trace_dataset(copy.deepcopy(spec), path, tmp_path / "b.h5")
    c = trace_dataset({**spec, "seed": 8}, path, tmp_path / "c.h5")
    ra, rb = read_dataset(tmp_path / "a.h5"), read_dataset(tmp_path / "b.h5")
    assert ra.images.tobytes() == rb.images.tobytes() and a.images.tobytes() == b.images.tobytes()
    np.testing.assert_array_equal(ra.azimuth_deg, rb.azimuth_deg)
    np.testing.assert_array_equal(ra.split, rb.split)
    assert not np.array_equal(a.images, c.images)


@pytest.mark.parametrize("splat, rays", [("kernel", 0), ("bilinear", 3000)])
def test_power_on_a_large_window_is_dni_times_area_times_cos_incidence(tiny, tmp_path, splat, rays):
    """An ideal flat 1 m^2 mirror, a point-like sun and no losses: all reflected power hits a 4 m window."""
    ideal = dict(deformation_mm=0.0, tracking_error_mrad=0.0, canting_error_mrad=0.0)
    path = _heliostat_file(tmp_path, tiny, "small", **ideal)
    positions = [[0.0, 30.0], [40.0, 50.0], [-60.0, 70.0]]
    spec = _spec(tiny, window_m=4.0, sun={"kind": "list", "positions_deg": positions},
                 world_effects={"sunshape": {"kind": "pillbox", "half_angle_mrad": 4.65}},
                 trace={"splat": splat, "rays": rays, "cells_per_side": 8},
                 splits={"interpolation": {"fraction": 0.0}})
    ds = trace_dataset(spec, path, tmp_path / "energy.h5")
    pixel_area = (4.0 / 32) ** 2
    power = ds.images.astype(np.float64).sum((1, 2)) * pixel_area
    az, el = torch.tensor(np.radians(positions), dtype=torch.float64).T
    sun = sun_vector(az, el)
    position = torch.tensor(tiny["heliostats"]["small"]["position_m"], dtype=torch.float64)
    to_target = normalize(torch.tensor(tiny["target"]["center_m"], dtype=torch.float64) - position)
    cos_incidence = (sun * normalize(sun + to_target)).sum(-1).numpy()
    expected = 1000.0 * 1.0 * cos_incidence
    assert cos_incidence.min() < 0.9  # the positions really differ in incidence
    np.testing.assert_allclose(power, expected, rtol=1e-5)  # exact up to float32 storage


# --- sun positions --------------------------------------------------------------------------------


def test_scan_is_fixed_azimuth_and_equal_elevation_steps():
    scan = {"kind": "scan", "azimuth_deg": -30.0, "elevation_deg": [10.0, 80.0], "n": 8}
    az, el = sun_positions(scan, seed=0)
    np.testing.assert_array_equal(az, np.full(8, -30.0))
    np.testing.assert_allclose(el, np.linspace(10.0, 80.0, 8))
    assert el[0] == 10.0 and el[-1] == 80.0


def test_list_returns_the_given_pairs():
    positions = [[10.0, 20.0], [-45.0, 60.5], [170.0, 89.0]]
    az, el = sun_positions({"kind": "list", "positions_deg": positions}, seed=0)
    np.testing.assert_array_equal(az, [10.0, -45.0, 170.0])
    np.testing.assert_array_equal(el, [20.0, 60.5, 89.0])


HEMISPHERE = {"kind": "hemisphere", "azimuth_deg": [-120.0, 120.0], "elevation_deg": [10.0, 85.0],
              "n": 20_000}


def test_hemisphere_is_uniform_in_solid_angle_within_the_ranges():
    az, el = sun_positions(HEMISPHERE, seed=0)
    assert az.shape == el.shape == (20_000,)
    assert az.min() >= -120.0 and az.max() <= 120.0 and el.min() >= 10.0 and el.max() <= 85.0
    lo, hi = np.sin(np.radians([10.0, 85.0]))
    u = np.sort((np.sin(np.radians(el)) - lo) / (hi - lo))  # uniform on [0, 1] if uniform in sin(el)
    assert np.abs(u - (np.arange(len(u)) + 0.5) / len(u)).max() < 0.015  # Kolmogorov-Smirnov distance
    # not uniform in elevation: uniform in sin(el) puts 65 % (not 47 %) of the positions below 45 deg
    below = (np.sin(np.radians(45.0)) - lo) / (hi - lo)
    assert (el < 45.0).mean() == pytest.approx(below, abs=0.015) and below > 0.6
    v = np.sort((az + 120.0) / 240.0)
    assert np.abs(v - (np.arange(len(v)) + 0.5) / len(v)).max() < 0.015


def test_hemisphere_is_seeded():
    sun = {**HEMISPHERE, "n": 50}
    a, b = sun_positions(sun, seed=3), sun_positions(sun, seed=3)
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_array_equal(a[1], b[1])
    assert not np.array_equal(a[0], sun_positions(sun, seed=4)[0])
    # the dataset's own sun.seed takes precedence over the experiment seed
    own = sun_positions({**sun, "seed": 3}, seed=99)
    np.testing.assert_array_equal(own[0], a[0])


# --- bad inputs -------------------------------------------------------------------------------------


def _truncated(src: Path, dst: Path) -> Path:
    dst.write_bytes(src.read_bytes()[: src.stat().st_size // 2])
    return dst


def _garbage(src: Path, dst: Path) -> Path:
    dst.write_bytes(b"\x00helioflow? no" * 100)
    return dst


def _wrong_kind(src: Path, dst: Path) -> Path:
    """A valid helioflow file, but a dataset instead of a heliostat geometry."""
    with h5py.File(dst, "w") as f:
        f["images"] = np.zeros((1, 8, 8))
        f.attrs["schema"] = "helioflow.dataset/1"
    return dst


def _missing_array(src: Path, dst: Path) -> Path:
    dst.write_bytes(src.read_bytes())
    with h5py.File(dst, "a") as f:
        del f["facets/normal"]
    return dst


@pytest.mark.parametrize("make, says", [
    (_truncated, "truncated or corrupt"),
    (_garbage, "not a readable HDF5 file"),
    (_wrong_kind, "helioflow.heliostat/1"),
    (_missing_array, "facets/normal"),
    (lambda src, dst: dst, "does not exist"),
], ids=["truncated", "garbage", "wrong schema", "missing array", "missing file"])
def test_a_bad_heliostat_file_gives_a_data_error_and_no_output(tiny, heliostat, tmp_path, make, says):
    bad = make(heliostat, tmp_path / "heliostat.h5")
    out = tmp_path / "out" / "scan.h5"
    with pytest.raises(DataError) as exc:
        trace_dataset(_spec(tiny), bad, out)
    assert str(bad) in str(exc.value) and says in str(exc.value)
    assert not out.exists()
    assert not list(tmp_path.rglob("*.tmp.h5"))

