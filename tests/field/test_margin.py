"""The pointing's spread on the receiver and an aiming that keeps the limit with a stated probability
(field/margin.py): the kinematic Jacobian against the tracer, the draws against their covariance, the
margin against fresh draws."""

import math
from dataclasses import replace

import numpy as np
import pytest
import torch
from support.field import PIXEL, build, gaussians, tiny_field

from helioflow.data.surfaces import HeliostatSpec, true_heliostat
from helioflow.field.aim import SpotPatches, optimise
from helioflow.field.aiming import MARGIN, STRATEGIES, optimise_aim
from helioflow.field.margin import (
    TRACKING_NAMES,
    covered,
    displacement_draws,
    jittered_peaks,
    optimise_with_margin,
    pointing_covariances,
    receiver_jacobian,
    tracking_covariance,
)
from helioflow.models.uncertainty import FitUncertainty
from helioflow.physics.effects import resolve
from helioflow.physics.field import FieldHeliostats, field_flux, flat_receiver
from helioflow.physics.geometry import sun_vector
from helioflow.report.page import build_report
from helioflow.workflow import optimise_aim_params


def test_the_receiver_jacobian_moves_the_spot_as_the_tracer_does():
    """A 2 x 2-facet heliostat 60 m out: each tracking parameter moved by 1 mrad moves the traced spot's
    centroid on a tilted receiver by the Jacobian's column (the central ray through the kinematics)."""
    spec = HeliostatSpec.from_config("h", {
        "position_m": [10.0, 60.0, 1.0], "mount": "az_el",
        "facets": {"rows": 2, "cols": 2, "width_m": 1.2, "height_m": 1.2, "gap_m": 0.02},
        "canting_focal_distance_m": 60.0, "facet_focal_length_m": None, "control_points": 5,
        "deformation_mm": 0.0, "tracking_error_mrad": 1.0, "canting_error_mrad": 0.0, "seed": 3})
    physics = resolve({"sunshape": {"kind": "buie", "csr": 0.1}, "slope_error": {"sigma_mrad": 0.5},
                       "tracking": {}}, true_heliostat(spec), 1000.0)
    heliostat = physics.heliostat.to("cpu", torch.float64)
    receiver = flat_receiver([0.0, 0.0, 30.0], [0.0, 1.0, -0.35], 5.0, 5.0, (200, 200))
    az, el = (torch.tensor([math.radians(a)], dtype=torch.float64) for a in (30.0, 45.0))

    def centroid(h):
        field = FieldHeliostats.stack([h], 12, torch.float64)
        return receiver.centroid(field_flux(field, receiver, az, el, physics.optics).flux)[0]

    jacobian = receiver_jacobian(heliostat, sun_vector(az, el)[0], receiver.center, receiver)
    base = centroid(heliostat)
    for j in range(5):
        step = torch.zeros(5, dtype=torch.float64)
        step[j] = 1e-3  # 1 mrad
        moved = centroid(replace(heliostat, tracking_error=heliostat.tracking_error + step)) - base
        assert torch.allclose(moved, jacobian[:, j], atol=0.01 * float(jacobian.norm()) + 2e-3), j
    assert 0.05 < float(jacobian.norm(dim=0).max()) < 0.5  # about twice the slant range per rad: a beam, not a normal


def test_the_tracking_block_is_read_from_the_fit_and_drawn_with_its_covariance():
    names = ["sunshape.sigma_mrad", *TRACKING_NAMES]
    a = np.random.default_rng(1).normal(size=(6, 6))
    u = FitUncertainty(names, ["mrad"] * 6, np.zeros(6), a @ a.T, 1.0, 1.0, 1.0)
    block = tracking_covariance(u)
    assert block is not None and torch.allclose(block, torch.as_tensor((a @ a.T)[1:, 1:]))
    assert tracking_covariance(FitUncertainty(names[:1], ["mrad"], np.zeros(1), np.eye(1), 1.0, 1.0, 1.0)) is None
    covariances = torch.tensor([[[4e-4, 1e-4], [1e-4, 1e-4]], [[0.0, 0.0], [0.0, 0.0]]], dtype=torch.float64)
    draws = displacement_draws(covariances, 20000, seed=3)
    sample = torch.einsum("dni,dnj->nij", draws, draws) / len(draws)
    assert torch.allclose(sample[0], covariances[0], rtol=0.05, atol=5e-6)
    assert float(draws[:, 1].abs().max()) == 0.0  # a heliostat known exactly is not moved
    # offsets drawn from the covariance fall in its 95 % ellipse 95 % of the time; ones twice as large do not
    many = covariances[:1].expand(4000, 2, 2)
    offsets = displacement_draws(many, 1, seed=5)[0]
    assert covered(many, offsets) == (pytest.approx(0.95, abs=0.015), 4000)
    assert covered(many, 2 * offsets)[0] < 0.6
    assert covered(covariances[1:], offsets[:1]) == (1.0, 0)  # no heliostat with a covariance: nothing to judge
    # J C J^T: a heliostat without a covariance has none on the receiver
    h = true_heliostat(HeliostatSpec.from_config("h", {
        "position_m": [0.0, 50.0, 0.0], "mount": "az_el",
        "facets": {"rows": 1, "cols": 1, "width_m": 1.0, "height_m": 1.0}}))
    receiver = flat_receiver([0.0, 0.0, 20.0], [0.0, 1.0, 0.0], 4.0, 4.0, (32, 32))
    sun = sun_vector(torch.tensor(0.3, dtype=torch.float64), torch.tensor(0.7, dtype=torch.float64))
    out = pointing_covariances([h, h], [torch.eye(5, dtype=torch.float64), None], sun,
                               receiver.center.expand(2, 3), receiver)
    j = receiver_jacobian(h, sun, receiver.center, receiver)
    assert torch.allclose(out[0], j @ j.T) and float(out[1].abs().max()) == 0.0


