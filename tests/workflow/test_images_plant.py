"""A plant's own images in one CSV (source: images with heliostats and a `heliostat` column): one
dataset per heliostat, each with its own rows and its own geometry, as a PAINT plant's."""

import csv
import json
import re
from pathlib import Path

import numpy as np
import pytest
import yaml

from helioflow.config import validate_config
from helioflow.data.hdf5 import read_dataset
from helioflow.data.images import import_images
from helioflow.data.paint import Tower, import_paint
from helioflow.errors import ConfigError
from helioflow.workflow import (
    PLANT_KEY,
    expand_config,
    import_images_inputs,
    import_images_params,
    plant_flux_paths,
    plant_groups,
    plant_table_spec,
)

REPO = Path(__file__).resolve().parents[2]
WORLD = REPO / "examples" / "plant_world"  # 6 heliostats in PAINT's layout (tests/support/paint_world.py)


def _campaign_csv(path: Path, heliostats: list[str]) -> None:
    """One CSV for the heliostats' calibration images of examples/plant_world: file, heliostat, sun."""
    with path.open("w", newline="") as f:
        out = csv.writer(f)
        out.writerow(["file", "heliostat", "azimuth_deg", "elevation_deg"])
        for h in heliostats:
            for props in sorted((WORLD / h).glob("*-calibration-properties.json")):
                m = json.loads(props.read_text())
                png = props.name.replace("-calibration-properties.json", "-flux.png")
                out.writerow([f"{h}/{png}", h, m["sun_azimuth"], m["sun_elevation"]])


def _config(tmp_path: Path, **entry) -> dict:
    _campaign_csv(tmp_path / "campaign.csv", ["P000", "P001", "P002"])
    tower = Tower(WORLD / "tower-measurements.json")
    plane = tower.target("solar_tower_juelich_upper", WORLD)
    config = yaml.safe_load((REPO / "tests" / "workflow" / "tiny_config.yaml").read_text())
    config["datasets"]["own"] = {
        "source": "images", "images_dir": str(WORLD), "csv": str(tmp_path / "campaign.csv"), "resolution": [32, 32],
        "target": {"center_m": plane.center.tolist(), "normal": plane.normal.tolist(), "width_m": plane.width,
                   "height_m": plane.height},
        "heliostats": "all", "heliostat_properties": str(WORLD / "{heliostat}" / "heliostat-properties.json"),
        "origin_wgs84": list(tower.origin), **entry}
    config.update(networks={"drt": {}}, diagnosis={})
    return config


def test_one_csv_becomes_one_dataset_per_heliostat_that_imports_as_the_same_plant_from_paint(tmp_path):
    config = expand_config(validate_config(_config(tmp_path, heliostats="P00[01]")))
    assert plant_groups(config) == {"own": ["own_P000", "own_P001"]}
    ds = config["datasets"]["own_P001"]
    assert ds[PLANT_KEY] == "own" and ds["csv_heliostat"] == "P001"
    assert ds["heliostat_properties"] == str(WORLD / "P001" / "heliostat-properties.json")
    images = import_images_inputs(config, "own_P001")["images"]
    assert len(images) == 16 and all("/P001/" in f for f in images)  # its own rows only
    assert [h["heliostat"] for h in plant_table_spec(config)["heliostats"]] == ["P000", "P001"]
    assert plant_flux_paths(config) == []  # no PAINT directory: the field's other heliostats are unknown
    own = import_images(import_images_params(config, "own_P001"), tmp_path / "own.h5", tmp_path / "own_geometry.h5")
    paint = import_paint(str(WORLD), "P001", tmp_path / "paint.h5", tmp_path / "paint_geometry.h5", resolution=(32, 32))
    assert own.attrs["csv_heliostat"] == "P001"
    np.testing.assert_allclose(own.azimuth_deg, paint.azimuth_deg, atol=1e-9)
    np.testing.assert_allclose(own.elevation_deg, paint.elevation_deg, atol=1e-9)
    peaks = paint.images.max(axis=(1, 2), keepdims=True)  # PAINT's scale is its own; the spots are the same
    np.testing.assert_allclose(own.images, paint.images / peaks, atol=1e-6)
    np.testing.assert_allclose(own.attrs["heliostat_position_m"], paint.attrs["heliostat_position_m"], atol=1e-6)
    assert read_dataset(tmp_path / "own.h5").images.shape == (16, 32, 32)


@pytest.mark.parametrize("edit, message", [
    (lambda c, t: c["datasets"]["own"].update(heliostats="Q*"),
     "datasets.own.heliostats: {csv}: 'Q*' selects no heliostat of column 'heliostat' "
     "(heliostats there: P000, P001, P002)"),
    (lambda c, t: c["datasets"]["own"].update(heliostats=["P001", "P009"]),
     "datasets.own.heliostats: {csv}: no image of heliostat 'P009' in column 'heliostat'"),
    (lambda c, t: c["datasets"]["own"].update(heliostat_properties=str(WORLD / "P000" / "heliostat-properties.json")),
     "datasets.own: a plant's heliostats stand at their own positions: give heliostat_properties with {heliostat}"),
    (lambda c, t: c["datasets"]["own"].update(heliostat_properties=str(t / "{heliostat}.json")),
     "datasets.own.heliostat_properties: {tmp}/P000.json (heliostat 'P000') does not exist"),
    (lambda c, t: (t / "campaign.csv").write_text("file,azimuth_deg,elevation_deg\nP000/100000-flux.png,1,20\n"),
     "datasets.own.heliostats: {csv}: no column 'heliostat' (columns found: file, azimuth_deg, elevation_deg)"),
])
def test_a_bad_images_plant_names_the_key_the_file_and_what_was_expected(tmp_path, edit, message):
    config = _config(tmp_path)
    edit(config, tmp_path)
    expected = message.format(csv=tmp_path / "campaign.csv", tmp=tmp_path, heliostat="{heliostat}")
    with pytest.raises(ConfigError, match=re.escape(expected)):
        validate_config(config)


def test_an_images_plant_beside_a_paint_plant_validates(tmp_path):
    config = _config(tmp_path)
    config["datasets"]["paint_plant"] = {"source": "paint", "paint_dir": str(WORLD), "heliostats": ["P000", "P001"],
                                         "resolution": [32, 32]}
    config = expand_config(validate_config(config))  # the PAINT plant has no `heliostat` of its own to compare
    assert set(plant_groups(config)) == {"own", "paint_plant"}
