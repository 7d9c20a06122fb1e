"""Heliostats the physics tests build."""

import torch

from helioflow.physics.heliostat import Heliostat, ideal_heliostat


def make_heliostat(rows=2, cols=2, width=1.0, height=1.0, gap=0.02, focal=None, canting=None,
                   position=(0.0, 0.0, 0.0), mount="az_el", n_control=6, dtype=torch.float64) -> Heliostat:
    """An ideal heliostat (physics.heliostat.ideal_heliostat) with the tests' defaults: 2 x 2 facets
    of 1 m, float64, at the origin."""
    return ideal_heliostat(rows, cols, width, height, gap, position, mount, canting, focal, n_control, dtype)