@pytest.fixture(scope="module")
def crowded():
    """Nine Gaussian spots (sigma 4 px = 0.2 m) that an aiming must spread to keep 60 % of their
    stacked peak, each pointing uncertain by 0.1 m in u and v."""
    maps = gaussians([(0.0, 0.0)] * 9, 4.0, 1e5)
    spots = SpotPatches.from_maps(maps, (64, 64), PIXEL)
    covariance = torch.eye(2, dtype=torch.float64).expand(9, 2, 2) * 0.1**2
    return spots, torch.zeros(9, 2, dtype=torch.float64), 0.6 * 9e5 * 0.25, covariance


def test_an_aiming_with_a_margin_keeps_the_limit_on_fresh_draws_with_the_stated_probability(crowded):
    spots, start, limit, covariance = crowded
    probability = 0.9
    draws = displacement_draws(covariance, 256, seed=0)
    result, bound, fraction = optimise_with_margin(spots, start, limit, draws, probability, region=0.8, steps=150)
    assert bound <= 1.0 and fraction < 1.0 and result.peak_over_limit <= 1.0
    fresh = jittered_peaks(spots, result.offsets, displacement_draws(covariance, 400, seed=7), limit)
    kept = float((fresh <= 1.0).double().mean())
    assert kept >= probability - 0.06  # 400 fresh draws: the binomial's 3 sigma is 0.045
    # the aiming chosen without the margin keeps the limit on its own map, under the pointing's spread about
    # every other time (0.54)
    plain = optimise(spots, start, limit, region=0.8, steps=150)
    assert plain.feasible
    assert float((jittered_peaks(spots, plain.offsets, displacement_draws(covariance, 400, seed=7), limit) <= 1.0)
                 .double().mean()) < probability - 0.2
    # the price of the margin: power given up, but not much
    assert result.on_receiver_w > 0.9 * plain.on_receiver_w


def test_optimise_aim_adds_an_aiming_that_keeps_the_limit_under_the_calibrated_pointing_sigma(tmp_path):
    """The tiny field, its 2 measured heliostats fitted by drt and then told a tracking sigma of 3 mrad
    per parameter: aim.json gains `hybrid_margin`, whose aiming keeps the hybrid map's peak under the
    limit at the stated probability (its 95 %-confidence bound), judged like every aiming on the truth;
    the spots' pointing sigma on the receiver is about twice the slant range times a mrad."""
    def with_drt(config: dict) -> None:
        config["field"]["network"] = "drt"
        config["networks"] = {"drt": {"freedom": "full"}}
        config["field"]["sun"] = {"noon": config["field"]["sun"]["noon"]}
        config["field"]["optimise_aim"] = {"limit_kw_m2": 4.0, "steps": 100, "keep_probability": 0.9, "draws": 64}

    config = tiny_field(with_drt)
    models, datasets = build(config, tmp_path, "drt", {"fit_steps": 1, "rounds": 1, "fit_images": 2,
                                                        "facet_hops": 0, "pinned_hops": 0, "gauss_newton_steps": 0})
    for path in models:  # the fit's covariance replaced: 9 mrad^2 on each tracking parameter, nothing else
        info = torch.load(path, weights_only=False)
        state = info["state"]["_extra_state"]["uncertainty"]
        tracking = torch.tensor([n in TRACKING_NAMES for n in state["names"]], dtype=torch.float64)
        state["covariance"] = torch.diag(tracking) * 9.0
        torch.save(info, path)
    result = optimise_aim(optimise_aim_params(config), models, datasets, tmp_path / "aim.json", tmp_path / "aim.png")
    row = result["design_points"]["noon"]
    assert set(row) == {*STRATEGIES, MARGIN} and result["keep_probability"] == 0.9
    sigma = result["pointing_sigma_m"]["noon"]
    assert sigma["heliostats"] == 2 and 0.1 < sigma["median"] < 1.0  # slant ~20 m: 2 x 20 m x 3 mrad, five of them
    assert 0.0 <= sigma["truth_within_95"] <= 1.0 and sigma["truth_offset_rms_m"] > 0.0
    margin, hybrid = row[MARGIN], row["hybrid"]
    assert margin["model_peak_bound_over_limit"] <= 1.0 and 0.5 <= margin["limit_fraction"] <= 1.0
    if hybrid["model_peak_bound_over_limit"] <= 1.0:  # the hybrid's aiming already keeps it: nothing to give up
        assert margin["limit_fraction"] == 1.0 and margin["aim_points_m"] == hybrid["aim_points_m"]
    else:
        assert margin["limit_fraction"] < 1.0 and margin["model_peak_over_limit"] < hybrid["model_peak_over_limit"]
    assert {"truth_peak_over_limit", "truth_intercepted_w", "intercept_of_bound"} <= set(margin)
    html = build_report({"aim": [str(tmp_path / "aim.json"), str(tmp_path / "aim.png")]}, None, "tiny")
    assert "hybrid_margin" in html and "model_peak_bound_over_limit" in html
