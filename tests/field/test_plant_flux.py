"""The plant's flux map (field.plant, rule plant_flux) on tests/data/paint's heliostats at the Jülich
tower: AA39 calibrated, AA28, AA31, AC43, AD37 and AU46 ideal (AA23 has no geometry: not part of the field)."""

import json
import math
import shutil
from pathlib import Path

import h5py
import numpy as np
import pytest
import torch

from helioflow.data.paint import PROPERTIES_FILE, Tower, read_heliostat_properties
from helioflow.errors import DataError
from helioflow.field.plant import compose_plant, map_effects, plant_folders
from helioflow.models.nearest import Nearest, NearestConfig
from helioflow.models.physical import DrtConfig, DrtModel
from helioflow.models.physics_fit import FitResult
from helioflow.models.registry import save_model
from helioflow.physics.geometry import normalize

PAINT = Path(__file__).parents[1] / "data" / "paint"
SETTINGS = {"receiver": "receiver", "resolution": [64, 64], "aim": {"kind": "center"},
            "sun": {"noon": {"azimuth_deg": 0.0, "elevation_deg": 40.0}},
            "effects": {"blocking_shading": {}}, "cells_per_side": 4}


def _drt(path, tracking_mrad=(0.0,) * 5, slope_mrad=None):
    """A drt model of AA39 (design geometry) whose fit holds these tracking errors and slope error."""
    tower = Tower(PAINT / "tower-measurements.json")
    design, _ = read_heliostat_properties(PAINT / "AA39" / PROPERTIES_FILE, tower)
    model = DrtModel(DrtConfig(effects={"sunshape": {"kind": "pillbox"}}, heliostat_path="AA39.h5"), (32, 32))
    model.heliostat = design.to("cpu", torch.float32)
    effects = {"sunshape": {"kind": "pillbox"}}
    if slope_mrad is not None:
        effects["slope_error"] = {"sigma_mrad": slope_mrad}
    model.fitted = FitResult(effects, {"tracking": torch.tensor(tracking_mrad, dtype=torch.float32)})
    save_model(path, model, "drt", model.config, 1.0, {})
    return str(path)


def _spec(model_path, paint_dir=PAINT, **settings):
    return {"plant": "plant", "paint_dir": str(paint_dir), "device": "cpu", "dni_w_m2": 1000.0,
            "effects": {"sunshape": {"kind": "pillbox"}, "slope_error": {"sigma_mrad": 1.0},
                        "camera": {"blur_px": "fit"}, "tracking": {"axis_1_offset_mrad": "fit"}},
            "calibrated": [{"heliostat": "AA39", "model_path": model_path}], "settings": {**SETTINGS, **settings}}


def _compose(tmp_path, spec):
    out = [tmp_path / f"flux.{ext}" for ext in ("h5", "png", "json")]
    metrics = compose_plant(spec, *out)
    with h5py.File(out[0]) as f:
        maps = {m: f[m][()] for m in ("ideal", "calibrated")}
        spots = {m: f[f"spots/{m}"][()] for m in ("ideal", "calibrated")}
    return metrics, maps, spots, out


def test_the_field_is_every_folder_with_geometry_and_the_map_leaves_out_what_does_not_reflect():
    assert [f.name for f in plant_folders(PAINT)] == ["AA28", "AA31", "AA39", "AC43", "AD37", "AU46"]
    effects, left_out = map_effects(_spec("m.pt")["effects"] | {"soiling": {}})
    assert effects["sunshape"] == {"kind": "pillbox"} and effects["slope_error"] == {"sigma_mrad": 1.0}
    assert effects["tracking"] == effects["canting"] == effects["surface"] == {}  # each heliostat's own
    assert set(left_out) == {"camera", "soiling"}


def test_a_fit_that_found_no_error_leaves_the_plant_map_as_designed(tmp_path):
    metrics, maps, spots, out = _compose(tmp_path, _spec(_drt(tmp_path / "drt.pt")))
    peak = maps["ideal"].max()
    assert peak > 0 and np.abs(maps["ideal"] - maps["calibrated"]).max() < 1e-5 * peak  # the model's float32 pivot
    spot = metrics["design_points"]["noon"]["heliostats"]["AA39"]
    assert spot["shift_m"] < 1e-4 and spot["on_receiver_ideal_kw"] > 1.0  # ~8 m^2 of mirror, 1 kW/m^2
    assert metrics["heliostats"] == 6 and metrics["calibrated"] == ["AA39"]
    assert set(metrics["left_out"]) == {"camera"} and out[1].stat().st_size > 0


def test_a_tracking_error_moves_the_spot_by_twice_the_normal_tilt_over_the_slant_range(tmp_path):
    """A 1 mrad offset of the second joint tilts the mirror normal by 1 mrad (tests/scoring/test_plant):
    the reflected beam turns by 2 mrad, its spot moves 2 mrad x slant range on a plane square to it,
    at most 1 / cos(incidence) more on the tilted receiver. The other heliostats' spots stay."""
    metrics, maps, spots, _ = _compose(tmp_path, _spec(_drt(tmp_path / "drt.pt", (0.0, 1.0, 0.0, 0.0, 0.0))))
    spot = metrics["design_points"]["noon"]["heliostats"]["AA39"]
    tower = Tower(PAINT / "tower-measurements.json")
    pivot = read_heliostat_properties(PAINT / "AA39" / PROPERTIES_FILE, tower)[0].position
    plane = tower.receiver("receiver")
    towards = torch.as_tensor(plane.center) - pivot
    cos_incidence = float(-(normalize(towards) @ torch.as_tensor(plane.normal)))
    expected = 2e-3 * float(towards.norm())
    assert expected * 0.97 < spot["shift_m"] < expected / cos_incidence * 1.03
    assert spot["on_receiver_calibrated_kw"] == pytest.approx(spot["on_receiver_ideal_kw"], rel=0.02)
    others = maps["calibrated"][0] - spots["calibrated"][0, 0] - (maps["ideal"][0] - spots["ideal"][0, 0])
    assert np.abs(others).max() < 1e-3 * maps["ideal"].max()  # float32 maps


