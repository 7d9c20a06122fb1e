"""A dataset's scene: the target a model of the dataset traces on."""

import pytest
from support.heliostats import make_heliostat

from helioflow.physics.scene import dataset_scene
from helioflow.physics.target import CAMERA_PIXEL_VARIANCE, TENT_VARIANCE

ATTRS = {"target_center_m": [0.0, 0.0, 20.0], "target_normal": [0.0, 1.0, 0.0], "target_size_m": [4.0, 4.0],
         "dni_w_m2": 1000.0}


@pytest.mark.parametrize(("trace", "pixel_variance"), [
    (None, CAMERA_PIXEL_VARIANCE),  # imported: a camera's images (PAINT, one's own PNGs)
    ({"splat": "bilinear", "rays": 1000, "cells_per_side": 8}, TENT_VARIANCE),  # helioflow's Monte Carlo
    ({"splat": "kernel", "rays": 0, "cells_per_side": 8}, None),  # the kernel splat's own images
])
def test_a_datasets_model_averages_over_pixels_as_its_images_do(trace, pixel_variance):
    attrs = ATTRS if trace is None else {**ATTRS, "trace": trace}
    for fitting in (False, True):
        scene = dataset_scene(make_heliostat(1, 1, 1.0, 1.0, 0.0), attrs, (64, 64), 8, 1000, fitting)
        assert scene.target.pixel_variance == pixel_variance
