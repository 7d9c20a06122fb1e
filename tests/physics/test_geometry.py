"""Frames and conventions: sun direction, ENU from WGS84, reflection law, target plane axes."""

import math

import numpy as np
import pytest
import torch

from helioflow.physics.geometry import (
    azimuth_elevation,
    normalize,
    plane_axes,
    reflect,
    rotation_about_axis,
    sun_vector,
    wgs84_to_enu,
)

DT = torch.float64


def _t(*values) -> torch.Tensor:
    return torch.tensor(values[0] if len(values) == 1 else values, dtype=DT)


@pytest.mark.parametrize(
    "az_deg, el_deg, expected",
    [
        (0.0, 0.0, (0.0, -1.0, 0.0)),  # azimuth 0 = south
        (90.0, 0.0, (1.0, 0.0, 0.0)),  # +90 = east
        (-90.0, 0.0, (-1.0, 0.0, 0.0)),  # -90 = west
        (180.0, 0.0, (0.0, 1.0, 0.0)),  # north
        (37.0, 90.0, (0.0, 0.0, 1.0)),  # zenith, any azimuth
        (0.0, 30.0, (0.0, -math.cos(math.radians(30)), 0.5)),
    ],
)
def test_sun_vector_convention(az_deg, el_deg, expected):
    v = sun_vector(_t(math.radians(az_deg)), _t(math.radians(el_deg)))
    torch.testing.assert_close(v, _t(*expected), atol=1e-12, rtol=0)


def test_azimuth_elevation_inverts_sun_vector():
    g = torch.Generator().manual_seed(0)
    az = (torch.rand(1000, generator=g, dtype=DT) * 2 - 1) * math.pi * 0.999
    el = (torch.rand(1000, generator=g, dtype=DT) * 2 - 1) * math.pi / 2 * 0.999
    v = sun_vector(az, el)
    torch.testing.assert_close(v.norm(dim=-1), torch.ones(1000, dtype=DT))
    a2, e2 = azimuth_elevation(3.7 * v)  # any length
    torch.testing.assert_close(a2, az, atol=1e-9, rtol=0)
    torch.testing.assert_close(e2, el, atol=1e-7, rtol=0)  # asin loses digits near +-90 deg


def test_wgs84_to_enu_known_offsets():
    lat0, lon0, alt0 = 50.9, 6.4, 100.0
    # 0.001 deg north: (meridional radius of curvature M + altitude) times the angle (~111 m), nothing east.
    e2 = 0.00669437999014
    m = 6378137.0 * (1 - e2) / (1 - e2 * math.sin(math.radians(lat0)) ** 2) ** 1.5
    east, north, up = wgs84_to_enu(lat0 + 0.001, lon0, alt0, lat0, lon0, alt0)
    assert north == pytest.approx((m + alt0) * math.radians(0.001), abs=1e-4)
    assert 111.0 < north < 111.4
    assert abs(east) < 1e-6
    assert up == pytest.approx(-(north**2) / (2 * 6.37e6), rel=0.05)  # the ground curves away (~1 mm)
    # 0.001 deg east: the prime-vertical radius N cos(lat) times the angle.
    n = 6378137.0 / math.sqrt(1 - e2 * math.sin(math.radians(lat0)) ** 2)
    east, north, up = wgs84_to_enu(lat0, lon0 + 0.001, alt0, lat0, lon0, alt0)
    assert east == pytest.approx((n + alt0) * math.cos(math.radians(lat0)) * math.radians(0.001), abs=1e-4)
    assert abs(north) < 1e-3 and abs(up) < 1e-2
    # Altitude is up; the reference point itself is the origin; arrays keep their shape.
    up25 = wgs84_to_enu(lat0, lon0, alt0 + 25.0, lat0, lon0, alt0)
    np.testing.assert_allclose(up25, [0, 0, 25.0], atol=1e-6)
    np.testing.assert_allclose(wgs84_to_enu(lat0, lon0, alt0, lat0, lon0, alt0), [0, 0, 0], atol=1e-6)
    out = wgs84_to_enu(np.full((2, 3), lat0), np.full((2, 3), lon0), np.full((2, 3), alt0), lat0, lon0, alt0)
    assert out.shape == (2, 3, 3)


