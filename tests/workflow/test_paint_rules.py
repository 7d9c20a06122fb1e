"""PAINT datasets in config (source: paint): validation, rule helpers, and the DAG picks the PAINT
rules (import_paint, paint_heliostat, paint_centroids) instead of trace and surfaces for them."""

import copy
import re
from pathlib import Path

import pytest
import yaml

from helioflow.config import validate_config
from helioflow.errors import ConfigError
from helioflow.workflow import (
    import_paint_inputs,
    import_paint_params,
    name_pattern,
    paint_datasets,
    paint_heliostat_params,
    paint_heliostats,
    report_inputs,
)

REPO = Path(__file__).resolve().parents[2]
PAINT = REPO / "tests" / "data" / "paint"


def _config(**paint) -> dict:
    config = yaml.safe_load((REPO / "tests" / "workflow" / "tiny_config.yaml").read_text())
    config["datasets"]["aa39"] = {"source": "paint", "paint_dir": str(PAINT), "heliostat": "AA39",
                                  "holdout": ["extra1"], **paint}
    return config


def test_a_paint_dataset_validates_and_synthetic_ones_default_to_source_synthetic():
    config = validate_config(_config())
    assert config["datasets"]["scan"]["source"] == "synthetic"
    assert paint_datasets(config) == ["aa39"] and paint_heliostats(config) == ["AA39"]


@pytest.mark.parametrize("edit, message", [
    (lambda c: c["datasets"]["aa39"].pop("paint_dir"), "datasets.aa39: missing key 'paint_dir'"),
    (lambda c: c["datasets"]["aa39"].update(sun={"kind": "scan"}), "key 'sun' is for traced datasets"),
    (lambda c: c["datasets"]["scan"].update(holdout=["1"]), "key 'holdout' is for PAINT datasets"),
    (lambda c: c["datasets"]["scan"].pop("trace"), "datasets.scan: missing key 'trace'"),
    (lambda c: c["datasets"]["aa39"].update(heliostat="small"), "'small' is also a configured heliostat"),
    (lambda c: c["datasets"]["aa39"].update(resolution=[64]), "datasets.aa39.resolution = [64]"),
    (lambda c: c["datasets"]["aa39"].update(centered="shape"), "datasets.aa39.centered = 'shape'"),
    (lambda c: c["datasets"]["scan"].update(centered="skip"), "key 'centered' is for PAINT datasets"),
    (lambda c: c["datasets"].update(b={"source": "paint", "paint_dir": "elsewhere", "heliostat": "AA39"}),
     "one heliostat, one PAINT directory"),
])
def test_bad_paint_config_names_the_key(edit, message):
    config = _config()
    edit(config)
    with pytest.raises(ConfigError, match=re.escape(message)):
        validate_config(config)


def test_import_params_default_the_resolution_to_the_targets_and_inputs_list_the_files():
    config = validate_config(_config())
    params = import_paint_params(config, "aa39")
    assert params == {"dataset": "aa39", "paint_dir": str(PAINT), "heliostat": "AA39", "resolution": [16, 16],
                      "holdout": ["extra1"], "targets": None, "dni_w_m2": config["dni_w_m2"], "centered": "place"}
    wide = validate_config(_config(resolution=[64, 64]))
    assert import_paint_params(wide, "aa39")["resolution"] == [64, 64]
    assert paint_heliostat_params(config, "AA39") == {"paint_dir": str(PAINT), "heliostat": "AA39"}
    files = import_paint_inputs(config, "aa39")
    assert files["properties"] == str(PAINT / "AA39" / "heliostat-properties.json")
    assert len(files["measurements"]) == 24 and all(Path(f).is_file() for f in files["measurements"])
    assert sum(f.endswith("-flux-centered.png") for f in files["measurements"]) == 6  # the centered-only ones
    skip = import_paint_inputs(validate_config(_config(centered="skip")), "aa39")["measurements"]
    assert len(skip) == 12 and not any(f.endswith("-flux-centered.png") for f in skip)
    with pytest.raises(ConfigError, match="not imported from PAINT"):
        import_paint_params(config, "scan")
    assert report_inputs(config)["paint_centroids"] == ["results/tiny/paint/aa39_centroids.json"]


def test_name_pattern_matches_exactly_the_names():
    pattern = name_pattern(["aa39", "a.b"])
    assert re.fullmatch(pattern, "aa39") and re.fullmatch(pattern, "a.b")
    assert not re.fullmatch(pattern, "aa3") and not re.fullmatch(pattern, "axb")
    assert not re.fullmatch(name_pattern([]), "")


def test_dry_run_imports_paint_datasets_and_traces_only_the_synthetic_ones(dry_run):
    config = _config()
    config["datasets"]["aa39_mf"] = {**copy.deepcopy(config["datasets"]["aa39"]),
                                     "targets": ["multi_focus_tower"]}
    output = dry_run(config)
    jobs = {}
    job = re.compile(r"^rule (\w+):\n(?:\s+.*\n)*?\s+output: (.+)$", re.MULTILINE)
    for rule, output in job.findall(output):
        jobs.setdefault(rule, set()).update(output.split(", "))
    r = "results/tiny"
    assert jobs["import_paint"] == {f"{r}/datasets/aa39.h5", f"{r}/datasets/aa39_mf.h5"}
    assert jobs["paint_heliostat"] == {f"{r}/surfaces/AA39.h5"}
    assert jobs["trace"] == {f"{r}/datasets/scan.h5", f"{r}/datasets/sky.h5"}
    assert jobs["surfaces"] == {f"{r}/surfaces/small.h5", f"{r}/surfaces/small_grid.h5"}
    assert jobs["paint_centroids"] == {f"{r}/paint/aa39_centroids.json", f"{r}/paint/aa39_mf_centroids.json"}
