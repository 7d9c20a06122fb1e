"""PAINT import (helioflow.data.paint): real AA39 measurements, conventions, resampling without
shift, centered-only measurements placed by their UTIS centroid, one clear error per bad input with
nothing written, the CLI, and the centroid check."""

import json
import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

from helioflow.cli import main
from helioflow.data.hdf5 import read_dataset
from helioflow.data.paint import (
    CENTERED_WINDOW_M,
    UTIS_PIXELS,
    PlaneTarget,
    Tower,
    import_paint,
    measurement_pngs,
    measurement_targets,
    place_centered,
    read_centered_png,
    read_flux_png,
    read_measurement,
    resample_area,
    utis_on_target,
)
from helioflow.data.surfaces import read_heliostat
from helioflow.errors import DataError
from helioflow.physics.target import Target
from helioflow.scoring.paint_centroids import centroid_check

PAINT = Path(__file__).resolve().parent / "paint"
AA39_CENTERED = ["202558", "205363", "209075", "218385", "223788", "246955"]  # only -flux-centered.png
AA39_WHOLE = ["270398", "271633", "275564", "extra1", "extra2", "extra3"]  # with the whole target's -flux.png
AA39_IDS = AA39_CENTERED + AA39_WHOLE  # numeric ids first


@pytest.fixture(autouse=True)
def _keep_torch_threads():
    """main() sets torch's thread count; restore it for the other tests of this process."""
    threads = torch.get_num_threads()
    yield
    torch.set_num_threads(threads)


@pytest.fixture(scope="module")
def aa39(tmp_path_factory):
    """AA39 imported once: (dataset, heliostat geometry, their paths)."""
    out = tmp_path_factory.mktemp("aa39")
    import_paint(PAINT, "AA39", out / "aa39.h5", out / "AA39.h5", holdout=["extra1", "271633"])
    return read_dataset(out / "aa39.h5"), read_heliostat(out / "AA39.h5"), out


@pytest.fixture
def paint_copy(tmp_path):
    """A writable copy of tower-measurements.json and AA39 to break."""
    root = tmp_path / "paint"
    root.mkdir()
    shutil.copy(PAINT / "tower-measurements.json", root)
    shutil.copytree(PAINT / "AA39", root / "AA39")
    return root


def _target(ds, i) -> Target:
    e = ds.extras
    width, height = (float(x) for x in e["target_size_m"][i])
    return Target(torch.as_tensor(e["target_center_m"][i]), torch.as_tensor(e["target_normal"][i]),
                  width, height, tuple(ds.images.shape[1:]))


def test_aa39_imports_images_sun_angles_and_splits(aa39):
    ds, _, _ = aa39
    assert ds.images.shape == (12, 64, 64) and ds.images.dtype == np.float32
    assert 0 <= ds.images.min() and 0.5 < ds.images.max() <= 1.0
    assert list(ds.extras["measurement_id"]) == AA39_IDS
    for i, mid in enumerate(AA39_IDS):
        meta = json.loads((PAINT / "AA39" / f"{mid}-calibration-properties.json").read_text())
        assert ds.azimuth_deg[i] == pytest.approx(meta["sun_azimuth"])
        assert ds.elevation_deg[i] == pytest.approx(meta["sun_elevation"])
        assert ds.extras["target_name"][i] == meta["target_name"]
    # extra1 (az -85) lies outside the train azimuths, 271633 (60, 37) inside the train ranges
    assert list(ds.split) == ["train"] * 7 + ["interpolation", "train", "extrapolation", "train", "train"]
    assert list(ds.extras["centered"]) == [True] * 6 + [False] * 6 and ds.extras["centered"].dtype == bool
    assert ds.attrs["heliostat_mount"] == "juelich" and ds.attrs["mixed_targets"] is True
    assert ds.attrs["target_name"] == "multi_focus_tower"  # 7 of the 12 images
    assert ds.attrs["canting_focal_distance_m"] == pytest.approx(65.0, abs=0.5)


