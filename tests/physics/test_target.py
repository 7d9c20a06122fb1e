"""The target's one centroid: pixels and metres agree, empty images have none."""

import math

import torch

from helioflow.physics.target import Target, pixel_centroid


def test_a_single_lit_pixels_centroid_is_its_centre_in_pixels_and_in_metres():
    target = Target.facing([0.0, 0.0, 10.0], [0.0, 50.0, 10.0], 4.0, 2.0, (8, 16))
    image = torch.zeros(1, 8, 16)
    image[0, 2, 11] = 5.0
    image[0, 3, 3] = -1.0  # negative flux (noise after background subtraction) does not count
    assert pixel_centroid(image)[0].tolist() == [2.0, 11.0]
    u, v = target.pixel_centres()
    assert torch.allclose(target.centroid(image)[0], torch.stack((u[11], v[2])))


def test_two_equal_pixels_centroid_lies_between_them_and_an_empty_image_has_none():
    image = torch.zeros(2, 4, 4, dtype=torch.float64)
    image[0, 0, 0] = image[0, 3, 1] = 2.0
    centre = pixel_centroid(image)
    assert centre[0].tolist() == [1.5, 0.5]
    assert all(math.isnan(x) for x in centre[1].tolist())
