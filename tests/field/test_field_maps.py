"""Rule compose_field's function on the tiny field (tests/workflow/tiny_field.yaml: 5 one-metre
heliostats, 2 measured, nearest models on 12-image calibration datasets): the three maps, the
metrics, flux.h5, and a perfect model reproducing the truth to within the carrying error."""

import copy
import json
import math

import numpy as np
import pytest
import torch
from support.field import build, tiny_field

from helioflow.data.hdf5 import read_arrays
from helioflow.errors import ConfigError, DataError
from helioflow.field import compose as field_maps
from helioflow.field.compose import SCHEMA, aim_points, build_scene, compose_field, without_fit
from helioflow.field.metrics import MAP_METRICS, SPOT_METRICS, spot_metrics
from helioflow.physics.carry import equivalent_sun
from helioflow.physics.field import BUDGET_TERMS, flat_receiver
from helioflow.physics.geometry import azimuth_elevation, sun_vector
from helioflow.workflow import compose_field_params


@pytest.fixture(scope="module")
def composed(tmp_path_factory):
    root = tmp_path_factory.mktemp("field")
    config = tiny_field()
    models, datasets = build(config, root)
    out = root / "out"
    metrics = compose_field(
        compose_field_params(config),
        models,
        datasets,
        out / "flux.h5",
        out / "flux.png",
        out / "metrics.json",
    )
    return config, metrics, out, models, datasets


def test_the_configured_device_reaches_compose_field(composed, monkeypatch, tmp_path):
    """The spec's device is the one the field is traced and the models predict on (see
    tests/test_device.py; answered with the CPU here)."""
    config, _, _, models, datasets = composed
    asked = []
    monkeypatch.setattr(field_maps, "resolve_device", lambda d: asked.append(d) or torch.device("cpu"))
    compose_field({**compose_field_params(config), "device": "cuda"}, models, datasets, tmp_path / "f.h5",
                  tmp_path / "f.png", tmp_path / "m.json")
    assert asked == ["cuda"]


