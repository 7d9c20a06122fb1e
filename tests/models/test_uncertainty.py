"""How sure a fit is (models/uncertainty.py): the reported sigma against the scatter of the fit over
noise draws, the predicted centroid's and flux's sigma likewise, and a fit that is off (a facet's surface
turned over) flagged instead of reported with a small sigma."""

import numpy as np
import pytest
import torch
from support.fit_scenes import BUIE, TRACKING, negated_facets, noisy, scene, suns

from helioflow.data.noise import correlate
from helioflow.models.physics_fit import (
    FitResult,
    FitSettings,
    Measurements,
    fit_effects,
    spot_spread,
    with_uncertainty,
)
from helioflow.models.uncertainty import STRUCTURED, FitUncertainty, widened_by_refits
from helioflow.physics.heliostat import TRACKING_PARAMETERS

TRUTH = {"tracking": torch.tensor([0.8, -0.5, 0.3, -0.6, 0.4])}
SETTINGS = FitSettings(steps=60, rounds=2, gauss_newton_steps=3, search_iterations=20)


def _tracking_problem():
    """(scene, the effects fitted, 12 sun positions (az, el), the images (peak 1), their scale) of a
    one-facet heliostat whose world has TRUTH's tracking error and a 1.5 mrad slope error."""
    s = scene()
    world = {"sunshape": BUIE, "slope_error": {"sigma_mrad": 1.5}, "tracking": {}}
    model = {"sunshape": BUIE, "slope_error": {"sigma_mrad": "fit"}, "tracking": TRACKING}
    az, el = suns(12)
    with torch.no_grad():
        clean = s.simulate(world, TRUTH, az, el)
    scale = float(clean.max())
    return s, model, (az, el), clean / scale, scale


@pytest.mark.slow
def test_reported_sigma_matches_the_scatter_of_the_fit_over_noise_draws():
    s, model, (az, el), clean, scale = _tracking_problem()
    values, sigmas, centroids, centroid_sigmas, fluxes, flux_sigmas = [], [], [], [], [], []
    held_az, held_el = torch.tensor([35.0]), torch.tensor([50.0])
    for seed in range(8):
        data = Measurements(noisy(clean, seed), az, el, scale)
        fit = with_uncertainty(s, fit_effects(s, model, data, SETTINGS), data, "absolute")
        u = fit.uncertainty
        assert u.undetermined == [] and u.structure < STRUCTURED
        values.append(u.values)
        sigmas.append(u.sigma)
        spot = spot_spread(s, fit, held_az, held_el, scale, "absolute", with_flux=True)
        centroids.append(spot["centroid_mrad"][0].numpy())
        centroid_sigmas.append(spot["centroid_sigma_mrad"][0].numpy())
        fluxes.append(spot["flux"][0].numpy())
        flux_sigmas.append(spot["flux_sigma"][0].numpy())
    scatter, reported = np.std(values, 0, ddof=1), np.mean(sigmas, 0)
    # 8 draws: the sample std is within a factor 0.55..1.5 of the true one at 95 %
    assert np.all(scatter / reported > 0.5) and np.all(scatter / reported < 1.6), (scatter, reported)
    assert np.median(scatter / reported) == pytest.approx(1.0, abs=0.3)
    truth_values = np.array([*TRUTH["tracking"].tolist(), 1.5])
    z = (np.array(values) - truth_values) / np.array(sigmas)
    assert np.mean(np.abs(z) < 1.96) > 0.85  # coverage of the 95 % interval
    c_scatter, c_reported = np.std(centroids, 0, ddof=1), np.mean(centroid_sigmas, 0)
    assert np.all(c_scatter / c_reported > 0.5) and np.all(c_scatter / c_reported < 1.6), (c_scatter, c_reported)
    # the flux per pixel: where the spot is brighter than a tenth of its peak, the reported sigma is
    # the scatter of the fitted flux over the draws (per pixel, 8 draws each: compared by the median)
    f_scatter, f_reported = np.std(fluxes, 0, ddof=1), np.mean(flux_sigmas, 0)
    bright = np.mean(fluxes, 0) > 0.1 * np.mean(fluxes, 0).max()
    assert bright.sum() > 50
    assert np.median(f_scatter[bright] / f_reported[bright]) == pytest.approx(1.0, abs=0.3)


@pytest.mark.slow
def test_noise_smooth_over_pixels_widens_the_sigma_to_the_scatter_of_the_fit():
    """Noise blurred over 1.5 px (a camera's optics, a rectified image): the tracking's sigma, read
    with the residual's own correlation (models/correlated.py), is the scatter of the fit over 8 draws
    (a white estimate would be 4-5 times low: the correlation multiplies the variance by more than 10);
    the slope error, which smooth noise moves as a width would, is flagged not determined or covered."""
    s, model, (az, el), clean, scale = _tracking_problem()
    fits = []
    for seed in range(8):
        white = torch.randn(clean.shape, generator=torch.Generator().manual_seed(seed), dtype=torch.float64)
        images = clean + correlate(white, 1.5).float() * (0.003 + 0.02 * clean.clamp_min(0).sqrt())
        data = Measurements(images, az, el, scale)
        fits.append(with_uncertainty(s, fit_effects(s, model, data, SETTINGS), data, "absolute").uncertainty)
    tracking = [k for k, n in enumerate(fits[0].names) if n.startswith("tracking.")]
    scatter = np.std([u.values for u in fits], 0, ddof=1)
    reported = np.mean([u.sigma for u in fits], 0)
    ratio = scatter[tracking] / reported[tracking]
    assert np.all(ratio > 0.5) and np.all(ratio < 1.6), ratio
    assert min(u.correlation_gain for u in fits) > 10
    slope = fits[0].index("slope_error.sigma_mrad")
    assert all("slope_error.sigma_mrad" in u.undetermined for u in fits) or scatter[slope] / reported[slope] < 1.6


