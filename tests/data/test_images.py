"""Own calibration images (source: images, helioflow.data.images): the round trip from PNGs and a CSV
to a dataset, the sun from timestamps, one clear error per bad input with nothing written, the
config, the rule helpers and the CLI."""

import copy
import csv
import json
import logging
import re
from datetime import UTC, datetime, timedelta
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml
from PIL import Image
from support.pipeline import layered

from helioflow.cli import main
from helioflow.config import validate_config
from helioflow.data.hdf5 import read_dataset
from helioflow.data.images import image_ids, import_images, parse_timestamp, sun_position
from helioflow.data.paint import Tower, import_paint, resample_area
from helioflow.data.surfaces import read_heliostat
from helioflow.errors import ConfigError, DataError
from helioflow.workflow import (
    dataset_heliostat,
    existing_upstream_files,
    expand_config,
    images_datasets,
    images_heliostat_params,
    images_heliostats,
    import_images_inputs,
    import_images_params,
    recovery_paths,
    traced_datasets,
)

REPO = Path(__file__).resolve().parents[2]
PAINT = REPO / "tests" / "data" / "paint"
SITE = {"latitude_deg": 50.9134, "longitude_deg": 6.3868, "altitude_m": 87.0}
TARGET = {"center_m": [0.0, 0.0, 10.0], "normal": [0.0, 1.0, 0.0], "width_m": 3.0, "height_m": 2.0}
HELIOSTAT = {"position_m": [0.0, 30.0, 0.0], "mount": "az_el", "facets": {"rows": 1, "cols": 1, "width_m": 1.0,
                                                                          "height_m": 1.0}}
SUN = [(-60.0, 20.0), (-20.0, 35.0), (0.0, 50.0), (10.0, 30.0), (30.0, 45.0), (70.0, 25.0)]
SHAPE = (40, 60)  # rows, columns of the PNGs: 3 m x 2 m at square pixels


@pytest.fixture(autouse=True)
def _keep_torch_threads():
    """main() sets torch's thread count; restore it for the other tests of this process."""
    threads = torch.get_num_threads()
    yield
    torch.set_num_threads(threads)


def _blob(i: int, shape=SHAPE) -> np.ndarray:
    """A known off-centre spot in [0, 1], its peak below 1 (a camera's exposure)."""
    r, c = np.mgrid[: shape[0], : shape[1]]
    return (0.3 + 0.1 * i) * np.exp(-((r - 12 - 2 * i) ** 2 / 40 + (c - 20 - 3 * i) ** 2 / 90)) + 0.01