def _variances(image, pixel):
    """Per-axis variance (m^2) of a spot (H, W) along the receiver's right and up axes."""
    rows, cols = np.mgrid[0:image.shape[0], 0:image.shape[1]]
    out = []
    for coordinate, size in ((cols, pixel[0]), (rows, pixel[1])):
        x = (coordinate + 0.5) * size
        mean = (image * x).sum() / image.sum()
        out.append((image * (x - mean) ** 2).sum() / image.sum())
    return np.array(out)


def test_a_fitted_slope_error_of_its_own_widens_only_that_heliostats_spot(tmp_path):
    """Slope error sigma per axis turns the reflected beam by 2 sigma: the spot's variance grows by
    (2 D)^2 (sigma_own^2 - sigma_plant^2) along the receiver's horizontal axis, 1 / cos^2(incidence)
    more along its tilted vertical one; the power stays (the receiver catches it all)."""
    metrics, maps, spots, _ = _compose(tmp_path, _spec(_drt(tmp_path / "drt.pt", slope_mrad=3.0)))
    ideal, calibrated = spots["ideal"][0, 0], spots["calibrated"][0, 0]
    tower = Tower(PAINT / "tower-measurements.json")
    plane = tower.receiver("receiver")
    pivot = read_heliostat_properties(PAINT / "AA39" / PROPERTIES_FILE, tower)[0].position
    towards = torch.as_tensor(plane.center) - pivot
    cos_incidence = float(-(normalize(towards) @ torch.as_tensor(plane.normal)))
    grown = _variances(calibrated, (plane.width / 64, plane.height / 64)) - _variances(ideal, (plane.width / 64,
                                                                                             plane.height / 64))
    expected = (2 * float(towards.norm())) ** 2 * (3.0e-3**2 - 1.0e-3**2)  # 3 mrad its own, the plant's 1 mrad
    assert grown[0] == pytest.approx(expected, rel=0.15)
    assert grown[1] == pytest.approx(expected / cos_incidence**2, rel=0.15)
    assert calibrated.sum() == pytest.approx(ideal.sum(), rel=1e-3)
    spot = metrics["design_points"]["noon"]["heliostats"]["AA39"]
    assert spot["shift_m"] < 0.05
    rest = maps["calibrated"][0] - calibrated - (maps["ideal"][0] - ideal)
    assert np.abs(rest).max() < 1e-3 * maps["ideal"].max()
    assert math.isclose(metrics["summary"]["calibrated"]["power_on_receiver_kw"],
                        metrics["design_points"]["noon"]["calibrated"]["power_on_receiver_kw"])


def test_clear_errors_for_a_network_a_heliostat_without_geometry_and_a_tower_without_the_receiver(tmp_path):
    path = tmp_path / "nearest.pt"
    save_model(path, Nearest(NearestConfig(), (32, 32)), "nearest", NearestConfig(), 1.0, {})
    with pytest.raises(DataError, match="nearest.pt: a nearest model has no fitted heliostat"):
        _compose(tmp_path, _spec(str(path)))
    spec = _spec(_drt(tmp_path / "drt.pt"))
    spec["calibrated"][0]["heliostat"] = "AA23"
    with pytest.raises(DataError, match="calibrated heliostat AA23 has no folder with a heliostat-properties.json"):
        _compose(tmp_path, spec)
    copy = tmp_path / "paint"
    shutil.copytree(PAINT, copy)
    with pytest.raises(DataError, match="tower-measurements.json: no entry 'receiver_top' to draw the flux map on"):
        _compose(tmp_path, _spec(_drt(tmp_path / "drt.pt"), copy, receiver="receiver_top"))
    props = json.loads((copy / "AA28" / PROPERTIES_FILE).read_text())
    props["facet_properties"]["facets"] = props["facet_properties"]["facets"][:2]
    (copy / "AA28" / PROPERTIES_FILE).write_text(json.dumps(props))
    odd = "AA28/heliostat-properties.json: 2 facets, but the plant's other heliostats have 4"
    with pytest.raises(DataError, match=odd):
        _compose(tmp_path, _spec(_drt(tmp_path / "drt.pt"), copy))
    shutil.copy(PAINT / "AA28" / PROPERTIES_FILE, copy / "AA28" / PROPERTIES_FILE)
    tower = json.loads((copy / "tower-measurements.json").read_text())
    del tower["receiver"]["coordinates"]["receiver_outer_lower_left"]
    (copy / "tower-measurements.json").write_text(json.dumps(tower))
    with pytest.raises(DataError, match="receiver.coordinates.receiver_outer_lower_left"):
        _compose(tmp_path, _spec(_drt(tmp_path / "drt.pt"), copy))
