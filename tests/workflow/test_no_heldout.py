"""Datasets that hold no images out (docs/data.md: own images without splits or holdout, a PAINT
dataset without holdout: every image trains) run `snakemake -j2 all` to the end; the diagnosis
scores its candidates by cross-validation over the images, and says so."""

import json
import shutil

import numpy as np
from support.pipeline import REPO, _tiny, _workdir, snakemake

from helioflow.data.hdf5 import CalibrationDataset, read_dataset
from helioflow.diagnosis.diagnose import cross_validation_folds, scoring_split

PAINT = REPO / "tests" / "data" / "paint"
OWN = REPO / "examples" / "own_images"


def _dataset(splits: list[str]) -> CalibrationDataset:
    n = len(splits)
    return CalibrationDataset(np.ones((n, 4, 4), np.float32), np.zeros(n), np.full(n, 40.0), np.array(splits))


def test_the_diagnosis_scores_on_the_held_out_splits_or_cross_validates_over_the_training_images():
    fit, scored, info = scoring_split(_dataset(["train", "interpolation", "train", "extrapolation"]))
    assert fit.tolist() == [0, 2] and scored.tolist() == [1, 3] and info["note"] == ""
    fit, scored, info = scoring_split(_dataset(["train"] * 9))
    assert fit.tolist() == list(range(9)) and scored.tolist() == []
    assert info["source"] == "4-fold cross-validation" and "fitted 4 times" in info["note"]
    for n in (2, 3, 7, 9):  # every image held out exactly once, no fold empty
        folds = cross_validation_folds(n)
        assert len(folds) == min(4, n) and all(len(f) for f in folds)
        assert sorted(np.concatenate(folds).tolist()) == list(range(n))
    fit, scored, info = scoring_split(_dataset(["train"]))
    assert fit.tolist() == scored.tolist() == [0] and "training error" in info["note"]


def test_a_paint_and_an_images_dataset_without_held_out_images_run_all_to_the_end(tmp_path):
    config = _tiny()
    config["datasets"] = {
        "real": {"source": "paint", "paint_dir": str(PAINT), "heliostat": "AA39", "resolution": [16, 16]},
        "own": {"source": "images", "images_dir": str(OWN / "images"), "csv": str(OWN / "calibration.csv"),
                "site": {"latitude_deg": 50.9134, "longitude_deg": 6.3868, "altitude_m": 87.0},
                "resolution": [16, 16],
                "target": {"center_m": [0.0, 0.0, 20.0], "normal": [0.0, 1.0, 0.0], "width_m": 4.0, "height_m": 4.0},
                "heliostat": {"position_m": [0.0, 60.0, 0.0], "mount": "az_el",
                              "facets": {"rows": 1, "cols": 1, "width_m": 2.0, "height_m": 2.0}}},
    }
    config["model"] = {"effects": {"sunshape": {"kind": "gaussian", "sigma_mrad": 2.5}}}
    config["networks"] = {"nearest": {}, "raytrace": {"fit_steps": 2, "rounds": 1, "fit_images": 4,
                                                      "cells_per_side": 4}}
    config["diagnosis"] = {"fit_images": 3, "heldout_images": 2, "fit_steps": 2, "rounds": 1, "cells_per_side": 4,
                           "max_effects": 1}
    workdir = _workdir(tmp_path / "run", config)
    proc = snakemake(workdir, "-j2", "all", timeout=600)
    assert proc.returncode == 0, proc.stderr[-4000:]
    for dataset in ("real", "own"):
        images = len(read_dataset(workdir / f"results/tiny/datasets/{dataset}.h5").images)
        result = json.loads((workdir / f"results/tiny/diagnosis/{dataset}.json").read_text())
        assert result["heldout"] == {"source": "3-fold cross-validation", "images": 3,  # diagnosis.fit_images
                                     "note": result["heldout"]["note"]}
        assert result["verdict"].startswith(f"The dataset holds no images out (every image trains the networks), so "
                                            f"the diagnosis cross-validates over 3 of its {images} images")
    counts = {d: len(read_dataset(workdir / f"results/tiny/datasets/{d}.h5").images) for d in ("real", "own")}
    assert counts == {"real": 12, "own": 12}  # AA39's 12 measurements, 6 of them centered-only
    assert (workdir / "results/tiny/report.html").is_file()
    shutil.rmtree(workdir / "results")