def _write_csv(path: Path, columns: list[str], rows: list[list]) -> None:
    with path.open("w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(columns)
        writer.writerows(rows)


@pytest.fixture
def folder(tmp_path):
    """Six 16-bit PNGs of known spots and a CSV of their sun angles: (images dir, csv, the arrays)."""
    images = tmp_path / "images"
    images.mkdir()
    arrays = []
    for i in range(len(SUN)):
        grey = np.round(_blob(i) * 65535).astype(np.uint16)
        Image.fromarray(grey).save(images / f"spot_{i}.png")
        arrays.append(grey / 65535.0)
    _write_csv(tmp_path / "sun.csv", ["file", "azimuth_deg", "elevation_deg"],
               [[f"spot_{i}.png", az, el] for i, (az, el) in enumerate(SUN)])
    return images, tmp_path / "sun.csv", arrays


def _spec(images, csv_path, **changes) -> dict:
    spec = {"dataset": "own", "heliostat": "own", "images_dir": str(images), "csv": str(csv_path),
            "resolution": [16, 24], "target": copy.deepcopy(TARGET), "site": None,
            "heliostat_geometry": copy.deepcopy(HELIOSTAT), "splits": None, "holdout": [], "seed": 0,
            "dni_w_m2": 1000.0}
    spec.update(changes)
    return spec


# --- round trip --------------------------------------------------------------------------------------


def test_images_and_csv_round_trip_to_a_dataset_and_an_ideal_heliostat(folder, tmp_path):
    images, csv_path, arrays = folder
    out = tmp_path / "out"
    import_images(_spec(images, csv_path, holdout=["spot_5", "spot_3"]), out / "own.h5", out / "own_h.h5")
    ds = read_dataset(out / "own.h5")
    expected = np.stack([resample_area(a, (16, 24)) for a in arrays])
    expected /= expected.max(axis=(1, 2), keepdims=True)  # each image divided by its own peak
    assert ds.images.shape == (6, 16, 24) and ds.images.dtype == np.float32
    assert np.allclose(ds.images, expected, atol=1e-6)
    assert np.allclose(ds.azimuth_deg, [a for a, _ in SUN]) and np.allclose(ds.elevation_deg, [e for _, e in SUN])
    # spot_3 (10, 30) lies inside the train azimuths and elevations, spot_5 (70, 25) outside
    assert list(ds.split) == ["train", "train", "train", "interpolation", "train", "extrapolation"]
    assert list(ds.extras["measurement_id"]) == [f"spot_{i}" for i in range(6)]
    assert np.allclose(ds.extras["raw_peak"], [a.max() for a in arrays])
    a = ds.attrs
    assert a["per_image_normalised"] is True and a["source_image_shape"] == list(SHAPE)
    assert a["target_center_m"] == TARGET["center_m"] and a["target_size_m"] == [3.0, 2.0]
    assert a["target_normal"] == [0.0, 1.0, 0.0] and a["heliostat_position_m"] == [0.0, 30.0, 0.0]
    assert a["heliostat_mount"] == "az_el" and a["heliostat"] == "own" and a["dni_w_m2"] == 1000.0
    heliostat = read_heliostat(out / "own_h.h5")
    assert heliostat.position.tolist() == [0.0, 30.0, 0.0] and heliostat.n_facets == 1
    assert heliostat.control_heights.abs().max() == 0 and heliostat.tracking_error.abs().max() == 0


def test_split_rules_label_as_for_a_traced_dataset(folder, tmp_path):
    images, csv_path, _ = folder
    splits = {"extrapolation": {"elevation_above_deg": 47.0}, "interpolation": {"fraction": 0.25}}
    ds = import_images(_spec(images, csv_path, splits=splits), tmp_path / "own.h5")
    assert ds.split[2] == "extrapolation" and list(ds.split).count("interpolation") == 1
    assert list(ds.split).count("train") == 4
    every = import_images(_spec(images, csv_path), tmp_path / "all.h5")  # neither: every image trains
    assert set(every.split) == {"train"}


def test_8_bit_and_colour_pngs_are_read_as_grey_and_ids_come_from_the_csv(tmp_path):
    images = tmp_path / "images"
    images.mkdir()
    grey = np.round(_blob(0) * 255).astype(np.uint8)
    Image.fromarray(grey).save(images / "grey.png")
    Image.fromarray(np.stack([grey] * 3, axis=-1)).save(images / "colour.png")
    _write_csv(tmp_path / "sun.csv", ["id", "file", "azimuth_deg", "elevation_deg"],
               [["a", "grey.png", 0, 40], ["b", "colour.png", 10, 40]])
    ds = import_images(_spec(images, tmp_path / "sun.csv"), tmp_path / "own.h5")
    assert np.allclose(ds.images[0], ds.images[1], atol=1e-6)
    assert list(ds.extras["measurement_id"]) == ["a", "b"] and image_ids(tmp_path / "sun.csv") == ["a", "b"]


# --- the sun from timestamps -----------------------------------------------------------------------------


def test_solar_noon_is_south_at_ninety_minus_latitude_minus_declination():
    declination = 23.44  # 2023-06-21
    start = datetime(2023, 6, 21, 10, 30, tzinfo=UTC)
    for site, south in ((SITE, True), ({"latitude_deg": -33.9, "longitude_deg": 18.4, "altitude_m": 0.0}, False)):
        times = [start - timedelta(hours=site["longitude_deg"] / 15 - 0.5) + timedelta(minutes=m)
                 for m in range(0, 120, 2)]
        az, el = sun_position(times, site)
        noon = int(np.argmax(el))
        assert 0 < noon < len(times) - 1  # the highest sun is inside the scan: solar noon
        assert el[noon] == pytest.approx(90 - abs(site["latitude_deg"] - declination), abs=0.5)
        # north of the tropic the noon sun is south (azimuth 0), south of it north (+-180)
        assert abs(az[noon]) < 1.5 if south else abs(az[noon]) > 178.5
    morning, afternoon = sun_position([parse_timestamp("2023-06-21T08:00:00+02:00", "t"),
                                       parse_timestamp("2023-06-21T18:00:00+02:00", "t")], SITE)[0]
    assert 60 < morning < 120 and -120 < afternoon < -60  # +90 = east, -90 = west


def test_times_beyond_astropys_bundled_tables_give_the_sun_with_a_warning(caplog):
    with caplog.at_level(logging.WARNING, logger="helioflow.data.images"):
        az, el = sun_position([parse_timestamp("2031-06-21T13:30:00+02:00", "t")], SITE)
    assert abs(az[0]) < 5 and el[0] == pytest.approx(62.5, abs=0.5)  # no error, offline
    assert "outside astropy's bundled IERS tables" in caplog.text


def test_timestamps_and_angles_give_the_same_sun(folder, tmp_path):
    images, _, _ = folder
    stamps = ["2023-06-01T08:30:00+02:00", "2023-06-01T10:00:00+02:00", "2023-06-01T11:30:00Z",
              "2023-06-01T13:30:00+02:00", "2023-06-01T15:00:00+02:00", "2023-06-01T17:30:00+02:00"]
    _write_csv(tmp_path / "time.csv", ["file", "timestamp"], [[f"spot_{i}.png", t] for i, t in enumerate(stamps)])
    by_time = import_images(_spec(images, tmp_path / "time.csv", site=SITE), tmp_path / "time.h5")
    az, el = sun_position([parse_timestamp(t, "t") for t in stamps], SITE)
    _write_csv(tmp_path / "angles.csv", ["file", "azimuth_deg", "elevation_deg"],
               [[f"spot_{i}.png", a, e] for i, (a, e) in enumerate(zip(az, el))])
    by_angle = import_images(_spec(images, tmp_path / "angles.csv"), tmp_path / "angles.h5")
    assert np.allclose(by_time.azimuth_deg, by_angle.azimuth_deg, atol=1e-9)
    assert np.allclose(by_time.elevation_deg, by_angle.elevation_deg, atol=1e-9)
    assert np.allclose(by_time.images, by_angle.images)
    assert list(read_dataset(tmp_path / "time.h5").extras["timestamp"]) == stamps
    assert "timestamp" in by_time.attrs["sun_from"] and by_time.attrs["site"] == SITE


# --- one clear error per bad input, nothing written ----------------------------------------------------------


def _rewrite(csv_path: Path, edit) -> None:
    rows = list(csv.reader(csv_path.open()))
    edit(rows)
    with csv_path.open("w", newline="") as f:
        csv.writer(f).writerows(rows)


BAD = {
    "missing image": (lambda d, c: (d / "spot_3.png").unlink(),
                      r"sun\.csv line 5 \(image spot_3\): file 'spot_3\.png': .*images/spot_3\.png does not exist"),
    "image of another size": (lambda d, c: Image.fromarray(np.uint16(_blob(0, (30, 20)) * 65535)).save(
                                  d / "spot_4.png"),
                              (r"sun\.csv line 6 \(image spot_4\): .*spot_4\.png is 20 x 30 pixels \(width x height\), "
                              r"the images before it 60 x 40")),
    "corrupt image": (lambda d, c: (d / "spot_1.png").write_bytes((d / "spot_1.png").read_bytes()[:200]),
                      r"sun\.csv line 3 \(image spot_1\): .*spot_1\.png is not a readable PNG image"),
    "not a PNG": (lambda d, c: Image.fromarray(np.uint8(_blob(0) * 255)).save(d / "spot_1.png", format="JPEG"),
                  r"spot_1\.png is a JPEG image; expected PNG"),
    "black image": (lambda d, c: Image.fromarray(np.zeros(SHAPE, np.uint16)).save(d / "spot_2.png"),
                    r"line 4 \(image spot_2\): .*spot_2\.png: the image is black \(all zero\): it shows no focal spot"),
    "no file column": (lambda d, c: _rewrite(c, lambda r: r[0].__setitem__(0, "image")),
                       r"sun\.csv: no column 'file' \(columns found: 'image', 'azimuth_deg', 'elevation_deg'\)"),
    "no sun columns": (lambda d, c: _rewrite(c, lambda r: [row.__delitem__(slice(1, 3)) for row in r]),
                       r"sun\.csv: no sun position: expected the columns azimuth_deg and elevation_deg, or timestamp"),
    "azimuth without elevation": (lambda d, c: _rewrite(c, lambda r: [row.pop() for row in r]),
                                  r"sun\.csv: column 'azimuth_deg' without 'elevation_deg'"),
    "sun below the horizon": (lambda d, c: _rewrite(c, lambda r: r[3].__setitem__(2, "-2.5")),
                              r"sun\.csv line 4 \(image spot_2\): sun elevation -2\.50 deg: "
                              r"the sun is below the horizon"),
    "not a number": (lambda d, c: _rewrite(c, lambda r: r[2].__setitem__(1, "east")),
                     r"sun\.csv line 3: azimuth_deg = 'east': expected a finite number"),
    "repeated file": (lambda d, c: _rewrite(c, lambda r: r[6].__setitem__(0, "spot_0.png")),
                      r"sun\.csv line 7: id 'spot_0' is also the id of line 2"),
    "empty CSV": (lambda d, c: c.write_text("file,azimuth_deg,elevation_deg\n"),
                  r"sun\.csv has a header row but no images"),
}


@pytest.mark.parametrize("case", BAD)
def test_bad_input_gives_one_clear_error_and_writes_nothing(folder, tmp_path, case):
    images, csv_path, _ = folder
    corrupt, message = BAD[case]
    corrupt(images, csv_path)
    out = tmp_path / "out"
    with pytest.raises(DataError) as err:
        import_images(_spec(images, csv_path), out / "own.h5", out / "own_h.h5")
    assert re.search(message, str(err.value)), str(err.value)
    assert "\n" not in str(err.value)
    assert not out.exists() or not any(p.is_file() for p in out.rglob("*"))


@pytest.mark.parametrize("stamp, message", [
    ("2023-06-01T10:30:00", (r"time\.csv line 3: timestamp = '2023-06-01T10:30:00' has no timezone; expected an "
                            r"offset or Z, e\.g\. 2023-06-01T10:30:00\+02:00")),
    ("1 June 2023", r"time\.csv line 3: timestamp = '1 June 2023' is not an ISO 8601 time"),
    ("2023-06-01T23:30:00+02:00", (r"time\.csv line 3 \(image spot_1\): sun elevation -1[0-9]\.[0-9]{2} deg at "
                                  r"2023-06-01T23:30:00\+02:00: the sun is below the horizon")),
])
def test_bad_timestamps_name_the_line_and_the_value(folder, tmp_path, stamp, message):
    images, _, _ = folder
    _write_csv(tmp_path / "time.csv", ["file", "timestamp"],
               [["spot_0.png", "2023-06-01T10:30:00+02:00"], ["spot_1.png", stamp]])
    with pytest.raises(DataError, match=message):
        import_images(_spec(images, tmp_path / "time.csv", site=SITE), tmp_path / "own.h5")
    with pytest.raises(DataError, match=r"time\.csv: the sun is given by timestamp, which needs the site"):
        import_images(_spec(images, tmp_path / "time.csv"), tmp_path / "own.h5")
    assert not (tmp_path / "own.h5").exists()


def test_unknown_holdout_and_a_heliostat_behind_the_target_are_named(folder, tmp_path):
    images, csv_path, _ = folder
    with pytest.raises(DataError, match=r"holdout ids \['spot_9'\] are not measurements in .*sun\.csv"):
        import_images(_spec(images, csv_path, holdout=["spot_9"]), tmp_path / "own.h5")
    behind = {**HELIOSTAT, "position_m": [0.0, -30.0, 0.0]}
    with pytest.raises(DataError, match=r"the heliostat at \[0\.0, -30\.0, 0\.0\] m is not in front of the target"):
        import_images(_spec(images, csv_path, heliostat_geometry=behind), tmp_path / "own.h5")
    assert not (tmp_path / "own.h5").exists()


# --- a PAINT-style heliostat-properties.json -----------------------------------------------------------------


def test_heliostat_properties_around_a_wgs84_origin_give_the_paint_geometry(tmp_path):
    origin = Tower(PAINT / "tower-measurements.json").origin
    spec = {"heliostat": "aa39", "heliostat_properties": str(PAINT / "AA39" / "heliostat-properties.json"),
            "origin_wgs84": list(origin)}
    import_images(spec, heliostat_path=tmp_path / "aa39.h5")
    import_paint(PAINT, "AA39", heliostat_path=tmp_path / "AA39.h5")
    ours, paints = read_heliostat(tmp_path / "aa39.h5"), read_heliostat(tmp_path / "AA39.h5")
    assert torch.allclose(ours.position, paints.position) and torch.allclose(ours.facet_normal, paints.facet_normal)
    assert ours.mount == "juelich"


# --- config, rule helpers, CLI ----------------------------------------------------------------------------------


def _config(folder, **entry) -> dict:
    images, csv_path, _ = folder
    config = yaml.safe_load((REPO / "tests" / "workflow" / "tiny_config.yaml").read_text())
    config["datasets"]["own"] = {"source": "images", "images_dir": str(images), "csv": str(csv_path),
                                 "target": copy.deepcopy(TARGET), "heliostat": copy.deepcopy(HELIOSTAT),
                                 "holdout": ["spot_5"], **entry}
    return config


def test_an_images_dataset_validates_and_gets_its_own_rules(folder):
    images, csv_path, _ = folder
    config = expand_config(validate_config(_config(folder)))
    assert images_datasets(config) == ["own"] and traced_datasets(config) == ["scan", "sky"]
    assert dataset_heliostat(config, "own") == "own" and images_heliostats(config) == ["own"]
    params = import_images_params(config, "own")
    assert params["resolution"] == [16, 16] and params["heliostat"] == "own" and params["holdout"] == ["spot_5"]
    assert params["heliostat_geometry"]["position_m"] == HELIOSTAT["position_m"]
    assert images_heliostat_params(config, "own") == {"heliostat": "own", "heliostat_geometry": HELIOSTAT}
    inputs = import_images_inputs(config, "own")
    assert inputs["csv"] == str(csv_path) and inputs["images"] == [str(images / f"spot_{i}.png") for i in range(6)]
    assert recovery_paths(config) == []  # no true heliostat to recover


def test_leave_one_out_of_own_images_makes_a_fold_per_image_sharing_one_heliostat(folder):
    config = expand_config(validate_config(_config(folder, holdout="leave_one_out")))
    folds = [f"own_loo_spot_{i}" for i in range(6)]
    assert images_datasets(config) == ["own", *folds] and images_heliostats(config) == ["own"]  # the whole one too
    assert import_images_params(config, folds[2])["holdout"] == ["spot_2"]
    assert import_images_params(config, "own")["holdout"] == []  # every image trains: the calibration


@pytest.mark.parametrize("edit, message", [
    (lambda d: d.update(heliostat_properties="x.json"), "both heliostat and heliostat_properties"),
    (lambda d: d.pop("heliostat"), "neither heliostat nor heliostat_properties"),
    (lambda d: d["heliostat"].update(deformation_mm=0.5), ("datasets.own.heliostat.deformation_mm = 0.5: an imported "
                                                          "dataset's heliostat is the ideal one")),
    (lambda d: d.update(sun={"kind": "scan"}), "key 'sun' is not for own images"),
    (lambda d: d.update(splits={"interpolation": {"fraction": 0.2}}), ("give splits (rules on the sun positions) or "
                                                                      "holdout (image ids), not both")),
    (lambda d: d.pop("target"), "datasets.own: missing key 'target'"),
    (lambda d: d["target"].update(normal=[0.0, -1.0, 0.0]), ("datasets.own: the heliostat at position_m "
                                                           "[0.0, 30.0, 0.0] is 30 m behind the target")),
    (lambda d: d.update(images_dir="no/such/folder"), "datasets.own.images_dir = 'no/such/folder': no such folder"),
    (lambda d: d.update(csv="no/such.csv"), "datasets.own.csv: no/such.csv does not exist"),
    (lambda d: d["heliostat"].update(position_m=[0.0, 30.0]), "datasets.own.heliostat.position_m = [0.0, 30.0]"),
])
def test_bad_images_config_names_the_key(folder, edit, message):
    config = _config(folder)
    edit(config["datasets"]["own"])
    with pytest.raises(ConfigError, match=re.escape(message)):
        validate_config(config)


def test_config_refuses_a_name_clash_timestamps_without_a_site_and_images_keys_elsewhere(folder, tmp_path):
    config = _config(folder)
    config["datasets"]["small"] = config["datasets"].pop("own")
    with pytest.raises(ConfigError, match=r"written to surfaces/small\.h5, as is the configured heliostat 'small'"):
        validate_config(config)
    _write_csv(tmp_path / "time.csv", ["file", "timestamp"], [["spot_0.png", "2023-06-01T10:30:00+02:00"]])
    with pytest.raises(ConfigError, match=r"gives the sun by timestamp; add site"):
        validate_config(_config(folder, csv=str(tmp_path / "time.csv")))
    config = _config(folder)
    config["datasets"]["scan"]["csv"] = "x.csv"
    with pytest.raises(ConfigError, match=r"datasets\.scan: key 'csv' is for own images; add source: images"):
        validate_config(config)


def test_upstream_check_sees_the_images_heliostat(folder, tmp_path, monkeypatch):
    config = expand_config(validate_config(_config(folder)))
    monkeypatch.chdir(tmp_path)
    (tmp_path / "results" / "tiny" / "surfaces").mkdir(parents=True)
    (tmp_path / "results" / "tiny" / "surfaces" / "own.h5").write_bytes(b"")
    assert Path("results/tiny/surfaces/own.h5") in existing_upstream_files(config)


def test_cli_imports_from_a_config_and_reports_errors_in_one_line(folder, tmp_path, capsys):
    images, csv_path, _ = folder
    (tmp_path / "config.yaml").write_text(yaml.safe_dump(_config(folder)))
    out = tmp_path / "own.h5"
    assert main(["import-images", "--output", str(out), "--heliostat-output", str(tmp_path / "own_h.h5"),
                 "--config", str(tmp_path / "config.yaml"), "--name", "own"]) == 0
    assert read_dataset(out).images.shape == (6, 16, 16) and (tmp_path / "own_h.h5").is_file()
    capsys.readouterr()
    (images / "spot_0.png").unlink()
    spec = json.dumps(_spec(images, csv_path))
    assert main(["import-images", "--output", str(tmp_path / "bad.h5"), "--spec", spec]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("helioflow import-images: error: ")
    assert "sun.csv line 2 (image spot_0)" in lines[0] and not (tmp_path / "bad.h5").exists()
    assert main(["import-images", "--spec", spec]) == 2
    assert "give --output" in capsys.readouterr().err


def test_dry_run_imports_the_images_dataset_and_traces_only_the_synthetic_ones(folder, dry_run):
    config = _config(folder)
    config["networks"] = {"nearest": {}, "raytrace": {}}  # raytrace traces the heliostat file
    output = dry_run(config)
    jobs = {}
    for rule, output in re.findall(r"^rule (\w+):\n(?:\s+.*\n)*?\s+output: (.+)$", output,
                                   re.MULTILINE):
        jobs.setdefault(rule, set()).update(output.split(", "))
    r = "results/tiny"
    assert jobs["import_images"] == {f"{r}/datasets/own.h5"}
    assert jobs["images_heliostat"] == {f"{r}/surfaces/own.h5"}
    assert jobs["trace"] == {f"{r}/datasets/scan.h5", f"{r}/datasets/sky.h5"}
    assert jobs["surfaces"] == {f"{r}/surfaces/small.h5", f"{r}/surfaces/small_grid.h5"}
    assert f"{r}/models/own/raytrace.pt" in jobs["train"]


def test_the_own_images_variant_validates_over_the_default_config_and_its_example_imports(tmp_path, monkeypatch):
    monkeypatch.chdir(REPO)  # the variant's paths are relative to the repository root
    config = layered(("workflow/variants/own_images.yaml",))
    assert config["experiment"] == "own_images" and "field" not in config
    assert list(config["networks"]) == ["nearest", "raytrace", "drt"] and images_datasets(config) == ["own"]
    ds = import_images(import_images_params(config, "own"), tmp_path / "own.h5", tmp_path / "own_h.h5")
    assert ds.images.shape == (12, 64, 64) and ds.attrs["source_image_shape"] == [96, 96]
    assert sorted(ds.split.tolist()).count("train") == 8 and ds.attrs["per_image_normalised"] is True
    assert len(ds.extras["timestamp"]) == 12 and 11 < ds.elevation_deg.min() < ds.elevation_deg.max() < 63
