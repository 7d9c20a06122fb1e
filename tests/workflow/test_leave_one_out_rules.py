"""Leave-one-out on PAINT datasets (holdout: leave_one_out -> one fold dataset per image), and the
real-data variants validated as snakemake layers them over config.yaml."""

import copy
import json
import shutil
from pathlib import Path

import pytest
import yaml
from support.pipeline import layered

from helioflow.config import validate_config
from helioflow.errors import ConfigError
from helioflow.workflow import (
    FOLD_KEY,
    centroid_datasets,
    expand_config,
    expand_leave_one_out,
    import_paint_params,
    leave_one_out_groups,
    leave_one_out_inputs,
    report_inputs,
)

REPO = Path(__file__).resolve().parents[2]
PAINT = REPO / "tests" / "data" / "paint"
MULTI_FOCUS = ["202558", "205363", "218385", "270398", "275564", "extra1", "extra3"]  # 3 centered-only


def _config(paint_dir=PAINT, **aa39) -> dict:
    config = yaml.safe_load((REPO / "tests" / "workflow" / "tiny_config.yaml").read_text())
    config["datasets"]["aa39"] = {"source": "paint", "paint_dir": str(paint_dir), "heliostat": "AA39",
                                  "holdout": "leave_one_out", **aa39}
    return validate_config(config)


def test_leave_one_out_makes_one_dataset_per_image_each_holding_that_one_out():
    config = expand_leave_one_out(_config(targets=["multi_focus_tower"]))
    folds = [f"aa39_loo_{i}" for i in MULTI_FOCUS]
    assert list(config["datasets"]) == ["scan", "sky", "aa39", *folds]  # aa39 itself, then its folds, in order
    whole = config["datasets"]["aa39"]  # the calibration on every image: nothing held out
    assert "holdout" not in whole and FOLD_KEY not in whole and import_paint_params(config, "aa39")["holdout"] == []
    for fold, mid in zip(folds, MULTI_FOCUS):
        ds = config["datasets"][fold]
        assert ds["holdout"] == [mid] and ds[FOLD_KEY] == "aa39" and ds["targets"] == ["multi_focus_tower"]
        assert import_paint_params(config, fold)["holdout"] == [mid]
    assert leave_one_out_groups(config) == {"aa39": folds}
    every = expand_leave_one_out(_config())  # no target filter: every image of the folder
    assert leave_one_out_groups(every)["aa39"] == [f"aa39_loo_{i}" for i in
                                                   ["202558", "205363", "209075", "218385", "223788", "246955",
                                                    "270398", "271633", "275564", "extra1", "extra2", "extra3"]]
    skip = expand_leave_one_out(_config(centered="skip"))  # the whole-target images alone
    assert leave_one_out_groups(skip)["aa39"] == [f"aa39_loo_{i}" for i in
                                                  ["270398", "271633", "275564", "extra1", "extra2", "extra3"]]


def test_a_config_without_leave_one_out_is_unchanged():
    config = _config(holdout=["extra1"])
    assert expand_leave_one_out(config) == config and leave_one_out_groups(config) == {}