def test_a_facet_left_turned_over_is_flagged_not_determined_and_the_rest_is_not():
    s, truth, data, effects, start = negated_facets(2, 2, negated=1)
    data = Measurements(noisy(data.images, 0), data.azimuth_deg, data.elevation_deg, data.scale)
    wrong = FitResult(effects, {"surface": start}, fitted=[("surface", "control_heights_mm")])
    u = with_uncertainty(s, wrong, data, "absolute").uncertainty
    assert u.structure > STRUCTURED
    assert np.argmax(u.facet_structure) == 0  # the residual lives most where facet 0's flux lands
    flagged = {int(n.split("[")[1].split(",")[0]) for n in u.undetermined}
    assert 0 in flagged  # (its neighbours' spots overlap it: they share its residual and are flagged too)
    right = FitResult(effects, {"surface": truth}, fitted=[("surface", "control_heights_mm")])
    u = with_uncertainty(s, right, data, "absolute").uncertainty
    assert u.structure < STRUCTURED and u.undetermined == []
    # a facet's plane changes no image: its heights' sigma is reported for the shape only (finite)
    assert np.all(np.isfinite(u.sigma)) and u.as_json()["tensors"]["surface.control_heights_mm"]["unit"] == "mm"


def test_the_uncertainty_survives_the_model_file_round_trip():
    u = FitUncertainty(["tracking.axis1_offset_mrad", "slope_error.sigma_mrad"], ["mrad", "mrad"],
                       np.array([0.5, 1.2]), np.array([[4e-4, 1e-4], [1e-4, 9e-4]]), 1.01, 0.98, 0.01)
    back = FitUncertainty.from_state(u.state())
    assert back.names == u.names and np.allclose(back.covariance, u.covariance)
    assert back.sigma == pytest.approx([0.02, 0.03])
    assert back.as_json()["scalars"]["slope_error.sigma_mrad"] == {"value": 1.2, "sigma": 0.03, "unit": "mrad",
                                                                     "determined": True}


@pytest.mark.parametrize("case", ["one facet, tracking and slope error", "2 x 2 facets, surface"])
def test_the_centroids_derivative_by_autograd_is_the_central_difference_one(case):
    """spot_spread takes the centroid's derivative by the heliostat tensors by autograd through the
    linearised trace (each image its own copy of the tensors); with_flux it takes every column by
    central differences of traced images. Both give the same Jacobian and sigma."""
    if case.startswith("one"):
        s, model, (az, el), clean, scale = _tracking_problem()
        data = Measurements(noisy(clean, 0), az, el, scale)
        fit = with_uncertainty(s, fit_effects(s, model, data, SETTINGS), data, "absolute")
    else:
        s, truth, data, effects, _ = negated_facets(2, 2, negated=1)
        data = Measurements(noisy(data.images, 0), data.azimuth_deg, data.elevation_deg, data.scale)
        fit = FitResult(effects, {"surface": truth}, fitted=[("surface", "control_heights_mm")])
        fit = with_uncertainty(s, fit, data, "absolute")
    held_az, held_el = torch.tensor([35.0, -20.0, 60.0]), torch.tensor([50.0, 30.0, 65.0])
    by_autograd = spot_spread(s, fit, held_az, held_el, data.scale, "absolute")
    by_differences = spot_spread(s, fit, held_az, held_el, data.scale, "absolute", with_flux=True)
    a, b = by_autograd["centroid_jacobian"].numpy(), by_differences["centroid_jacobian"].numpy()
    assert np.abs(a).max() > 0.1  # mrad of centroid per parameter unit: the derivative is not trivially 0
    assert np.abs(a - b).max() < 0.02 * np.abs(b).max()
    assert by_autograd["centroid_sigma_mrad"].numpy() == pytest.approx(
        by_differences["centroid_sigma_mrad"].numpy(), rel=0.02)


def test_refits_with_one_image_left_out_widen_each_sigma_to_their_jackknife_spread_and_keep_the_correlations():
    names = [f"tracking.{n}_mrad" for n in TRACKING_PARAMETERS] + ["sunshape.sigma_mrad"]
    covariance = 0.01**2 * (0.5 * np.eye(6) + 0.5)  # sigma 0.01 each, correlation 0.5
    u = FitUncertainty(names, ["mrad"] * 6, np.zeros(6), covariance, 1.0, 1.0, 1.0)
    refits = [FitResult({"sunshape": {"sigma_mrad": 2.5 + 1e-3 * i}},
                        {"tracking": torch.tensor([a, 0.0, 0.0, 0.0, 0.0])}) for i, a in enumerate((1.0, 2.0, 3.0))]
    widened = widened_by_refits(u, refits)
    # the first tracking entry scatters over the refits: (n-1)/n sum (a - mean a)^2 = 2/3 * 2
    assert widened.sigma[0] == pytest.approx(np.sqrt(4 / 3))
    # the others do not move, and the sun's width moves less than its sigma: both keep the end point's sigma
    assert np.allclose(widened.sigma[1:], 0.01)
    assert np.allclose(widened.correlation(), u.correlation())
    assert widened.refits == 3 and FitUncertainty.from_state(widened.state()).refits == 3
    assert widened.as_json()["refits"] == 3
    assert widened_by_refits(u, refits[:1]) is u  # one refit has no spread to read