def test_wgs84_to_enu_preserves_distances():
    """ENU is a rotation + translation of ECEF: distances between points are kept (no round trip needed)."""
    lat0, lon0, alt0 = 50.9, 6.4, 100.0
    lat = np.array([50.9, 50.91, 50.88, 50.902])
    lon = np.array([6.4, 6.39, 6.42, 6.401])
    alt = np.array([100.0, 130.0, 90.0, 250.0])
    enu = wgs84_to_enu(lat, lon, alt, lat0, lon0, alt0)
    a, e2 = 6378137.0, 0.00669437999014
    la, lo = np.radians(lat), np.radians(lon)
    nn = a / np.sqrt(1 - e2 * np.sin(la) ** 2)
    ecef = np.stack(((nn + alt) * np.cos(la) * np.cos(lo), (nn + alt) * np.cos(la) * np.sin(lo),
                     (nn * (1 - e2) + alt) * np.sin(la)), -1)
    d_enu = np.linalg.norm(enu[:, None] - enu[None], axis=-1)
    d_ecef = np.linalg.norm(ecef[:, None] - ecef[None], axis=-1)
    np.testing.assert_allclose(d_enu, d_ecef, atol=1e-6)


def test_reflect_single_ray_obeys_the_law_of_reflection():
    g = torch.Generator().manual_seed(1)
    d = normalize(torch.randn(100, 3, generator=g, dtype=DT))
    n = normalize(torch.randn(100, 3, generator=g, dtype=DT))
    r = reflect(d, n)
    torch.testing.assert_close(r.norm(dim=-1), torch.ones(100, dtype=DT))
    # Angle in = angle out: the normal component flips, the tangential one is kept.
    torch.testing.assert_close((r * n).sum(-1), -(d * n).sum(-1))
    torch.testing.assert_close(r - (r * n).sum(-1, keepdim=True) * n, d - (d * n).sum(-1, keepdim=True) * n)
    # Incoming ray, normal and reflected ray are coplanar.
    coplanar = torch.linalg.det(torch.stack((d, n, r), dim=-2))
    torch.testing.assert_close(coplanar, torch.zeros(100, dtype=DT), atol=1e-12, rtol=0)
    # A ray hitting a mirror facing south at 45 deg from above leaves towards the south, upwards.
    down_north = normalize(_t(0.0, 1.0, -1.0))
    torch.testing.assert_close(reflect(down_north, _t(0.0, -1.0, 0.0)), normalize(_t(0.0, -1.0, -1.0)))


def test_plane_axes_convention():
    # A plane facing north (seen from the north): right = west, up = up.
    right, up = plane_axes(_t(0.0, 1.0, 0.0))
    torch.testing.assert_close(right, _t(-1.0, 0.0, 0.0))
    torch.testing.assert_close(up, _t(0.0, 0.0, 1.0))
    # Facing south: right = east. Horizontal (facing up): right = east, up = north.
    torch.testing.assert_close(plane_axes(_t(0.0, -1.0, 0.0))[0], _t(1.0, 0.0, 0.0))
    right, up = plane_axes(_t(0.0, 0.0, 1.0))
    torch.testing.assert_close(right, _t(1.0, 0.0, 0.0))
    torch.testing.assert_close(up, _t(0.0, 1.0, 0.0))
    # Tilted planes: (right, up, normal) is right-handed and orthonormal, right is horizontal.
    g = torch.Generator().manual_seed(2)
    normal = normalize(torch.randn(50, 3, generator=g, dtype=DT))
    right, up = plane_axes(normal)
    frame = torch.stack((right, up, normal), dim=-1)
    torch.testing.assert_close(frame.transpose(-1, -2) @ frame, torch.eye(3, dtype=DT).expand(50, 3, 3))
    torch.testing.assert_close(torch.linalg.det(frame), torch.ones(50, dtype=DT))
    torch.testing.assert_close(right[:, 2], torch.zeros(50, dtype=DT), atol=1e-12, rtol=0)
    assert (up[:, 2] >= -1e-12).all()


def test_rotation_about_axis_is_right_handed():
    r = rotation_about_axis(_t(0.0, 0.0, 1.0), _t(math.pi / 2))
    torch.testing.assert_close(r @ _t(1.0, 0.0, 0.0), _t(0.0, 1.0, 0.0))  # east -> north about up
    axis = normalize(_t(0.3, -0.5, 0.8))
    r = rotation_about_axis(axis, _t(0.7))
    torch.testing.assert_close(r.T @ r, torch.eye(3, dtype=DT))
    torch.testing.assert_close(r @ axis, axis)