def test_rule_inputs_list_every_fold_per_network_and_the_report_takes_the_summary():
    config = expand_config(_config(targets=["multi_focus_tower"]))
    config["networks"] = {"nearest": {}, "drt": {}}
    inputs = leave_one_out_inputs(config, "aa39")
    r = "results/tiny"
    assert inputs["datasets"] == [f"{r}/datasets/aa39_loo_{i}.h5" for i in MULTI_FOCUS]
    assert inputs["model_drt"] == [f"{r}/models/aa39_loo_{i}/drt.pt" for i in MULTI_FOCUS]
    assert inputs["metrics_nearest"] == [f"{r}/metrics/aa39_loo_{i}/nearest.csv" for i in MULTI_FOCUS]
    assert set(inputs) == {"datasets", "model_nearest", "metrics_nearest", "model_drt", "metrics_drt"}
    assert report_inputs(config)["leave_one_out"] == [f"{r}/figures/leave_one_out/aa39.png",
                                                      f"{r}/leave_one_out/aa39.csv"]
    assert centroid_datasets(config) == ["aa39"]  # the folds hold the same images: one check, on the whole
    # the whole one's fit, not the folds'
    assert report_inputs(config)["heliostats"] == [f"{r}/heliostats/aa39.json", f"{r}/heliostats/aa39.png"]
    config["diagnosis"] = {}
    assert report_inputs(config)["diagnosis"] == [f"{r}/diagnosis/{d}.json" for d in ("scan", "sky", "aa39")]
    with pytest.raises(ConfigError, match="no leave-one-out dataset 'scan'; leave-one-out datasets: aa39"):
        leave_one_out_inputs(config, "scan")


@pytest.mark.parametrize("edit, message", [
    ({"targets": ["solar_tower_juelich_upper"]}, "at least two measurements; .*AA39 has 0 on targets"),
    ({"heliostat": "AB99"}, "heliostat = .AB99.: no such heliostat folder in .*; folders there: AA23"),
])
def test_leave_one_out_without_enough_images_is_a_config_error(edit, message):
    with pytest.raises(ConfigError, match=message):
        expand_leave_one_out(_config(**edit))


def test_a_fold_name_in_use_and_an_unreadable_measurement_are_config_errors(tmp_path):
    config = _config()
    config["datasets"]["aa39_loo_extra1"] = copy.deepcopy(config["datasets"]["scan"])
    with pytest.raises(ConfigError, match="fold name 'aa39_loo_extra1' is already a dataset"):
        expand_leave_one_out(config)
    paint = tmp_path / "paint"
    shutil.copytree(PAINT, paint)
    path = paint / "AA39" / "extra2-calibration-properties.json"
    path.write_text(json.dumps({k: v for k, v in json.loads(path.read_text()).items() if k != "target_name"}))
    with pytest.raises(ConfigError, match=f"{path}: missing field 'target_name'"):
        expand_leave_one_out(_config(paint_dir=paint))


def test_the_paint_aa39_variant_validates_over_the_default_config_and_runs_folds_of_real_images():
    config = layered(("workflow/variants/paint_aa39.yaml",))
    assert config["experiment"] == "paint_aa39" and "field" not in config
    assert list(config["networks"]) == ["nearest", "raytrace", "drt"]
    groups = leave_one_out_groups(config)
    assert groups == {"aa39": [f"aa39_loo_{i}" for i in MULTI_FOCUS],
                      "aa39_lower": [f"aa39_lower_loo_{i}" for i in ["209075", "223788", "246955", "271633",
                                                                       "extra2"]]}
    assert set(config["datasets"]) == {f for folds in groups.values() for f in folds} | {"aa39", "aa39_lower"}
    assert all(ds["paint_dir"] == "tests/data/paint" for ds in config["datasets"].values())


def test_the_paint_heliostats_variant_takes_every_real_heliostat_with_two_images_on_a_target():
    config = layered(("workflow/variants/paint_heliostats.yaml",))
    assert config["experiment"] == "paint_heliostats" and "field" not in config
    groups = leave_one_out_groups(config)
    assert {g: len(f) for g, f in groups.items()} == {"aa39": 7, "aa39_lower": 5, "aa31_lower": 4, "aa31": 2,
                                                     "ad37_upper": 3, "ad37": 2, "au46_lower": 5}
    assert {config["datasets"][g]["heliostat"] for g in groups} == {"AA39", "AA31", "AD37", "AU46"}
    r = "results/paint_heliostats"
    assert report_inputs(config)["diagnosis"] == [f"{r}/diagnosis/{g}.json" for g in groups]  # the whole ones
    assert report_inputs(config)["heliostats"][::2] == [f"{r}/heliostats/{g}.json" for g in groups]
