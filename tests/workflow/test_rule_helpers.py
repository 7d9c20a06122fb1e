"""The rule helpers the Snakefile binds (helioflow.workflow): each rule's params hold exactly what
its output depends on, so snakemake's params trigger reruns only what a config edit touches."""

import copy
import json
from pathlib import Path

import pytest

from helioflow.config import load_config
from helioflow.errors import ConfigError, HelioflowError
from helioflow.workflow import (
    all_targets,
    compose_field_inputs,
    compose_field_params,
    dataset_heliostat,
    expand_config,
    metrics_paths,
    report_inputs,
    rule_spec,
    spec_path,
    surfaces_params,
    trace_params,
    world_effects,
    write_spec,
)

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def default_config():
    return load_config(REPO / "config.yaml")


@pytest.fixture
def config(default_config):
    return copy.deepcopy(default_config)


def test_trace_params_hold_the_dataset_section_target_and_merged_world_effects(config):
    params = trace_params(config, "semi_sphere")
    ds = config["datasets"]["semi_sphere"]
    assert set(params) == {"dataset", "heliostat", "sun", "splits", "trace", "window_m", "target",
                           "world_effects", "dni_w_m2", "seed", "device"}
    assert params["dataset"] == "semi_sphere" and params["heliostat"] == "multi_facet"
    for key in ("sun", "splits", "trace", "window_m"):
        assert params[key] == ds[key]
    assert params["target"] == config["target"]
    # Nothing of the other dataset, the heliostat sections or the model leaks in.
    text = json.dumps(params)
    for foreign in ("sanity_check", "square", "position_m", "pillbox", "half_angle_mrad"):
        assert foreign not in text


def test_dataset_world_effects_replace_global_entries_by_name(config):
    merged = trace_params(config, "semi_sphere")["world_effects"]
    assert merged == {
        "sunshape": {"kind": "point"},  # dataset entry replaces the global buie one wholesale (no csr left)
        "slope_error": {"sigma_mrad": 0.3},  # dataset value wins
        "tracking": {}, "canting": {}, "surface": {},  # global entries kept
    }
    config["datasets"]["sanity_check"]["world_effects"] = {"reflectivity": {"value": 0.9}}
    expected = {**config["world"]["effects"], "reflectivity": {"value": 0.9}}
    assert world_effects(config, "sanity_check") == expected
    del config["datasets"]["sanity_check"]["world_effects"]
    assert world_effects(config, "sanity_check") == config["world"]["effects"]


def test_a_global_effect_that_a_dataset_overrides_does_not_touch_it(config):
    before = trace_params(config, "semi_sphere")
    config["world"]["effects"]["slope_error"]["sigma_mrad"] = 0.7  # semi_sphere sets its own slope_error
    assert trace_params(config, "semi_sphere") == before
    assert trace_params(config, "sanity_check")["world_effects"]["slope_error"] == {"sigma_mrad": 0.7}


def test_params_are_copies(config):
    before = copy.deepcopy(config)
    params = trace_params(config, "sanity_check")
    params["sun"]["n"] = 3
    params["world_effects"]["sunshape"]["csr"] = 0.3
    params["target"]["resolution"][0] = 8
    surfaces_params(config, "square")["facets"]["rows"] = 9
    assert config == before


@pytest.mark.parametrize("edit", [
    lambda c: c["datasets"]["semi_sphere"]["trace"].update(rays=123),
    lambda c: c["datasets"]["semi_sphere"]["sun"].update(n=7),
    lambda c: c["datasets"]["semi_sphere"]["world_effects"].update(camera={"noise": 0.1}),
    lambda c: c["heliostats"]["multi_facet"].update(deformation_mm=1.0),
    lambda c: c["model"]["effects"]["sunshape"].update(half_angle_mrad=5.0),
], ids=["semi_sphere.trace", "semi_sphere.sun", "semi_sphere.world_effects", "other heliostat", "model"])
def test_editing_another_section_leaves_sanity_check_params_unchanged(config, edit):
    before = (trace_params(config, "sanity_check"), surfaces_params(config, "square"))
    edit(config)
    assert (trace_params(config, "sanity_check"), surfaces_params(config, "square")) == before