def test_aa39_enu_geometry_is_plausible(aa39):
    ds, heliostat, _ = aa39
    position = np.asarray(ds.attrs["heliostat_position_m"])
    assert np.allclose(position, heliostat.position.numpy())
    assert 20 < np.hypot(*position[:2]) < 300 and 0 < position[2] < 5  # in the field north of the tower
    assert position[1] > 0
    for i in range(len(ds.images)):
        centre, normal = ds.extras["target_center_m"][i], ds.extras["target_normal"][i]
        assert np.linalg.norm(normal) == pytest.approx(1.0)
        assert normal @ (position - centre) > 0 and normal[1] > 0.99  # faces north, towards the field
        assert 30 < centre[2] < 60  # on the tower
        width, height = ds.extras["target_size_m"][i]
        assert 5 < width < 9 and 6 < height < 8
        spot = ds.extras["focal_spot_enu_m"][i]
        assert abs((spot - centre) @ normal) < 0.15  # PAINT's centroid lies on the target plane


def test_aa39_heliostat_is_four_canted_facets_without_errors(aa39):
    _, h, _ = aa39
    assert h.mount == "juelich" and h.n_facets == 4 and h.facet_focal_length is None
    assert np.allclose(h.facet_size.numpy(), [1.605, 1.275], atol=1e-3)
    assert np.allclose(h.facet_translation[:, :2].abs().numpy(), [0.8075, 0.6425])
    # the facets 0.0402 m ahead of the aimed point, their translation vectors' normal component (as ARTIST)
    assert np.allclose(h.facet_translation[:, 2].numpy(), 0.0402)
    # each facet normal tilts towards the heliostat centre (concave, focusing)
    tilt = h.facet_normal[:, :2] / h.facet_normal[:, 2:]
    assert (torch.sign(tilt) == -torch.sign(h.facet_translation[:, :2])).all()
    for t in (h.control_heights, h.canting_error, h.tracking_error):
        assert not t.any()


def test_image_centroids_match_paints_utis_centroids(aa39):
    """Image orientation: a flipped or transposed image would put the centroid metres away."""
    ds, _, _ = aa39
    for i in range(len(ds.images)):
        target = _target(ds, i)
        measured = target.centroid(torch.as_tensor(ds.images[i : i + 1], dtype=torch.float64))[0].numpy()
        utis = target.to_plane(torch.as_tensor(ds.extras["focal_spot_enu_m"][i])).numpy()
        assert np.linalg.norm(measured - utis) < 0.05, (ds.extras["measurement_id"][i], measured, utis)


def _blob(shape=(256, 256), centre=(70.3, 181.7), sigma=(9.0, 14.0)) -> np.ndarray:
    r, c = np.mgrid[: shape[0], : shape[1]] + 0.5
    return np.exp(-0.5 * (((r - centre[0]) / sigma[0]) ** 2 + ((c - centre[1]) / sigma[1]) ** 2))


def _centroid_fraction(image: np.ndarray) -> np.ndarray:
    """Flux-weighted centroid (row, col) as a fraction of the image extent, pixel centres."""
    r = (np.arange(image.shape[0]) + 0.5) / image.shape[0]
    c = (np.arange(image.shape[1]) + 0.5) / image.shape[1]
    total = image.sum()
    return np.array([(image.sum(1) * r).sum() / total, (image.sum(0) * c).sum() / total])


