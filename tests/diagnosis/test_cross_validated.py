"""A dataset that holds no images out (a real heliostat's few calibration images) is diagnosed by
cross-validation over all of them: a hidden tracking error on six images is named, and nothing is
named when the model holds it."""

import pytest
import torch

from helioflow.diagnosis.diagnose import CrossValidated, cross_validation_folds
from helioflow.models.physics_fit import FitSettings, Measurements
from helioflow.physics.heliostat import ideal_heliostat
from helioflow.physics.scene import Scene
from helioflow.physics.target import Target

BUIE = {"kind": "buie", "csr": 0.1}
TRACKING = {"axis1_offset_mrad": 2.0, "pedestal_tilt_east_mrad": -1.5}
TRIED = ("tracking", "slope_error", "canting", "soiling")


def cross_validated(world: dict, model: dict) -> CrossValidated:
    """Six 8-bit images of a 2 x 2-facet heliostat in `world` (sun positions over a day, 2 % noise),
    diagnosed against `model` by cross-validation (four folds), with a few candidates."""
    h = ideal_heliostat(rows=2, cols=2, width=1.0, height=1.0, gap=0.05, position=(0.0, 60.0, 0.0),
                        control_points=5, dtype=torch.float32)
    target = Target(torch.tensor([0.0, 0.0, 20.0]), torch.tensor([0.0, 1.0, 0.0]), 4.0, 4.0, (32, 32))
    az, el = torch.tensor([-70.0, -40.0, -10.0, 15.0, 45.0, 75.0]), torch.tensor([25.0, 45.0, 60.0, 62.0, 48.0, 30.0])
    with torch.no_grad():
        images = Scene(h, target, 1000.0, cells_per_side=8).simulate(world, {}, az, el)
    images = images / images.amax((-2, -1), keepdim=True)
    images = (images + 0.02 * torch.randn(images.shape, generator=torch.Generator().manual_seed(7))).clamp(0, 1)
    images = (images * 255).round() / 255
    d = CrossValidated(Scene(h, target, 1000.0, cells_per_side=8), model, Measurements(images, az, el, 1.0),
                       cross_validation_folds(len(az)), FitSettings(steps=30, rounds=1, search_iterations=6))
    d.tried = [c for c in d.tried if c.label in TRIED]
    return d


@pytest.mark.slow
def test_a_tracking_error_on_six_images_is_named_by_cross_validation_and_nothing_when_the_model_has_it():
    hidden = cross_validated({"sunshape": BUIE, "tracking": TRACKING}, {"sunshape": BUIE})
    ranked = hidden.rank()
    assert ranked.selected == ["tracking"], [(r["effect"], round(r["relative_reduction"], 3)) for r in ranked.entries]
    assert ranked.entries[0]["relative_reduction"] >= 0.5
    assert len(hidden.folds) == 4 and sum(len(f.heldout.images) for f in hidden.folds) == 6  # each image once
    held = cross_validated({"sunshape": BUIE, "tracking": TRACKING}, {"sunshape": BUIE, "tracking": TRACKING})
    ranked = held.rank()
    assert ranked.selected == [], [(r["effect"], round(r["relative_reduction"], 3)) for r in ranked.entries]
    assert held.remaining([])["explained"], held.remaining([])
