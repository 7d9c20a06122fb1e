"""drt's freedom on few images (models/freedom.py): the simplest nested level whose held-out error,
by leave-one-out over the training images, is within one standard error of the best; one image
keeps the design; the choice travels with the model file and the fitted heliostat says what stayed
at the design."""

from pathlib import Path

import pytest
import torch

from helioflow.data.paint import import_paint
from helioflow.errors import ConfigError
from helioflow.models.freedom import FREEDOMS, choose_freedom
from helioflow.models.physical import DrtConfig
from helioflow.models.physics_fit import FitResult, Measurements
from helioflow.models.registry import load_model, train_network
from helioflow.scoring.fitted_heliostat import fitted_heliostat

PAINT = Path(__file__).resolve().parents[1] / "data" / "paint"
EFFECTS = {"sunshape": {"kind": "buie", "csr": "fit"}, "camera": {"gain": "fit", "background_w_m2": "fit",
                                                                  "blur_px": 0.0}}


def _spot(centre: float, n: int = 16) -> torch.Tensor:
    """(n, n) a Gaussian spot at column `centre`."""
    y, x = torch.meshgrid(torch.arange(n, dtype=torch.float64), torch.arange(n, dtype=torch.float64), indexing="ij")
    return torch.exp(-((x - centre) ** 2 + (y - 7.5) ** 2) / 8.0)


def _choice(errors: dict[str, list[float]]):
    """choose_freedom on 3 images at centre 7.5, where level k predicts image i shifted by
    errors[k][i] pixels (its held-out misplaced flux grows with the shift)."""
    images = torch.stack([_spot(7.5)] * 3)
    data = Measurements(images, torch.tensor([0.0, 10.0, 20.0]), torch.tensor([30.0, 40.0, 50.0]), 1.0)
    levels = {k: {"level": k} for k in errors}
    seen = []

    def fit(effects, subset, start):
        seen.append((effects["level"], len(subset.images), None if start is None else start.effects["level"]))
        return FitResult(effects, {})

    def predict(result, azimuth, elevation):
        i = int(azimuth[0] // 10)
        return _spot(7.5 + errors[result.effects["level"]][i])[None]

    return choose_freedom(levels, data, fit, predict), seen


def test_a_freer_level_is_taken_only_when_it_predicts_the_left_out_images_better_beyond_the_scatter():
    choice, seen = _choice({"design": [3.0, 3.0, 3.0], "tracking": [0.5, 0.5, 0.5], "full": [0.4, 0.6, 0.5]})
    assert choice.chosen == "tracking"  # full is no better than tracking: the simpler one
    assert [len(v) for v in choice.scores.values()] == [3, 3, 3]
    assert seen[:3] == [("design", 2, None), ("tracking", 2, "design"), ("full", 2, "tracking")]  # nested, 2 of 3
    assert "leave-one-out over the 3 training images" in choice.reason
    choice, _ = _choice({"design": [3.0, 3.0, 3.0], "tracking": [2.0, 2.0, 2.0], "full": [0.1, 0.1, 0.1]})
    assert choice.chosen == "full"
    choice, _ = _choice({"design": [1.0, 1.1, 0.9], "tracking": [0.5, 3.0, 0.5], "full": [4.0, 0.2, 4.0]})
    assert choice.chosen == "design"  # the runaway: a freer fit that predicts worse somewhere is not earned


def test_one_training_image_keeps_the_design():
    data = Measurements(_spot(7.5)[None], torch.tensor([0.0]), torch.tensor([30.0]), 1.0)
    choice = choose_freedom({k: {} for k in FREEDOMS}, data, None, None)
    assert choice.chosen == "design" and "one training image" in choice.reason and choice.scores == {}


def test_an_unknown_freedom_is_a_config_error():
    with pytest.raises(ConfigError, match="freedom = 'surface': expected one of auto, design, tracking, canting, full"):
        DrtConfig(freedom="surface")


@pytest.fixture(scope="module")
def lower(tmp_path_factory):
    """AA39's 5 images on the lower target at 16 x 16, three held out: 2 training images."""
    root = tmp_path_factory.mktemp("lower")
    import_paint(PAINT, "AA39", root / "lower.h5", root / "AA39.h5", resolution=(16, 16),
                 holdout=["209075", "223788", "246955"], targets=["solar_tower_juelich_lower"])
    return root


def test_drt_on_two_real_images_chooses_its_freedom_and_the_written_heliostat_says_what_stayed_at_the_design(lower):
    settings = {"effects": EFFECTS, "heliostat_path": str(lower / "AA39.h5"), "fit_steps": 2, "rounds": 1,
                "cells_per_side": 4, "gauss_newton_steps": 0}
    train_network("drt", settings, lower / "lower.h5", lower / "drt.pt", lower / "drt.csv", lower / "drt.png",
                  seed=1, progress=False)
    model, _ = load_model(lower / "drt.pt")
    choice = model.freedom
    assert choice.chosen in FREEDOMS and list(choice.scores) == list(FREEDOMS)  # 4 facets: every level
    assert all(len(v) == 2 for v in choice.scores.values())
    freed = {"design": set(), "tracking": {"tracking"}, "canting": {"tracking", "canting"},
             "full": {"tracking", "canting", "surface"}}[choice.chosen]
    assert set(model.fitted.tensors) == freed
    assert model.fitted.uncertainty.refits == 2  # its sigma at least the spread of the chosen level's 2 refits
    written = fitted_heliostat(lower / "drt.pt")
    assert written["freedom"]["chosen"] == choice.chosen
    kept = ({"tracking", "canting", "surface", "slope error"} - freed
            - ({"slope error"} if choice.chosen == "full" else set()))
    assert set(written["at_design"]) == kept
    assert ("tracking_mrad" in written) == ("tracking" in freed)
