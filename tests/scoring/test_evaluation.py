"""evaluate_model on a tiny dataset with the `nearest` baseline, and Table 1 from metrics JSONs."""

import csv
import json

import numpy as np
import pytest

from helioflow.data.hdf5 import CalibrationDataset, write_dataset
from helioflow.errors import DataError
from helioflow.models import registry
from helioflow.models.nearest import Nearest
from helioflow.scoring import evaluation
from helioflow.scoring.evaluation import evaluate_model, grid_indices
from helioflow.scoring.metrics import PSNR_MAX_DB
from helioflow.scoring.table import build_table

# sun elevation rises with the index; the two highest (and brightest) images are extrapolation
SPLIT = ["train", "interpolation", "train", "train", "interpolation", "train", "train", "interpolation", "train",
         "train", "extrapolation", "extrapolation"]
METRIC_KEYS = {"psnr", "ssim", "centroid_mrad", "flux_accuracy", "n"}


def tiny_dataset(path, n=12, size=16):
    """Gaussian spots that move and brighten with elevation; the brightest image is in the
    extrapolation split, so the dataset's maximum exceeds the model's (train) scale."""
    rng = np.random.default_rng(0)
    r, c = np.mgrid[0:size, 0:size]
    elevation = np.linspace(10, 80, n)
    images = []
    for i, el in enumerate(elevation):
        row, col = 4 + 8 * i / n, 6 + 4 * np.sin(i)
        images.append((500 + 10 * el) * np.exp(-((r - row) ** 2 + (c - col) ** 2) / 6.0))
    images = np.asarray(images) + rng.uniform(0, 5, (n, size, size))
    write_dataset(path, CalibrationDataset(
        images=images.astype(np.float32), azimuth_deg=np.linspace(-40, 40, n), elevation_deg=elevation,
        split=np.array(SPLIT[:n]),
        attrs={"dataset": "toy", "target_size_m": [2.0, 2.0], "target_center_m": [0.0, 0.0, 20.0],
               "heliostat_position_m": [0.0, 60.0, 0.0]}))


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("eval")
    tiny_dataset(tmp / "toy.h5")
    registry.train_network("nearest", {}, tmp / "toy.h5", tmp / "nearest.pt", tmp / "curve.csv",
                           tmp / "curve.png", seed=0, progress=False)
    return tmp


def outputs(tmp, stem):
    return [tmp / f"{stem}.json", tmp / f"{stem}.csv", tmp / f"{stem}_grid.png", tmp / f"{stem}_psnr.png"]


def test_evaluate_nearest(trained):
    outs = outputs(trained, "nearest_toy")
    result = evaluate_model(trained / "nearest.pt", trained / "toy.h5", *outs)
    written = json.loads(outs[0].read_text())
    assert written == result
    assert {"network", "dataset", "controllable", "splits"} <= set(written)
    assert (written["network"], written["dataset"], written["controllable"]) == ("nearest", "toy", True)
    assert set(written["splits"]) == {"train", "interpolation", "extrapolation"}
    for entry in written["splits"].values():
        assert set(entry) == METRIC_KEYS
    train, interp = written["splits"]["train"], written["splits"]["interpolation"]
    assert sum(s["n"] for s in written["splits"].values()) == 12
    # nearest returns the training image itself: exact up to float round-off, on the dataset's scale
    assert train["psnr"] == pytest.approx(PSNR_MAX_DB)
    assert train["ssim"] == pytest.approx(1.0)
    assert train["flux_accuracy"] == pytest.approx(1.0, abs=1e-5)
    assert train["centroid_mrad"] == pytest.approx(0.0, abs=1e-3)
    assert 5 < interp["psnr"] < 60 and interp["centroid_mrad"] > 0
    assert "note" not in written
    assert written["dataset_max_w_m2"] > written["model_scale_w_m2"]  # the rescale to the dataset's max is tested

    with open(outs[1], newline="") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 12
    assert list(rows[0]) == ["index", "azimuth_deg", "elevation_deg", "split", "psnr", "ssim", "centroid_mrad",
                             "flux_accuracy"]
    interp_psnr = [float(r["psnr"]) for r in rows if r["split"] == "interpolation"]
    assert np.mean(interp_psnr) == pytest.approx(interp["psnr"], rel=1e-6)
    for png in outs[2:]:
        assert png.stat().st_size > 1000
    assert not list(trained.glob(".*.tmp*"))


