"""Rule helpers of the networks stage: model names, train parameters, targets."""

import pytest

from helioflow.config import load_config
from helioflow.errors import ConfigError
from helioflow.models.names import parse_model
from helioflow.workflow import (
    efficiency_metrics,
    expand_config,
    field_measured,
    models,
    report_inputs,
    train_inputs,
    train_params,
    train_threads,
)


@pytest.fixture
def config():
    cfg = load_config("config.yaml")
    cfg["networks"] = {"nearest": {}, "cgan": {"steps": 3}}
    return cfg


def test_parse_model_names():
    assert parse_model("cgan") == ("cgan", None)
    assert parse_model("nerf-n25") == ("nerf", 25)
    with pytest.raises(ConfigError, match="nerf-nx"):
        parse_model("nerf-nx")


def test_train_params_hold_only_the_network_section(config):
    p = train_params(config, "sanity_check", "cgan-n50")
    assert p == {"network": "cgan", "settings": {"steps": 3}, "seed": config["seed"], "train_images": 50,
                 "device": config["device"]}
    config["networks"]["nearest"] = {"steps": 7}
    assert train_params(config, "sanity_check", "cgan") == {**p, "train_images": None}


def test_unknown_network_is_named(config):
    with pytest.raises(ConfigError, match="'gan'.*nearest, cgan"):
        train_params(config, "sanity_check", "gan")


def test_report_inputs_include_evaluation_figures_table_and_data_efficiency(config):
    config["data_efficiency"] = {"networks": ["cgan"], "train_images": [25, 50]}
    inputs = report_inputs(config)
    assert "results/default/figures/semi_sphere/cgan_samples.png" in inputs["samples"]
    assert "results/default/figures/semi_sphere/cgan_psnr.png" in inputs["psnr"]
    assert "results/default/tables/table1.md" in inputs["table"]
    assert inputs["data_efficiency"] == ["results/default/figures/data_efficiency.png"]
    assert models(config) == ["nearest", "cgan", "cgan-n25", "cgan-n50"]
    assert efficiency_metrics(config) == [f"results/default/metrics/{d}/cgan-n{k}.json"
                                          for d in ("sanity_check", "semi_sphere") for k in (25, 50)]


def test_unknown_network_setting_stops_validation(config):
    config["networks"]["cgan"] = {"stepz": 3}
    from helioflow.config import validate_config

    with pytest.raises(ConfigError, match="networks.cgan: unknown setting 'stepz'"):
        validate_config(config)


def test_physics_models_get_the_datasets_model_effects_and_heliostat_file(config):
    config["networks"] = {"drt": {"fit_steps": 5}}
    config["model"]["effects"] = {"sunshape": {"kind": "buie", "csr": 0.1}, "slope_error": {"sigma_mrad": "fit"}}
    config["datasets"]["semi_sphere"]["model_effects"] = {"sunshape": {"kind": "point"}}
    p = train_params(config, "semi_sphere", "drt")
    assert p["settings"] == {"fit_steps": 5, "heliostat_path": "results/default/surfaces/multi_facet.h5",
                             "effects": {"sunshape": {"kind": "point"}, "slope_error": {"sigma_mrad": "fit"}}}
    assert train_inputs(config, "semi_sphere", "drt") == {"dataset": "results/default/datasets/semi_sphere.h5",
                                                          "heliostat": "results/default/surfaces/multi_facet.h5"}
    assert train_inputs(config, "semi_sphere", "nearest-n5") == {"dataset": "results/default/datasets/semi_sphere.h5"}


def test_short_and_many_small_trainings_take_one_thread_the_rest_torch_threads(config):
    """-j2 runs two one-thread jobs at once; the number is fixed by the config, not by -j."""
    config = expand_config({**config, "torch_threads": 2})
    assert train_threads(config, "sanity_check", "nearest") == 1
    assert train_threads(config, "sanity_check", "drt") == 2
    assert train_threads(config, field_measured(config)[0], "drt") == 1
