"""The physics models on imported PAINT data: per-image normalised real images are fitted by shape
and predicted peak-normalised; drt runs through the real training path on a tiny PAINT dataset."""

from pathlib import Path

import pytest
import torch

from helioflow.data.paint import import_paint
from helioflow.models.registry import load_model, train_network

PAINT = Path(__file__).resolve().parents[1] / "data" / "paint"
EFFECTS = {"sunshape": {"kind": "buie", "csr": "fit"}, "camera": {"gain": "fit", "background_w_m2": "fit",
                                                                  "blur_px": 0.0}}


@pytest.fixture(scope="module")
def aa39(tmp_path_factory):
    """AA39's images on the multi-focus tower at 16 x 16, extra1 held out, and its ideal geometry."""
    root = tmp_path_factory.mktemp("aa39")
    import_paint(PAINT, "AA39", root / "aa39.h5", root / "AA39.h5", resolution=(16, 16), holdout=["extra1"],
                 targets=["multi_focus_tower"], dni_w_m2=900.0)
    return root


def test_a_paint_dataset_has_the_attributes_a_physics_model_reads(aa39):
    from helioflow.data.hdf5 import read_dataset

    attrs = read_dataset(aa39 / "aa39.h5").attrs
    assert attrs["dni_w_m2"] == 900.0 and attrs["per_image_normalised"] is True
    assert len(attrs["target_center_m"]) == 3 and len(attrs["target_normal"]) == 3
    assert len(attrs["target_size_m"]) == 2 and "trace" not in attrs  # no trace settings: kernel splatting


def test_drt_fits_a_tiny_paint_dataset_in_two_steps_and_predicts_peak_normalised_spots(aa39):
    settings = {"effects": EFFECTS, "heliostat_path": str(aa39 / "AA39.h5"), "fit_steps": 2, "rounds": 1,
                "cells_per_side": 4}
    model = train_network("drt", settings, aa39 / "aa39.h5", aa39 / "drt.pt", aa39 / "drt.csv", aa39 / "drt.png",
                          seed=1, progress=False)
    assert model.config.per_image_normalised and model.config.target_size_m[0] > 5.0  # from the dataset
    assert model.config.dni_w_m2 == 900.0
    assert set(model.fitted.tensors) == {"tracking", "canting", "surface"}
    assert not (aa39 / "drt.pt.fit.ckpt").exists()  # the fit's checkpoint goes once the model is written
    # the rigid descent and the full one, two traces each, then the final loss
    assert len(model.curve) == 2 + 2 + 1 and all(torch.isfinite(torch.tensor([r["loss"] for r in model.curve])))
    loaded, info = load_model(aa39 / "drt.pt")
    with torch.no_grad():
        pred = loaded.predict(torch.tensor([-85.3, 31.9]), torch.tensor([27.8, 58.8]), torch.Generator())
    assert pred.shape == (2, 16, 16)
    peaks = pred.amax((-2, -1)) * info["scale"]  # each image peaks at 1, as PAINT's PNGs do
    assert torch.allclose(peaks, torch.ones(2), atol=1e-5)