@pytest.mark.parametrize("edit", [
    lambda c: c["world"]["effects"].update(reflectivity={"value": 0.9}),
    lambda c: c["target"].update(resolution=[32, 32]),
    lambda c: c.update(seed=1),
    lambda c: c.update(dni_w_m2=900.0),
], ids=["world.effects", "target", "seed", "dni"])
def test_editing_a_shared_section_changes_every_dataset(config, edit):
    before = {d: trace_params(config, d) for d in config["datasets"]}
    edit(config)
    for d in config["datasets"]:
        assert trace_params(config, d) != before[d]


def test_surfaces_params_are_the_heliostat_section_and_its_name(config):
    expected = {"name": "multi_facet", **config["heliostats"]["multi_facet"]}
    assert surfaces_params(config, "multi_facet") == expected
    assert dataset_heliostat(config, "semi_sphere") == "multi_facet"


@pytest.mark.parametrize("call, name, known", [
    (lambda c: trace_params(c, "nope"), "'nope'", "sanity_check, semi_sphere"),
    (lambda c: dataset_heliostat(c, "nope"), "'nope'", "sanity_check, semi_sphere"),
    (lambda c: surfaces_params(c, "round"), "'round'", "square, multi_facet"),
])
def test_unknown_name_raises_config_error_listing_known_names(config, call, name, known):
    with pytest.raises(ConfigError) as exc:
        call(config)
    assert name in str(exc.value) and known in str(exc.value)


def test_all_targets_are_the_report_whose_inputs_are_datasets_and_figures_under_results_experiment(config):
    config["networks"] = {}
    for section in ("diagnosis", "field"):
        config.pop(section, None)
    assert all_targets(config) == ["results/default/report.html"]
    inputs = report_inputs(config)
    assert inputs["datasets"] == ["results/default/datasets/sanity_check.h5",
                                  "results/default/datasets/semi_sphere.h5"]
    assert inputs["dataset_figures"] == ["results/default/figures/datasets/sanity_check.png",
                                         "results/default/figures/datasets/semi_sphere.png"]
    config["experiment"] = "run-2"
    del config["datasets"]["semi_sphere"]
    assert all_targets(config) == ["results/run-2/report.html"]
    assert [f for files in report_inputs(config).values() for f in files] == [
        "results/run-2/datasets/sanity_check.h5", "results/run-2/figures/datasets/sanity_check.png"]


def test_parameters_that_grow_with_the_plant_travel_in_a_spec_file_the_cli_reads(default_config, tmp_path):
    """rule `spec` writes rule_spec(config, rule) to specs/<rule>.json; the rules pass `@file` instead
    of the lists, which for a plant exceed what one command-line argument holds (128 KiB)."""
    from helioflow.cli import _metric_paths, read_spec

    config = expand_config(default_config)
    assert rule_spec(config, "report") == report_inputs(config)
    assert rule_spec(config, "table") == {"metrics": metrics_paths(config)}
    assert rule_spec(config, "compose_field") == {**compose_field_params(config), **compose_field_inputs(config)}
    assert spec_path(config, "report") == "results/default/specs/report.json"
    with pytest.raises(ConfigError, match="no spec file for rule 'train'"):
        rule_spec(config, "train")
    path = tmp_path / "table.json"
    write_spec(rule_spec(config, "table"), str(path), str(tmp_path / "table.log"))
    assert _metric_paths([f"@{path}"]) == metrics_paths(config)
    assert _metric_paths(["a.json", "b.json"]) == ["a.json", "b.json"]
    assert read_spec(f"@{path}") == {"metrics": metrics_paths(config)}
    with pytest.raises(HelioflowError, match="missing.json: cannot read the rule's parameters"):
        read_spec(f"@{tmp_path / 'missing.json'}")