def test_three_maps_per_design_point_and_the_measured_spots(composed):
    _, _, out, _, _ = composed
    arrays, attrs = read_arrays(out / "flux.h5", SCHEMA)
    for m in ("truth", "ideal", "hybrid"):
        assert arrays[m].shape == (2, 32, 32) and arrays[m].dtype == np.float32 and arrays[m].min() >= 0
        assert arrays[m].max() > 100.0
    assert list(arrays["design_points"]) == ["noon", "morning"]
    assert list(arrays["measured/names"]) == ["field_001", "field_003"]
    for s in ("truth", "ideal", "hybrid", "carried_truth"):
        assert arrays[f"measured/{s}"].shape == (2, 2, 32, 32)
    assert arrays["heliostats/measured"].tolist() == [False, True, False, True, False]
    assert arrays["measured/equivalent_sun_deg"].shape == (2, 2, 2)
    assert all(arrays[f"budget/truth/{t}"].shape == (2, 5) for t in BUDGET_TERMS)
    # the measured heliostats' ideal spots are their share of the ideal map; the hybrid swaps them
    swapped = arrays["ideal"] - arrays["measured/ideal"].sum(1) + arrays["measured/hybrid"].sum(1)
    assert np.allclose(arrays["hybrid"], np.clip(swapped, 0, None), atol=1e-2)
    assert attrs["network"] == "nearest" and attrs["receiver_size_m"] == [3.0, 3.0]
    assert (out / "flux.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_metrics_per_design_point_map_and_measured_heliostat(composed):
    _, metrics, out, _, _ = composed
    assert json.loads((out / "metrics.json").read_text()) == metrics
    assert metrics["measured"] == ["field_001", "field_003"] and metrics["heliostats"] == 5
    for point in ("noon", "morning"):
        row = metrics["design_points"][point]
        assert set(row["ideal"]) == set(row["hybrid"]) == set(MAP_METRICS)
        assert 0.5 < row["truth"]["intercept"] <= 1.0
        for name in ("field_001", "field_003"):
            h = row["measured"][name]
            assert set(h) == {
                "equivalent_sun_deg",
                "nearest_calibration_deg",
                "hybrid_from",
                "ideal",
                "hybrid",
                "carried_truth",
            }
            assert h["hybrid_from"] == "carried learned spot"  # nearest is a network: its spot is carried
            assert all(set(h[s]) == set(SPOT_METRICS) for s in ("ideal", "hybrid", "carried_truth"))
            assert 0 < h["equivalent_sun_deg"][1] < 90 and h["nearest_calibration_deg"] >= 0
    summary = metrics["summary"]
    assert set(summary) == {"ideal", "hybrid", "measured_heliostats"}
    assert summary["measured_heliostats"]["carried_truth"]["flux_accuracy"] > 0.8
    assert metrics["seconds"] > 0


def test_a_perfect_model_gives_the_truth_to_within_the_carrying_error(tmp_path):
    """Calibration images at exactly the equivalent sun positions make `nearest` a perfect model:
    the hybrid spot is then the carried true spot, and its error against the true receiver spot
    is the carrying error alone (the factors agree: no blocking, the same atmosphere)."""
    config = tiny_field()
    for key in ("world_effects", "model_effects"):
        config["field"][key] = {"attenuation": {"model": "vittitoe_biggs_clear"}}
    spec = compose_field_params(config)
    scene = build_scene(spec, torch.device("cpu"))
    target = torch.tensor(config["target"]["center_m"], dtype=torch.float64)
    for k in scene.measured:
        suns = [
            equivalent_sun(scene.true[k].position, scene.aims[k], s, target)
            for s in sun_vector(scene.azimuth, scene.elevation)
        ]
        positions = [[math.degrees(float(a)) for a in azimuth_elevation(s)] for s in suns]
        config["datasets"][scene.names[k]]["sun"] = {"kind": "list", "positions_deg": positions}
    models, datasets = build(config, tmp_path)
    metrics = compose_field(
        spec, models, datasets, tmp_path / "f.h5", tmp_path / "f.png", tmp_path / "m.json"
    )
    arrays, _ = read_arrays(tmp_path / "f.h5", SCHEMA)
    hybrid, carried, truth = (arrays[f"measured/{s}"] for s in ("hybrid", "carried_truth", "truth"))
    assert np.allclose(hybrid, carried, rtol=1e-4, atol=1e-3 * truth.max())
    for row in metrics["design_points"].values():
        for h in row["measured"].values():
            assert h["nearest_calibration_deg"] < 1e-3
            assert h["hybrid"]["flux_accuracy"] == pytest.approx(
                h["carried_truth"]["flux_accuracy"], abs=1e-4
            )
            assert h["hybrid"]["flux_accuracy"] > 0.85
            assert h["hybrid"]["flux_accuracy"] > h["ideal"]["flux_accuracy"]


def test_inputs_of_another_heliostat_or_count_are_errors(composed, tmp_path):
    config, _, _, models, datasets = composed
    spec = compose_field_params(config)
    with pytest.raises(DataError, match="a dataset of heliostat 'field_003', expected 'field_001'"):
        compose_field(
            spec, models, datasets[::-1], tmp_path / "f.h5", tmp_path / "f.png", tmp_path / "m.json"
        )
    with pytest.raises(ConfigError, match="2 measured heliostats, but 1 models"):
        compose_field(spec, models[:1], datasets, tmp_path / "f.h5", tmp_path / "f.png", tmp_path / "m.json")
    assert not list(tmp_path.iterdir())


def test_vertical_aim_points_spread_over_the_receiver_height():
    receiver = flat_receiver([0.0, 0.0, 30.0], [0.0, 1.0, 0.0], 4.0, 6.0)
    aims = aim_points(receiver, {"kind": "vertical", "spread": 0.5, "levels": 3}, 5)
    assert aims[:, 2].tolist() == pytest.approx([28.5, 30.0, 31.5, 28.5, 30.0])
    assert aims[:, :2].abs().max() < 1e-12
    assert torch.equal(aim_points(receiver, {"kind": "center"}, 2), receiver.center.expand(2, 3))


def test_fit_values_take_the_registry_default():
    effects = {
        "sunshape": {"kind": "pillbox", "half_angle_mrad": "fit"},
        "slope_error": {"sigma_mrad": "fit"},
        "surface": {"control_heights_mm": "fit"},
    }
    assert without_fit(effects) == {
        "sunshape": {"kind": "pillbox", "half_angle_mrad": 4.65},
        "slope_error": {"sigma_mrad": 1.0},
        "surface": {},
    }
    assert effects["slope_error"] == {"sigma_mrad": "fit"}


def test_spot_metrics_of_exact_and_scaled_maps():
    truth = np.zeros((8, 8))
    truth[2:5, 3:6] = 1000.0
    exact = spot_metrics(truth, truth, (0.1, 0.1))
    assert exact == {
        "flux_accuracy": 1.0,
        "psnr_db": 100.0,
        "peak_flux_error": 0.0,
        "centroid_error_m": 0.0,
        "power_error": 0.0,
    }
    shifted = spot_metrics(1.1 * np.roll(truth, 1, axis=1), truth, (0.1, 0.2))
    assert shifted["peak_flux_error"] == pytest.approx(0.1) and shifted["power_error"] == pytest.approx(0.1)
    assert shifted["centroid_error_m"] == pytest.approx(0.1)


def test_a_physics_models_hybrid_spot_is_its_fit_traced_on_the_receiver(tmp_path):
    """A drt model whose fit is the heliostat's truth (its tracking and surface as the surfaces rule
    drew them, the world's slope error) under the world's physics: its hybrid spot is traced on the
    receiver as fitted, so on these canted 2 x 2 heliostats it is the true spot, where the true
    calibration spot carried there (what a perfect learned model gives) keeps the carrying error."""
    def canted(config: dict) -> None:
        config["field"]["heliostat"] = "small_grid"
        config["field"]["network"] = "drt"
        config["networks"] = {"drt": {}}
        config["model"]["effects"] = copy.deepcopy(config["world"]["effects"])
        for key in ("world_effects", "model_effects"):
            config["field"][key] = {"attenuation": {"model": "vittitoe_biggs_clear"}}

    config = tiny_field(canted)
    models, datasets = build(config, tmp_path, "drt", {"fit_steps": 1, "rounds": 1, "fit_images": 2,
                                                        "facet_hops": 0, "pinned_hops": 0, "gauss_newton_steps": 0})
    spec = compose_field_params(config)
    scene = build_scene(spec, torch.device("cpu"))
    for k, path in zip(scene.measured, models):
        info = torch.load(path, weights_only=False)
        fit = info["state"]["_extra_state"]
        truth = scene.true[k]
        fit["tensors"] = {"tracking": truth.tracking_error * 1e3, "canting": truth.canting_error * 1e3,
                          "surface": truth.control_heights * 1e3}  # mrad, mrad, mm: the fit's units
        fit["tensors"] = {key: value.float() for key, value in fit["tensors"].items()}  # as the model holds them
        fit["effects"] = {**fit["effects"], "slope_error": {"sigma_mrad": 0.5}}
        torch.save(info, path)
    metrics = compose_field(spec, models, datasets, tmp_path / "f.h5", tmp_path / "f.png", tmp_path / "m.json")
    for row in metrics["design_points"].values():
        for h in row["measured"].values():
            assert h["hybrid_from"] == "traced fit"
            assert h["hybrid"]["flux_accuracy"] > 0.999, h
            assert h["hybrid"]["flux_accuracy"] > h["carried_truth"]["flux_accuracy"] + 0.01, h
