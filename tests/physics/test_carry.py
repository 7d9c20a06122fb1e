"""Carrying a spot from the calibration target to the receiver (physics.carry) against spots traced
directly on the receiver."""

import math

import pytest
import torch

from helioflow.data.surfaces import HeliostatSpec, true_heliostat
from helioflow.physics.carry import carry_spot, commanded_normal, core_spread, equivalent_sun
from helioflow.physics.effects import resolve
from helioflow.physics.field import FieldHeliostats, field_flux, flat_receiver
from helioflow.physics.geometry import azimuth_elevation, sun_vector
from helioflow.physics.raytrace import trace
from helioflow.physics.sun import SunShape
from helioflow.physics.target import Target
from helioflow.scoring.metrics import flux_accuracy

WORLD = {
    "sunshape": {"kind": "pillbox", "half_angle_mrad": 4.65},
    "slope_error": {"sigma_mrad": 0.5},
    "tracking": {},
    "surface": {},
}
F64 = torch.float64


def _scene(tracking_mrad: float, deformation_mm: float, position=(20.0, 45.0, 2.0)):
    spec = HeliostatSpec(
        "h", position, "az_el", 1, 1, 2.0, 2.0, 0.0, None, None, 6, deformation_mm, tracking_mrad, 0.0, 5
    )
    physics = resolve(WORLD, true_heliostat(spec), 1000.0)
    receiver = flat_receiver([0.0, 0.0, 35.0], [0.0, 1.0, -0.35], 5.0, 5.0, (96, 96))
    target = Target(
        torch.tensor([0.0, 0.0, 20.0], dtype=F64),
        torch.tensor([0.0, 1.0, 0.0], dtype=F64),
        5.0,
        5.0,
        (80, 80),
    )
    return physics, receiver, target


def _carried_and_true(physics, receiver, target, sun_deg, spread):
    az, el = (torch.tensor([math.radians(x)], dtype=F64) for x in sun_deg)
    sun = sun_vector(az, el)[0]
    h = physics.heliostat
    eq_az, eq_el = azimuth_elevation(equivalent_sun(h.position, receiver.center, sun, target.center))
    image = trace(
        h, target, eq_az[None], eq_el[None], physics.optics, rays=0, splat="kernel", cells_per_side=32
    )[0]
    carried = carry_spot(image, target, receiver, h.position, receiver.center, sun, spread)
    truth = field_flux(
        FieldHeliostats.stack([h], 32), receiver, az, el, physics.optics, blocking_shading=False
    ).flux[0]
    return carried, truth, image


def test_the_equivalent_sun_commands_the_same_normal():
    position, aim, target = (
        torch.tensor(v, dtype=F64) for v in ([30.0, 50.0, 2.0], [0, 0, 35.0], [0, 0, 20.0])
    )
    for sun_deg in ((0.0, 60.0), (75.0, 30.0), (-120.0, 20.0)):
        sun = sun_vector(*(torch.tensor(math.radians(x), dtype=F64) for x in sun_deg))
        s_eq = equivalent_sun(position, aim, sun, target)
        assert torch.allclose(commanded_normal(position, target, s_eq), commanded_normal(position, aim, sun))
        assert s_eq.norm().item() == pytest.approx(1.0)


def test_core_spread_of_a_gaussian_sun_is_its_sigma():
    assert core_spread(SunShape.from_config({"kind": "gaussian", "sigma_mrad": 2.0}), 0.0) == pytest.approx(
        2e-3, 1e-3
    )
    with_slope = core_spread(SunShape.from_config({"kind": "gaussian", "sigma_mrad": 2.0}), 0.5e-3)
    assert with_slope == pytest.approx(math.hypot(2e-3, 1e-3), 1e-3)  # slope errors double on reflection
    assert core_spread(SunShape.from_config({"kind": "point"}), 0.0) == 0.0


@pytest.mark.parametrize("sun_deg", [(0.0, 60.0), (75.0, 30.0), (-75.0, 30.0)])
def test_a_carried_true_spot_matches_the_spot_traced_on_the_receiver(sun_deg):
    physics, receiver, target = _scene(tracking_mrad=1.0, deformation_mm=0.5)
    spread = core_spread(physics.optics.sun, physics.optics.slope_error)
    carried, truth, _ = _carried_and_true(physics, receiver, target, sun_deg, spread)
    assert flux_accuracy(carried.numpy(), truth.numpy()) > 0.93
    # power: the target's, scaled by the change of incidence, and all of it lands on the receiver
    assert carried.sum() * receiver.pixel_area == pytest.approx(
        float(truth.sum() * receiver.pixel_area), rel=0.01
    )
    # the pointing error is carried: centroids agree to 1 cm (the spot is ~2.5 m wide, 60 m away)
    offset = receiver.centroid(carried[None]) - receiver.centroid(truth[None])
    assert offset.norm() < 0.01
    assert float(carried.max() / truth.max()) == pytest.approx(1.0, abs=0.05)


@pytest.mark.parametrize("deformation_mm", [0.0, 0.5])
def test_the_blur_of_the_longer_path_brings_the_carried_spot_closer(deformation_mm):
    physics, receiver, target = _scene(tracking_mrad=1.0, deformation_mm=deformation_mm)
    spread = core_spread(physics.optics.sun, physics.optics.slope_error)
    accuracy = {}
    for s in (0.0, spread):
        carried, truth, _ = _carried_and_true(physics, receiver, target, (-75.0, 30.0), s)
        accuracy[s] = flux_accuracy(carried.numpy(), truth.numpy())
    assert accuracy[spread] > accuracy[0.0] + 0.01


def test_an_ideal_heliostat_lands_on_the_aim_point():
    physics, receiver, target = _scene(tracking_mrad=0.0, deformation_mm=0.0, position=(-30.0, 40.0, 2.0))
    carried, truth, _ = _carried_and_true(physics, receiver, target, (75.0, 30.0), 0.0)
    assert receiver.centroid(carried[None]).norm() < 0.01
    assert receiver.centroid(truth[None]).norm() < 0.01
