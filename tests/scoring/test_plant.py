"""The plant table's pointing error (scoring.plant): the angle between fitted and ideal mirror
normals, and its sigma from the fit's covariance against first-order propagation."""

import numpy as np
import torch

from helioflow.physics.heliostat import ideal_heliostat
from helioflow.scoring.plant import pointing_error
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
