"""What a fitted drt model recovered of a synthetic heliostat: a model holding the true errors
recovers them exactly; a known offset shows up as that error and as lost PSNR against the true
heliostat in the same model; a network has nothing to compare."""

import json
from pathlib import Path

import pytest

from helioflow.cli import main
from helioflow.config import load_config
from helioflow.data.hdf5 import read_dataset
from helioflow.data.surfaces import HeliostatSpec, read_heliostat, true_heliostat, write_heliostat
from helioflow.data.synthetic import trace_dataset
from helioflow.errors import DataError
from helioflow.models.nearest import Nearest, NearestConfig
from helioflow.models.physical import DrtConfig, DrtModel
from helioflow.models.physics_fit import FitResult
from helioflow.models.registry import dataset_geometry, save_model
from helioflow.scoring.recovery import recovery
from helioflow.workflow import surfaces_params, trace_params

TINY = Path(__file__).resolve().parents[1] / "workflow" / "tiny_config.yaml"


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """(heliostat file, dataset file) of the tiny config's heliostat `small` and dataset `scan`."""
    config = load_config(TINY)
    directory = tmp_path_factory.mktemp("recovery")
    params = surfaces_params(config, "small")
    spec = HeliostatSpec.from_config(params.pop("name"), params)
    heliostat = directory / "small.h5"
    write_heliostat(heliostat, true_heliostat(spec), spec)
    dataset = directory / "scan.h5"
    trace_dataset(trace_params(config, "scan"), heliostat, dataset)
    return heliostat, dataset


def _drt_file(path, files, tracking_offset_mrad: float, surface_factor: float = 1.0, slope_mrad: float = 0.7):
    """A drt model file on `files` (heliostat, dataset) whose fitted tensors are the true ones,
    tracking parameter 0 offset and the control heights scaled by `surface_factor`, with a fitted
    slope error of `slope_mrad`; it traces the dataset's target at the dataset's resolution with the
    dataset's own 8 cells per side."""
    heliostat_path, dataset_path = files
    true = read_heliostat(heliostat_path)
    ds = read_dataset(dataset_path)
    model = DrtModel(DrtConfig(effects={"sunshape": {"kind": "pillbox"}}, heliostat_path=str(heliostat_path),
                                   cells_per_side=8, **dataset_geometry("drt", ds.attrs)), tuple(ds.images.shape[1:]))
    model.heliostat = true.ideal().to("cpu")
    tracking = (true.tracking_error * 1e3).float()
    tracking[0] += tracking_offset_mrad
    model.fitted = FitResult({"sunshape": {"kind": "pillbox"}, "slope_error": {"sigma_mrad": slope_mrad}},
                             {"tracking": tracking, "surface": (true.control_heights * 1e3 * surface_factor).float()})
    save_model(path, model, "drt", model.config, 1.0, {})
    return path


def test_a_model_holding_the_true_errors_recovers_them_exactly(files, tmp_path):
    heliostat, dataset = files
    out = recovery(_drt_file(tmp_path / "drt.pt", files, 0.0), heliostat, dataset)
    assert out["tracking_mrad"]["max_error"] < 1e-4
    assert out["pointing_error_mrad"]["max"] < 1e-3
    assert out["surface_mm"]["rms_error_over_rms_true"] < 1e-4 and out["surface_mm"]["correlation"] > 0.9999
    assert out["slope_error_mrad"]["fitted"] == 0.7


def test_a_tracking_offset_shows_as_that_error_and_a_pointing_error(files, tmp_path):
    heliostat, dataset = files
    out = recovery(_drt_file(tmp_path / "drt.pt", files, 0.5), heliostat, dataset)
    assert out["tracking_mrad"]["max_error"] == pytest.approx(0.5, abs=1e-4)
    assert 0.05 < out["pointing_error_mrad"]["rms"] <= 0.5 + 1e-6  # a joint offset turns the normal by at most itself


@pytest.mark.parametrize("factor", [0.0, 0.5, 2.0])
def test_a_scaled_surface_misses_the_true_heights_by_the_scale(files, tmp_path, factor):
    """Heights are linear in the control heights: fitted = factor * true misses by |1 - factor| of
    the amplitude, on the whole surface and on every facet alike (correlation 1 unless flat)."""
    heliostat, dataset = files
    out = recovery(_drt_file(tmp_path / "drt.pt", files, 0.0, factor), heliostat, dataset)["surface_mm"]
    assert out["rms_error_over_rms_true"] == pytest.approx(abs(1.0 - factor), abs=1e-4)
    if factor:
        assert out["correlation"] > 0.9999 and min(out["facet_correlation"]) > 0.9999
    else:  # a flat surface has no correlation: null in the JSON, not NaN
        assert out["correlation"] is None and out["facet_correlation"] == [None]


def test_the_true_heliostat_in_the_model_scores_what_a_perfect_recovery_would(files, tmp_path):
    """psnr_db: the world of `scan` is the model (pillbox sun, slope error 0.5 mrad, the dataset's kernel
    trace), so the true heliostat in it reproduces every image (PSNR capped at 100 dB), and so does a fit
    that holds the true errors; a tracking offset and a wrong slope error cost PSNR on every split, while
    the true heliostat (with the world's slope error, not the fit's) still scores 100 dB."""
    heliostat, dataset = files
    exact = recovery(_drt_file(tmp_path / "a.pt", files, 0.0, slope_mrad=0.5), heliostat, dataset)["psnr_db"]
    offset = recovery(_drt_file(tmp_path / "b.pt", files, 0.5, slope_mrad=0.7), heliostat, dataset)["psnr_db"]
    perfect = {"train": 100.0, "interpolation": 100.0, "extrapolation": 100.0}
    assert exact == {"fitted": perfect, "true_heliostat": perfect}
    assert offset["true_heliostat"] == perfect and all(offset["fitted"][s] < 40.0 for s in perfect)


def test_the_rule_writes_the_comparison_with_its_inputs_named(files, tmp_path):
    """Rule `recovery` (helioflow recovery --output): the JSON file, whole: what the command prints."""
    heliostat, dataset = files
    model = _drt_file(tmp_path / "drt.pt", files, 0.5)
    out = tmp_path / "recovery" / "scan.json"
    assert main(["recovery", "--model", str(model), "--heliostat", str(heliostat), "--dataset", str(dataset),
                 "--output", str(out)]) == 0
    written = json.loads(out.read_text())
    assert written == recovery(model, heliostat, dataset)
    assert written["tracking_mrad"]["max_error"] == pytest.approx(0.5, abs=1e-4)
    assert [p.name for p in out.parent.iterdir()] == ["scan.json"]  # no temporary left


def test_a_network_has_no_heliostat_to_compare(files, tmp_path):
    heliostat, dataset = files
    path = tmp_path / "nearest.pt"
    save_model(path, Nearest(NearestConfig(), (32, 32)), "nearest", NearestConfig(), 1.0, {})
    with pytest.raises(DataError, match="nearest.pt: a nearest model has no fitted heliostat tensors"):
        recovery(path, heliostat, dataset)