class Unconditioned(Nearest):
    """A stand-in for the GAN: ignores the sun position and returns its training images in turn."""

    controllable = False

    def predict(self, azimuth_deg, elevation_deg, generator):
        return self.images[np.arange(len(azimuth_deg)) % len(self.images)]


def test_unconditioned_model_scored_by_best_sample(trained, monkeypatch):
    nearest, info = registry.load_model(trained / "nearest.pt")
    model = Unconditioned(nearest.config, nearest.image_shape)
    model.load_state_dict(nearest.state_dict())
    monkeypatch.setattr(evaluation, "load_model", lambda path, device="cpu": (model, dict(info, network="gan")))
    result = evaluate_model(trained / "nearest.pt", trained / "toy.h5", *outputs(trained, "gan_toy"), gan_samples=8)
    assert result["controllable"] is False and result["samples"] == 8 and "best" in result["note"]
    # all 6 training images are among the 8 samples, so each train image finds itself
    assert result["splits"]["train"]["psnr"] == pytest.approx(PSNR_MAX_DB)


def test_image_shape_mismatch_is_a_data_error(trained, tmp_path):
    tiny_dataset(tmp_path / "small.h5", size=8)
    with pytest.raises(DataError, match="16x16.*8x8"):
        evaluate_model(trained / "nearest.pt", tmp_path / "small.h5", *outputs(tmp_path, "x"))
    assert not (tmp_path / "x.json").exists()


def test_grid_spreads_over_interpolation_and_extrapolation(trained):
    from helioflow.data.hdf5 import read_dataset

    ds = read_dataset(trained / "toy.h5")
    pick = grid_indices(ds, columns=8)
    assert sorted(set(ds.split[pick])) == ["extrapolation", "interpolation"]
    assert len(pick) == len(ds.indices("interpolation")) + len(ds.indices("extrapolation"))


def metrics_json(path, network, dataset, psnr, ssim, controllable=True, samples=None):
    splits = {s: {"psnr": p, "ssim": q, "centroid_mrad": None if p is None else 0.1, "flux_accuracy": None
                  if p is None else 0.9, "n": 0 if p is None else 5}
              for s, p, q in zip(("train", "interpolation", "extrapolation"), psnr, ssim)}
    data = {"network": network, "dataset": dataset, "controllable": controllable, "splits": splits}
    if samples:
        data["samples"] = samples
    path.write_text(json.dumps(data))
    return path


def test_build_table(tmp_path):
    paths = [
        metrics_json(tmp_path / "a.json", "gan", "toy", [22.04, 18.96, 17.5], [0.5, 0.41234, 0.4], False, 64),
        metrics_json(tmp_path / "b.json", "zeta", "toy", [30.0, 29.0, 28.0], [0.9, 0.8, 0.7]),
        metrics_json(tmp_path / "c.json", "nearest", "toy", [100.0, 31.25, None], [1.0, 0.9876, None]),
        metrics_json(tmp_path / "d.json", "nerf", "toy", [40.0, 35.55, 30.0], [0.99, 0.95, 0.9]),
    ]
    rows = build_table(paths, tmp_path / "table.csv", tmp_path / "table.md")
    assert [r["network"] for r in rows] == ["nearest", "gan", "nerf", "zeta"]
    md = (tmp_path / "table.md").read_text().splitlines()
    assert "PSNR" in md[0] and "best of 64" in md[0]
    assert md[2] == ("| network | dataset | controllable | PSNR train | PSNR interp. | PSNR extrap. "
                     "| SSIM train | SSIM interp. | SSIM extrap. |")
    assert md[4] == "| nearest | toy | yes | 100.0 | 31.2 | – | 1.000 | 0.988 | – |"
    assert md[5] == "| gan | toy | no (best of 64 samples) | 22.0 | 19.0 | 17.5 | 0.500 | 0.412 | 0.400 |"
    assert md[6].startswith("| nerf | toy | yes | 40.0 | 35.5")
    with open(tmp_path / "table.csv", newline="") as f:
        table = list(csv.DictReader(f))
    assert table[0]["psnr_extrapolation"] == "" and float(table[0]["psnr_interpolation"]) == 31.25

    with pytest.raises(DataError, match="both hold"):
        build_table(paths + [paths[0]], tmp_path / "t2.csv", tmp_path / "t2.md")
    (tmp_path / "bad.json").write_text("{}")
    with pytest.raises(DataError, match="bad.json"):
        build_table([tmp_path / "bad.json"], tmp_path / "t3.csv", tmp_path / "t3.md")
