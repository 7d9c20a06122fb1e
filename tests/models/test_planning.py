"""The next images (models/planning.py): the sigma `plan` expects after an image is the sigma the fit
reports once the image is taken, a targeted plan shrinks its targets at least as much as the
information-gain plan, and the sun path has the sun where it should be."""

from datetime import datetime, timezone

import numpy as np
import pytest
import torch
from support.fit_scenes import BUIE, TRACKING, noisy, scene, suns

from helioflow.models.physics_fit import (
    FitSettings,
    Measurements,
    fit_effects,
    initial_tensors,
    with_uncertainty,
)
from helioflow.models.planning import canonical_correlation, image_information, plan, sun_path
from helioflow.models.uncertainty import FitUncertainty, end_state, predicted_spread

TRUTH = {"tracking": torch.tensor([0.8, -0.5, 0.3, -0.6, 0.4])}
WORLD = {"sunshape": BUIE, "slope_error": {"sigma_mrad": 1.5}, "tracking": {}}
MODEL = {"sunshape": BUIE, "slope_error": {"sigma_mrad": "fit"}, "tracking": TRACKING}


def images(s, az, el, scale=None, seed=0):
    with torch.no_grad():
        clean = s.simulate(WORLD, TRUTH, az, el)
    scale = scale or float(clean.max())
    return Measurements(noisy(clean / scale, seed), az, el, scale)


@pytest.mark.slow
def test_the_sigma_a_plan_expects_is_the_sigma_of_the_refit_with_the_picked_image():
    s = scene()
    az, el = suns(6, 3)  # a narrow start: 6 images, two azimuths
    taken = images(s, az[:6], el[:6])
    settings = FitSettings(steps=60, rounds=2, gauss_newton_steps=3, search_iterations=20)
    fit = with_uncertainty(s, fit_effects(s, MODEL, taken, settings), taken, "absolute")
    grid_az, grid_el = (torch.tensor(v, dtype=torch.float32) for v in zip(*[(a, e) for a in (-80.0, -20.0, 40.0, 90.0)
                                                                              for e in (15.0, 40.0, 70.0)]))
    _, masks = initial_tensors(fit.effects, s.heliostat)
    state = end_state(s, fit, grid_az, grid_el, taken.scale, "absolute", masks)
    information = image_information(state, fit.fitted, masks, fit.uncertainty)
    picks = plan(information, fit.uncertainty, 3)
    assert len({p.index for p in picks}) == 3
    assert all(np.all(p.sigma_after <= fit.uncertainty.sigma * 1.0001) for p in picks)
    chosen = torch.tensor([p.index for p in picks])
    more = images(s, torch.cat((az[:6], grid_az[chosen])), torch.cat((el[:6], grid_el[chosen])), taken.scale)
    refit = with_uncertainty(s, fit_effects(s, MODEL, more, settings, start=fit), more, "absolute")
    ratio = refit.uncertainty.sigma / picks[-1].sigma_after
    assert np.all(ratio > 0.6) and np.all(ratio < 1.6), (refit.uncertainty.sigma, picks[-1].sigma_after)
    # a plan targeted at one parameter shrinks it at least as much as the information-gain plan
    target = "tracking.pedestal_tilt_north_mrad"
    k = fit.uncertainty.index(target)
    targeted = plan(information, fit.uncertainty, 3, "targets", targets=[target])
    assert targeted[-1].sigma_after[k] <= picks[-1].sigma_after[k] * 1.0001
    # the image that makes the centroids predicted at two far sun positions surest (one pick: the
    # greedy choice is the best single image) does so at least as well as the information gain's
    far = end_state(s, fit, torch.tensor([-100.0, 100.0]), torch.tensor([20.0, 20.0]), taken.scale, "absolute", masks)
    g = predicted_spread(far, fit.fitted, masks, fit.uncertainty)["centroid_jacobian"].flatten(0, 1).numpy()

    def predicted_variance(pick) -> float:  # mrad^2, summed over the 4 centroid coordinates
        after = np.linalg.pinv(np.linalg.pinv(fit.uncertainty.covariance) + information[pick.index].numpy())
        return float(np.trace(g @ after @ g.T))

    aimed = plan(information, fit.uncertainty, 1, "predictions", predictions=torch.as_tensor(g))[0]
    best = min(predicted_variance(p) for p in plan(information, fit.uncertainty, 1))
    assert predicted_variance(aimed) <= best * 1.0001


def test_a_plan_for_the_prediction_of_one_parameter_is_the_plan_targeted_at_it():
    """"targets" is "predictions" with G = rows of the identity: the same picks."""
    rng = np.random.default_rng(3)
    a = rng.normal(size=(4, 4))
    covariance = a @ a.T + 0.1 * np.eye(4)
    u = FitUncertainty([f"e.p{i}" for i in range(4)], [""] * 4, np.zeros(4), covariance, 1.0, 1.0, 1.0)
    information = torch.as_tensor(np.stack([(v := rng.normal(size=(2, 4))).T @ v for _ in range(10)]))
    for k in range(4):
        by_name = plan(information, u, 3, "targets", targets=[f"e.p{k}"])
        by_rows = plan(information, u, 3, "predictions", predictions=torch.eye(4, dtype=torch.float64)[k:k + 1])
        assert [p.index for p in by_name] == [p.index for p in by_rows]
        assert np.allclose(by_name[-1].sigma_after, by_rows[-1].sigma_after)
    with pytest.raises(ValueError, match="predictions"):
        plan(information, u, 1, "predictions")


def test_canonical_correlation_of_two_groups():
    c = np.array([[1.0, 0.9, 0.0], [0.9, 1.0, 0.0], [0.0, 0.0, 1.0]])
    assert canonical_correlation(c, [0], [1]) == pytest.approx(0.9)
    assert canonical_correlation(c, [0], [2]) == pytest.approx(0.0, abs=1e-12)
    assert canonical_correlation(c, [0, 2], [1]) == pytest.approx(0.9)


def test_the_sun_path_at_juelich_on_midsummer_noon_stands_south_at_62_degrees():
    site = {"latitude_deg": 50.9134, "longitude_deg": 6.3878, "altitude_m": 87.0}
    times, azimuth, elevation = sun_path(site, datetime(2026, 6, 21, 0, 0, tzinfo=timezone.utc), 1.0, 10.0, 10.0)
    noon = int(np.argmax(elevation))
    assert elevation[noon] == pytest.approx(90 - 50.9134 + 23.44, abs=0.5)  # solar noon: 90 - latitude + declination
    assert abs(azimuth[noon]) < 3.0  # helioflow's azimuth: 0 = south
    assert min(elevation) >= 10.0 and 10.5 < (times[noon].hour + times[noon].minute / 60) < 12.5  # UTC, 6.4 deg E