@pytest.mark.parametrize("shape", [(64, 64), (48, 40), (16, 16)])
def test_resampling_keeps_an_off_centre_blobs_centroid(shape):
    blob = _blob()
    small = resample_area(blob, shape)
    shift_px = (_centroid_fraction(small) - _centroid_fraction(blob)) * np.array(shape)
    assert np.abs(shift_px).max() < 0.02, shift_px
    assert small.sum() * (256 * 256) / (shape[0] * shape[1]) == pytest.approx(blob.sum())
    # the test tells: strided subsampling (pixel 0 of each block) shifts by 0.375 output pixels
    naive = blob[:: 256 // 64, :: 256 // 64]
    assert np.abs((_centroid_fraction(naive) - _centroid_fraction(blob)) * 64).max() > 0.3


def test_resampling_keeps_uniform_images_uniform():
    assert np.allclose(resample_area(np.full((256, 256), 0.3), (48, 40)), 0.3)


def test_imported_blob_keeps_its_target_coordinates(paint_copy, tmp_path):
    """End to end: a synthetic off-centre spot in a flux.png lands at the same target point."""
    blob = _blob()
    png_path = paint_copy / "AA39" / "270398-flux.png"
    Image.fromarray((blob / blob.max() * 255).round().astype(np.uint8)).save(png_path)
    ds = import_paint(paint_copy, "AA39", tmp_path / "ds.h5", resolution=(32, 32))
    i = AA39_IDS.index("270398")
    target = _target(ds, i)
    full = Target(target.center, target.normal, target.width, target.height, (256, 256))
    png = torch.as_tensor(read_flux_png(png_path))[None]
    imported = torch.as_tensor(ds.images[i : i + 1], dtype=torch.float64)
    assert torch.allclose(target.centroid(imported), full.centroid(png), atol=0.002)  # m, < 1/60 pixel


def _edit_json(path: Path, edit) -> None:
    data = json.loads(path.read_text())
    edit(data)
    path.write_text(json.dumps(data))


BAD_INPUTS = {
    "missing field": ("AA39/270398-calibration-properties.json",
                      lambda p: _edit_json(p, lambda d: d.pop("sun_elevation")),
                      "missing field 'sun_elevation'"),
    "missing nested field": ("AA39/271633-calibration-properties.json",
                             lambda p: _edit_json(p, lambda d: d["focal_spot"].pop("UTIS")),
                             "missing field 'focal_spot.UTIS'"),
    "missing facet field": ("AA39/heliostat-properties.json",
                            lambda p: _edit_json(p, lambda d: d["facet_properties"]["facets"][2].pop(
                                "canting_n")),
                            "missing field 'facet_properties.facets[2].canting_n'"),
    "wrong type": ("AA39/heliostat-properties.json",
                   lambda p: _edit_json(p, lambda d: d.update(heliostat_position=[50.9, "x", 88.0])),
                   "field 'heliostat_position'"),
    "not JSON": ("AA39/extra2-calibration-properties.json", lambda p: p.write_text("{ not json"),
                 "not a readable JSON file"),
    "sun below horizon": ("AA39/extra3-calibration-properties.json",
                          lambda p: _edit_json(p, lambda d: d.update(sun_elevation=-2.5)),
                          "below the horizon"),
    "unknown target": ("AA39/275564-calibration-properties.json",
                       lambda p: _edit_json(p, lambda d: d.update(target_name="nowhere")),
                       "target_name 'nowhere' is not a planar target"),
    "corrupt PNG": ("AA39/271633-flux.png", lambda p: p.write_bytes(p.read_bytes()[:300]),
                    "not a readable PNG image"),
    "neither PNG": ("AA39/extra1-flux.png",
                    lambda p: [p.unlink(), p.with_name("extra1-flux-centered.png").unlink()],
                    ("does not exist, nor does extra1-flux-centered.png: each <id>-calibration-properties.json "
                     "needs its <id>-flux.png (the whole target) or its <id>-flux-centered.png")),
    "centered PNG of a wrong size": ("AA39/205363-flux-centered.png",
                                     lambda p: Image.open(p).resize((40, 48)).save(p),
                                     "is 48 x 40 pixels; expected a centered PAINT image of 64 x 64 or 256 x 256"),
    "centered-only without its UTIS centroid": ("AA39/209075-calibration-properties.json",
                                                lambda p: _edit_json(p, lambda d: d["focal_spot"].pop("UTIS")),
                                                ("missing field 'focal_spot.UTIS': 209075-flux-centered.png, the "
                                                 "only image of this measurement, is placed on the target by it")),
    "target missing a corner": ("tower-measurements.json",
                                lambda p: _edit_json(p, lambda d: d["multi_focus_tower"]["coordinates"].pop(
                                    "upper_left")),
                                "missing field 'multi_focus_tower.coordinates.upper_left'"),
    "tower file missing its origin": ("tower-measurements.json",
                                      lambda p: _edit_json(p, lambda d: d.pop("power_plant_properties")),
                                      "missing field 'power_plant_properties'"),
}


@pytest.mark.parametrize("case", BAD_INPUTS)
def test_bad_input_gives_one_clear_error_and_writes_nothing(paint_copy, tmp_path, case):
    name, corrupt, message = BAD_INPUTS[case]
    corrupt(paint_copy / name)
    out = tmp_path / "out"
    with pytest.raises(DataError) as err:
        import_paint(paint_copy, "AA39", out / "datasets" / "aa39.h5", out / "surfaces" / "AA39.h5")
    assert str(paint_copy / name) in str(err.value) and message in str(err.value), str(err.value)
    assert "\n" not in str(err.value)
    assert not out.exists() or not any(p.is_file() for p in out.rglob("*"))


def test_a_failed_second_write_removes_the_first(paint_copy, tmp_path, monkeypatch):
    def fail(*args, **kwargs):
        raise DataError("disk full")

    monkeypatch.setattr("helioflow.data.paint.write_heliostat", fail)
    with pytest.raises(DataError, match="disk full"):
        import_paint(paint_copy, "AA39", tmp_path / "aa39.h5", tmp_path / "AA39.h5")
    assert not list(tmp_path.glob("*.h5"))


def test_aa23_without_geometry_and_aa28_without_measurements_say_what_is_missing(tmp_path):
    missing = (r"AA23/heliostat-properties.json does not exist: the heliostat's position and facets are "
               r"missing")
    with pytest.raises(DataError, match=missing + r" \(2 measurements found"):
        import_paint(PAINT, "AA23", tmp_path / "aa23.h5")
    with pytest.raises(DataError, match=r"AA28 has no measurements .*heliostat-properties.json is there"):
        import_paint(PAINT, "AA28", tmp_path / "aa28.h5")
    assert not list(tmp_path.iterdir())
    import_paint(PAINT, "AA28", heliostat_path=tmp_path / "AA28.h5")  # the geometry alone imports
    assert read_heliostat(tmp_path / "AA28.h5").n_facets == 4


def test_every_sample_folder_imports_or_fails_with_one_clear_message(tmp_path):
    outcomes = {}
    for folder in sorted(p for p in PAINT.iterdir() if p.is_dir()):
        try:
            ds = import_paint(PAINT, folder.name, tmp_path / f"{folder.name}.h5",
                              tmp_path / f"{folder.name}_geometry.h5")
            outcomes[folder.name] = len(ds.images)
        except DataError as exc:
            assert str(folder) in str(exc) and "\n" not in str(exc)
            outcomes[folder.name] = "error"
    assert outcomes == {"AA23": "error", "AA28": "error", "AA31": 7, "AA39": 12, "AC43": 2, "AD37": 6, "AU46": 6}


def test_unknown_heliostat_holdout_and_target_are_named(tmp_path):
    folders = "AA23, AA28, AA31, AA39, AC43, AD37, AU46"
    with pytest.raises(DataError, match=f"AB99 does not exist; heliostat folders there: {folders}"):
        import_paint(PAINT, "AB99", tmp_path / "x.h5")
    with pytest.raises(DataError, match=r"holdout ids \['123'\] are not measurements in .*AA31"):
        import_paint(PAINT, "AA31", tmp_path / "x.h5", holdout=["123"])
    with pytest.raises(DataError, match="holdout holds every measurement"):
        import_paint(PAINT, "AA31", tmp_path / "x.h5", holdout=list(measurement_targets(PAINT, "AA31")))
    with pytest.raises(DataError, match=r"targets \['roof'\] are not planar targets"):
        import_paint(PAINT, "AA31", tmp_path / "x.h5", targets=["roof"])
    assert not list(tmp_path.iterdir())


def test_a_target_filter_gives_a_single_target_dataset(tmp_path):
    ds = import_paint(PAINT, "AA39", tmp_path / "x.h5", targets=["multi_focus_tower"], resolution=(16, 16))
    assert list(ds.extras["measurement_id"]) == ["202558", "205363", "218385", "270398", "275564", "extra1", "extra3"]
    assert ds.attrs["mixed_targets"] is False and ds.images.shape == (7, 16, 16)
    assert np.allclose(ds.extras["target_center_m"], ds.attrs["target_center_m"])


def test_cli_imports_by_hand_and_reports_errors_in_one_line(tmp_path, capsys):
    out = tmp_path / "aa31.h5"
    assert main(["import-paint", "--paint-dir", str(PAINT), "--heliostat", "AA31", "--resolution", "32", "32",
                 "--holdout", "126372", "--output", str(out)]) == 0
    assert read_dataset(out).images.shape == (7, 32, 32)
    capsys.readouterr()
    bad = tmp_path / "aa23.h5"
    assert main(["import-paint", "--paint-dir", str(PAINT), "--heliostat", "AA23", "--output", str(bad)]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("helioflow import-paint: error: ")
    assert "AA23/heliostat-properties.json does not exist" in lines[0]
    assert not bad.exists()
    assert main(["import-paint", "--paint-dir", str(PAINT), "--heliostat", "AA31"]) == 2
    assert "give --output" in capsys.readouterr().err


def test_ideal_spot_lands_on_the_aim_point_and_is_oriented_like_the_measured_one(aa39):
    """The centroid check's numbers (docs/data.md): measured - ideal offsets are the real heliostat's
    pointing error; the matching spot orientation rules out flips and a wrong mount."""
    _, _, out = aa39
    rows = centroid_check(out / "aa39.h5", out / "AA39.h5")
    assert [r["id"] for r in rows] == AA39_IDS
    for r in rows:
        # the aim point is the target centre (9.5 mm right of it on the Juelich targets) and the ideal spot misses
        # it by the facets' stand-off, 0.3-2.4 cm (module docstring): 2.3 cm at 223788 (az -68, el 46)
        assert np.hypot(*r["ideal_uv_m"]) < 0.03
        assert abs(r["image_mrad"] - r["utis_mrad"]) < 0.5  # our centroid and PAINT's agree
        assert 1.0 < r["image_mrad"] < 25.0
        angle = r["spot_angle_deg"]
        assert abs(angle["ideal"] - angle["measured"]) < 5.0


def test_a_holdout_fraction_holds_out_a_seeded_share_of_the_measurements(tmp_path):
    """holdout: {fraction, seed}: round(fraction * N) measurements, the same ones for the same seed,
    others for another; at least one stays for training."""
    from helioflow.data.paint import held_out

    ids = [f"m{i}" for i in range(40)]
    quarter = held_out(ids, {"fraction": 0.25, "seed": 3})
    assert len(quarter) == 10 and set(quarter) <= set(ids)
    assert held_out(ids, {"fraction": 0.25, "seed": 3}) == quarter != held_out(ids, {"fraction": 0.25, "seed": 4})
    assert len(held_out(ids[:2], {"fraction": 0.9})) == 1
    ds = import_paint(PAINT, "AA39", tmp_path / "x.h5", holdout={"fraction": 0.5, "seed": 0})
    assert (ds.split != "train").sum() == 6


# Centered-only measurements (module docstring: Centered measurements). AA23's focal spots are the 2025
# release's: brought into the 2026 frame (ENU m) by the constants of the data's README.
AA23_TO_2026 = {"multi_focus_tower": np.array([-0.014, 0.092, 0.0]),
                "solar_tower_juelich_upper": np.array([-0.017, 0.0, 0.0]),
                "solar_tower_juelich_lower": np.array([-0.017, 0.0, 0.0])}
BOTH_FILES = sorted(str(p.relative_to(PAINT)) for p in PAINT.glob("*/*-calibration-properties.json")
                    if all(f.is_file() for f in measurement_pngs(p)))


def _centroid_mm(image: np.ndarray, plane) -> np.ndarray:
    """(2,) flux-weighted centroid (u right, v up) of a (H, W) image of the whole target, mm."""
    target = Target(torch.as_tensor(plane.center), torch.as_tensor(plane.normal), plane.width, plane.height,
                    image.shape)
    return 1e3 * target.centroid(torch.as_tensor(image)[None])[0].numpy()


@pytest.mark.parametrize("name", BOTH_FILES)
def test_a_centered_image_placed_by_its_utis_centroid_matches_the_whole_image(name):
    """On the measurements with both images (the 2026 release's 256 px centered images; AA23's 64 px): placed
    at 64 x 64, centroid within 10 mm of the whole image's (measured at most 7.6 mm) and at most 1 % of the
    flux misplaced (measured 0.16-0.65 %); without the half UTIS pixel the spots land 17-30 mm off."""
    path = PAINT / name
    tower = Tower(PAINT / "tower-measurements.json")
    m = read_measurement(path, tower)
    if path.parent.name == "AA23":
        m = replace(m, focal_spot_utis_m=m.focal_spot_utis_m + AA23_TO_2026[m.target_name])
    plane = tower.target(m.target_name, path)
    whole_png, centered_png = measurement_pngs(path)
    ref = resample_area(read_flux_png(whole_png), (64, 64))
    centered = read_centered_png(centered_png)
    placed = place_centered(centered, utis_on_target(m, plane), plane, (64, 64))
    offset = _centroid_mm(placed, plane) - _centroid_mm(ref, plane)
    misplaced = 0.5 * np.abs(placed / placed.sum() - ref / ref.sum()).sum()
    assert np.hypot(*offset) < 10.0 and misplaced < 0.01, (offset, misplaced)
    half = np.array([plane.width, -plane.height]) / (2 * UTIS_PIXELS)
    raw = place_centered(centered, utis_on_target(m, plane) - half, plane, (64, 64))
    assert np.hypot(*(_centroid_mm(raw, plane) - _centroid_mm(ref, plane))) > 15.0  # the test tells


def test_placing_keeps_the_flux_puts_the_centroid_and_loses_what_leaves_the_target():
    plane = PlaneTarget("t", np.array([0.0, 0.0, 50.0]), np.array([0.0, 1.0, 0.0]), 8.0, 7.0)
    blob = _blob((64, 64), centre=(30.2, 33.9), sigma=(5.0, 7.0))
    side = CENTERED_WINDOW_M[64]
    flux = blob.sum() * (side / 64) ** 2  # relative flux x m^2
    placed = place_centered(blob, np.array([0.834, -0.267]), plane, (48, 40))  # the window inside the target
    assert placed.sum() * plane.width * plane.height / (48 * 40) == pytest.approx(flux)
    assert np.allclose(_centroid_mm(placed, plane), [834.0, -267.0], atol=1.0)  # 1 mm of 200 mm pixels
    edge = place_centered(blob, np.array([plane.width / 2, 0.0]), plane, (48, 40))  # centroid on the right edge
    kept = edge.sum() * plane.width * plane.height / (48 * 40) / flux
    assert kept == pytest.approx(0.5, abs=0.02)  # the half beyond the edge is lost


def test_centered_skip_gives_the_dataset_of_the_whole_images_alone(tmp_path):
    """centered: skip leaves out the centered-only measurements, unread: the same dataset as a folder without them."""
    root = tmp_path / "paint"
    (root / "AA39").mkdir(parents=True)
    shutil.copy(PAINT / "tower-measurements.json", root)
    for f in (PAINT / "AA39").iterdir():
        if not any(f.name.startswith(i) for i in AA39_CENTERED):
            shutil.copy(f, root / "AA39")
    held = ["extra1"]
    skip = import_paint(PAINT, "AA39", tmp_path / "skip.h5", holdout=held, centered="skip")
    alone = import_paint(root, "AA39", tmp_path / "alone.h5", holdout=held)
    assert list(skip.extras["measurement_id"]) == AA39_WHOLE and not skip.extras["centered"].any()
    assert np.array_equal(skip.images, alone.images) and list(skip.split) == list(alone.split)
    assert np.array_equal(skip.azimuth_deg, alone.azimuth_deg) and skip.extras.keys() == alone.extras.keys()
    assert all(np.array_equal(skip.extras[k], alone.extras[k]) for k in skip.extras)
    broken = tmp_path / "broken"
    shutil.copytree(PAINT / "AA39", broken / "AA39")
    shutil.copy(PAINT / "tower-measurements.json", broken)
    (broken / "AA39" / "205363-calibration-properties.json").write_text("{ not json")
    assert len(import_paint(broken, "AA39", tmp_path / "b.h5", centered="skip").images) == 6  # not read
    with pytest.raises(DataError, match=r"AD37: every measurement has only its <id>-flux-centered.png"):
        import_paint(PAINT, "AD37", tmp_path / "ad37.h5", centered="skip")
    assert list(measurement_targets(PAINT, "AA39", centered="skip")) == AA39_WHOLE


def test_centered_only_heliostats_import_with_their_spots_at_the_utis_centroids(tmp_path):
    tower = Tower(PAINT / "tower-measurements.json")
    for heliostat in ("AD37", "AU46"):
        ds = import_paint(PAINT, heliostat, tmp_path / f"{heliostat}.h5")
        assert ds.images.shape == (6, 64, 64) and ds.extras["centered"].all()
        assert ds.attrs["source_image_shape"] == [UTIS_PIXELS, UTIS_PIXELS]
        for i, mid in enumerate(ds.extras["measurement_id"]):
            path = PAINT / heliostat / f"{mid}-calibration-properties.json"
            m = read_measurement(path, tower)
            plane = tower.target(m.target_name, path)
            centroid = _centroid_mm(ds.images[i].astype(np.float64), plane)
            assert np.allclose(centroid, 1e3 * utis_on_target(m, plane), atol=3.0)  # float32, 64 px: < 0.1 px
