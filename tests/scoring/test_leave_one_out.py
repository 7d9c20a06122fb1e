"""Rule `leave_one_out`: held-out scores per image and network from the fold datasets, models and
per-image metrics, and a figure; a fold that does not hold out exactly one image is an error."""

import csv
import json
from pathlib import Path

import numpy as np
import pytest

from helioflow.cli import main
from helioflow.data.hdf5 import read_dataset
from helioflow.data.paint import import_paint
from helioflow.errors import DataError
from helioflow.models.registry import train_network
from helioflow.scoring.evaluation import evaluate_model
from helioflow.scoring.leave_one_out import COLUMNS, held_out_index, leave_one_out

PAINT = Path(__file__).resolve().parents[1] / "data" / "paint"
IDS = ["270398", "275564"]


@pytest.fixture(scope="module")
def folds(tmp_path_factory):
    """Two folds of AA39's multi-focus images at 16 x 16 with the nearest baseline trained and scored."""
    root = tmp_path_factory.mktemp("loo")
    out = {"datasets": [], "model_nearest": [], "metrics_nearest": []}
    for mid in IDS:
        ds, model, metrics = root / f"aa39_loo_{mid}.h5", root / f"{mid}.pt", root / f"{mid}.csv"
        import_paint(PAINT, "AA39", ds, resolution=(16, 16), holdout=[mid], targets=["multi_focus_tower"])
        train_network("nearest", {}, ds, model, root / f"{mid}_curve.csv", root / f"{mid}_curve.png", seed=0,
                      progress=False)
        evaluate_model(model, ds, root / f"{mid}.json", metrics, root / f"{mid}_grid.png", root / f"{mid}_psnr.png")
        for key, path in zip(out, (ds, model, metrics)):
            out[key].append(str(path))
    return root, out


def test_scores_each_held_out_image_as_evaluate_did_and_adds_the_misplaced_flux(folds):
    root, inputs = folds
    rows = leave_one_out(inputs["datasets"], {"nearest": inputs["model_nearest"]},
                         {"nearest": inputs["metrics_nearest"]}, root / "aa39.csv", root / "aa39.png")
    assert [r["id"] for r in rows] == IDS and {r["network"] for r in rows} == {"nearest"}
    for row, metrics in zip(rows, inputs["metrics_nearest"]):
        ds = read_dataset(root / f"{row['dataset']}.h5")
        i = held_out_index(ds, row["dataset"])
        evaluated = next(r for r in csv.DictReader(Path(metrics).read_text().splitlines()) if r["index"] == str(i))
        assert row["psnr"] == pytest.approx(float(evaluated["psnr"]))
        assert row["split"] == ds.split[i] != "train" and 0.0 < row["misplaced_flux"] < 1.0
    with open(root / "aa39.csv") as f:
        written = list(csv.DictReader(f))
    assert tuple(written[0]) == COLUMNS and len(written) == 2
    assert (root / "aa39.png").stat().st_size > 0


def test_the_cli_takes_the_rules_inputs(folds):
    root, inputs = folds
    assert main(["leave-one-out", "--inputs", json.dumps(inputs), "--csv", str(root / "cli.csv"),
                 "--figure", str(root / "cli.png")]) == 0
    lines = (root / "cli.csv").read_text().splitlines()
    assert lines[0] == ",".join(COLUMNS) and [line.split(",")[1] for line in lines[1:]] == IDS


def test_a_fold_must_hold_out_exactly_one_image(tmp_path):
    ds = import_paint(PAINT, "AA39", tmp_path / "two.h5", resolution=(16, 16), holdout=["extra1", "extra3"])
    with pytest.raises(DataError, match="two.h5: a leave-one-out fold holds out exactly one image; this one "
                                        "holds out 2"):
        held_out_index(ds, tmp_path / "two.h5")
    ds.split = np.full(len(ds.split), "train")
    with pytest.raises(DataError, match="holds out 0"):
        held_out_index(ds, "none.h5")
