"""The plant table's pointing error (scoring.plant): the angle between fitted and ideal mirror
normals, and its sigma from the fit's covariance against first-order propagation."""

import numpy as np
import pytest
import torch

from helioflow.physics.heliostat import ideal_heliostat
from helioflow.scoring.plant import is_off, pointing_error, unnamed_widening
from helioflow.scoring.recovery import pointing_angles_mrad

SUNS_AZ = np.array([-60.0, -20.0, 10.0, 45.0, 70.0])
SUNS_EL = np.array([25.0, 50.0, 60.0, 40.0, 20.0])
AIM = [0.0, 0.0, 30.0]


def _heliostat():
    return ideal_heliostat(2, 2, 1.6, 1.25, 0.05, (10.0, 80.0, 0.0), "juelich", 80.0, None, 4, torch.float64)


def test_the_ideal_kinematics_point_without_error_and_a_joint_offset_tilts_the_normal_by_it():
    h = _heliostat()
    rms, sigma = pointing_error(h, torch.zeros(5), None, SUNS_AZ, SUNS_EL, AIM)
    assert rms < 1e-9 and sigma is None
    # the second joint turns about an axis perpendicular to the mirror normal: the normal tilts by
    # the offset itself at every sun position
    second = pointing_angles_mrad(h, torch.tensor([0.0, 0.7, 0.0, 0.0, 0.0]), SUNS_AZ, SUNS_EL, AIM)
    assert torch.allclose(second, torch.full((5,), 0.7, dtype=torch.float64), rtol=1e-3)


def test_the_sigma_is_the_first_order_propagation_of_the_covariance():
    h = _heliostat()
    fitted = torch.tensor([0.9, -0.6, 0.3, 0.2, -0.4], dtype=torch.float64)
    rng = np.random.default_rng(1)
    root = rng.normal(0.0, 0.02, (5, 5))
    covariance = root @ root.T + np.eye(5) * 1e-4  # mrad^2, sigmas of ~0.05 mrad
    rms, sigma = pointing_error(h, fitted, covariance, SUNS_AZ, SUNS_EL, AIM)
    step = 1e-4
    gradient = np.array([(pointing_error(h, fitted + step * e, None, SUNS_AZ, SUNS_EL, AIM)[0]
                          - pointing_error(h, fitted - step * e, None, SUNS_AZ, SUNS_EL, AIM)[0]) / (2 * step)
                         for e in torch.eye(5, dtype=torch.float64)])
    linear = float(np.sqrt(gradient @ covariance @ gradient))
    assert rms > 0.5 and sigma == np.float64(sigma)
    assert abs(sigma / linear - 1.0) < 0.1  # 512 draws: the sample std is within ~6 % at 95 %


def _uncertainty(names, values, covariance, undetermined=()):
    from helioflow.models.uncertainty import FitUncertainty

    return FitUncertainty(list(names), ["mrad"] * len(names), np.asarray(values, float), np.asarray(covariance, float),
                          1.0, 1.0, 1.0, undetermined=list(undetermined))


def test_the_canting_rms_sigma_is_the_first_order_propagation_of_the_covariance():
    from helioflow.scoring.plant import tensor_rms

    tilts = torch.tensor([[0.8, -0.3], [-0.5, 0.6], [0.2, -0.9], [-0.5, 0.6]], dtype=torch.float64)  # mrad
    names = [f"canting.facet_tilts_mrad[{f}, {a}]" for f in range(4) for a in range(2)]
    rng = np.random.default_rng(2)
    root = rng.normal(0.0, 0.03, (8, 8))
    covariance = root @ root.T + np.eye(8) * 1e-3
    value, sigma, undetermined = tensor_rms(tilts, "canting", _uncertainty(names, tilts.flatten(), covariance))
    assert value == pytest.approx(float(tilts.pow(2).mean().sqrt()))
    gradient = (tilts.flatten() / (8 * value)).numpy()  # d RMS / d entry
    linear = float(np.sqrt(gradient @ covariance @ gradient))
    assert abs(sigma / linear - 1.0) < 0.12 and not undetermined  # 512 draws; RMS is nearly linear here
    value, sigma, undetermined = tensor_rms(tilts, "canting", _uncertainty(names[:2], [0.8, -0.3], np.eye(2) * 1e-6,
                                                                           undetermined=[names[1]]))
    assert sigma < 1e-3 and undetermined  # two entries known to 1e-3 mrad, one not determined
    assert tensor_rms(tilts, "canting", None)[1:] == (None, False)


def test_the_surface_rms_is_that_of_the_heights_the_control_points_span():
    from helioflow.scoring.plant import tensor_rms
    from helioflow.scoring.recovery import surface_heights

    heights = torch.zeros(4, 6, 6, dtype=torch.float64)
    heights[1, 2:4, 2:4] = 0.5  # a bump of half a millimetre on facet 1
    names = [f"surface.control_heights_mm[{f}, {i}, {j}]" for f in range(4) for i in range(6) for j in range(6)]
    value, sigma, _ = tensor_rms(heights, "surface", _uncertainty(names, heights.flatten(), np.zeros((144, 144))),
                                 heights=True)
    assert value == pytest.approx(float(surface_heights(heights).pow(2).mean().sqrt())) and 0 < value < 0.5
    assert sigma == pytest.approx(0.0, abs=1e-12)


def test_a_heliostat_named_only_its_kinematics_but_widened_beyond_the_plants_envelope_is_flagged():
    """A heliostat whose own camera blur (the plant fit, its kinematics and the blur free) lies beyond
    WIDENED of its sigma above the lower envelope of the plant's values, and whose diagnosis named only
    its kinematics, hides a widening of its own that the shared level took: flagged, and off."""
    blur = {"value": 1.53, "sigma": 0.084, "clipped": 1.611,
            "alone": {"P012": {"value": 1.651, "sigma": 0.05, "kept": True},
                      "P005": {"value": 1.537, "sigma": 0.04, "kept": True}}}
    shared = {"shared": [{"effect": "camera", "values": {"camera.blur_px": blur}},
                         {"effect": "sunshape", "values": {}}]}
    flag = unnamed_widening("P012", ["tracking"], shared)
    assert flag == ("own widening unnamed (camera.blur_px 1.651 +- 0.05 alone, 2.4 sigma above the plant's "
                    "envelope 1.53)") and is_off(flag)
    assert unnamed_widening("P005", ["tracking"], shared) is None  # 0.2 sigma: as clean as the plant's
    assert unnamed_widening("P012", ["tracking", "canting"], shared) is None  # its diagnosis named its widening
    assert unnamed_widening("P099", ["tracking"], shared) is None  # not among the heliostats the plant fit took
    assert unnamed_widening("P012", ["tracking"], None) is None  # no plant fit
