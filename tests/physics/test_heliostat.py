"""Heliostat kinematics, facet frames and canting, B-spline surfaces."""

import math

import numpy as np
import pytest
import torch
from support.heliostats import make_heliostat

from helioflow.physics.geometry import normalize, sun_vector
from helioflow.physics.heliostat import (
    MOUNTS,
    REST_FRAME,
    bspline_basis,
    canting_focal_distance,
    facet_frames,
    facet_layout,
    ideal_heliostat,
    ideal_joint_angles,
    joint_rotation,
    on_axis_canting,
    orientation,
    sample_surface,
    without_planes,
)

DT = torch.float64


def _upper_hemisphere(n: int, seed: int) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    v = normalize(torch.randn(n, 3, generator=g, dtype=DT))
    v[:, 2] = v[:, 2].abs() + 0.05  # stay off the horizon
    return normalize(v)


def test_rest_frame_faces_south():
    torch.testing.assert_close(REST_FRAME[:, 0], torch.tensor([1.0, 0, 0], dtype=DT))  # right = east
    torch.testing.assert_close(REST_FRAME[:, 1], torch.tensor([0.0, 0, 1], dtype=DT))  # up = up
    torch.testing.assert_close(REST_FRAME[:, 2], torch.tensor([0.0, -1, 0], dtype=DT))  # normal = south


@pytest.mark.parametrize("mount", MOUNTS)
def test_ideal_joint_angles_reproduce_the_commanded_normal(mount):
    normal = _upper_hemisphere(500, seed=3)
    a1, a2 = ideal_joint_angles(mount, normal)
    rot = joint_rotation(mount, a1, a2, torch.zeros(5, dtype=DT)) @ REST_FRAME
    torch.testing.assert_close(rot[..., 2], normal, atol=1e-12, rtol=0)
    torch.testing.assert_close(rot.transpose(-1, -2) @ rot, torch.eye(3, dtype=DT).expand(500, 3, 3))
    torch.testing.assert_close(torch.linalg.det(rot), torch.ones(500, dtype=DT))


@pytest.mark.parametrize("mount", MOUNTS)
def test_orientation_of_an_ideal_heliostat_bisects_sun_and_aim(mount):
    h = make_heliostat(mount=mount, position=(10.0, 60.0, 2.0))
    aim = torch.tensor([0.0, 0.0, 20.0], dtype=DT)
    az = torch.tensor([-1.2, -0.3, 0.0, 0.4, 1.5], dtype=DT)
    el = torch.tensor([0.2, 0.5, 1.0, 0.7, 0.1], dtype=DT)
    sun = sun_vector(az, el)
    rot = orientation(h, sun, aim)
    to_aim = normalize(aim - h.position)
    normal = rot[..., 2]
    torch.testing.assert_close(normal, normalize(sun + to_aim), atol=1e-12, rtol=0)
    # The reflected central sun ray goes to the aim point.
    reflected = -sun - 2 * (-sun * normal).sum(-1, keepdim=True) * normal
    torch.testing.assert_close(reflected, to_aim.expand_as(reflected), atol=1e-12, rtol=0)


@pytest.mark.parametrize("mount, which", [("az_el", 0), ("az_el", 1), ("juelich", 0), ("juelich", 1)])
def test_joint_offset_tilts_the_normal_by_the_offset_times_the_lever(mount, which):
    """An offset e on a joint turns the normal by e |axis x normal|: for az_el's azimuth axis that
    is e cos(elevation of the normal); for the second (elevation / tilt) axis it is e."""
    normal = _upper_hemisphere(200, seed=4)
    a1, a2 = ideal_joint_angles(mount, normal)
    e = 1e-3
    err = torch.zeros(5, dtype=DT)
    err[which] = e
    tilted = (joint_rotation(mount, a1, a2, err) @ REST_FRAME)[..., 2]
    angle = torch.linalg.cross(normal, tilted).norm(dim=-1).asin()
    if mount == "az_el" and which == 0:
        expected = e * torch.sqrt(1 - normal[:, 2] ** 2)  # e cos(elevation)
    elif which == 0:  # juelich: first joint about the fixed east axis
        expected = e * torch.sqrt(1 - normal[:, 0] ** 2)
    else:  # second joint: the normal is perpendicular to its axis
        expected = torch.full_like(angle, e)
    torch.testing.assert_close(angle, expected, atol=1e-9, rtol=1e-3)


def test_pedestal_tilts_move_the_normal_east_and_north():
    normal = torch.tensor([[0.0, -math.cos(0.6), math.sin(0.6)]], dtype=DT)
    a1, a2 = ideal_joint_angles("az_el", normal)
    for index, axis in ((2, 0), (3, 1)):  # tilt east moves the normal east, tilt north moves it north
        err = torch.zeros(5, dtype=DT)
        err[index] = 1e-3
        moved = (joint_rotation("az_el", a1, a2, err) @ REST_FRAME)[0, :, 2] - normal[0]
        assert moved[axis] > 0.5e-3 * math.sin(0.6)


def test_bspline_basis_partition_of_unity_and_derivative():
    x = np.linspace(0.0, 1.0, 1001)
    for n_control in (4, 6, 9):
        b, db = bspline_basis(x, n_control)
        assert b.shape == db.shape == (1001, n_control)
        np.testing.assert_allclose(b.sum(1), 1.0, atol=1e-12)
        np.testing.assert_allclose(db.sum(1), 0.0, atol=1e-9)
        assert (b >= -1e-15).all()
        # Clamped: the curve starts at the first and ends at the last control point.
        np.testing.assert_allclose(b[0], np.eye(n_control)[0], atol=1e-12)
        np.testing.assert_allclose(b[-1], np.eye(n_control)[-1], atol=1e-9)
        # Derivative against central differences (away from the clamped ends).
        xm = np.linspace(0.01, 0.99, 97)
        h = 1e-6
        fd = (bspline_basis(xm + h, n_control)[0] - bspline_basis(xm - h, n_control)[0]) / (2 * h)
        np.testing.assert_allclose(bspline_basis(xm, n_control)[1], fd, atol=1e-5 * n_control**2)


def test_sample_surface_of_ideal_flat_facets():
    h = make_heliostat(rows=2, cols=3, width=1.2, height=0.8)
    s = sample_surface(h, 8)
    n_points = 6 * 64
    assert s.points.shape == (n_points, 3) and s.normals.shape == (n_points, 3)
    torch.testing.assert_close(s.normals, torch.tensor([0.0, 0, 1], dtype=DT).expand(n_points, 3))
    torch.testing.assert_close(s.points[:, 2], torch.zeros(n_points, dtype=DT))
    torch.testing.assert_close(s.area.sum(), torch.tensor(6 * 1.2 * 0.8, dtype=DT))
    # The cells tile each facet: the mean cell centre is the facet centre.
    torch.testing.assert_close(s.points.reshape(6, 64, 3).mean(1), h.facet_translation)
    # A constant deformation only lifts the facet (partition of unity): normals unchanged.
    h.control_heights = torch.full_like(h.control_heights, 2e-3)
    s = sample_surface(h, 8)
    torch.testing.assert_close(s.normals, torch.tensor([0.0, 0, 1], dtype=DT).expand(n_points, 3))
    torch.testing.assert_close(s.points[:, 2], torch.full((n_points,), 2e-3, dtype=DT))


def test_sample_surface_normals_are_unit_and_match_the_slopes():
    h = make_heliostat(rows=1, cols=2, focal=20.0, canting=20.0)
    g = torch.Generator().manual_seed(5)
    h.control_heights = torch.randn(h.control_heights.shape, generator=g, dtype=DT) * 1e-3
    h.canting_error = torch.randn(2, 2, generator=g, dtype=DT) * 1e-3
    s = sample_surface(h, 16)
    torch.testing.assert_close(s.normals.norm(dim=-1), torch.ones(len(s.normals), dtype=DT))
    # The normal is perpendicular to the surface: check against finite differences of the points
    # sampled on a much finer grid (neighbouring cells along facet right).
    fine = sample_surface(h, 512).points.reshape(2, 512, 512, 3)
    tangent_right = fine[:, :, 1:] - fine[:, :, :-1]  # (F, up, right-1, 3)
    tangent_up = fine[:, :-1] - fine[:, 1:]
    nf = sample_surface(h, 512).normals.reshape(2, 512, 512, 3)
    mid_r = 0.5 * (nf[:, :, 1:] + nf[:, :, :-1])
    mid_u = 0.5 * (nf[:, :-1] + nf[:, 1:])
    cos_r = (normalize(tangent_right) * mid_r).sum(-1)
    cos_u = (normalize(tangent_up) * mid_u).sum(-1)
    assert cos_r.abs().max() < 1e-5 and cos_u.abs().max() < 1e-5


def test_on_axis_canting_points_the_normals_at_twice_the_focal_length():
    tr, _ = facet_layout(3, 4, 1.0, 0.8, 0.05)
    f = 35.0
    n = on_axis_canting(tr, f)
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0)
    to_point = np.array([0.0, 0.0, 2 * f]) - tr
    np.testing.assert_allclose(np.cross(n, to_point), 0.0, atol=1e-12)
    assert (n[:, 2] > 0).all()
    np.testing.assert_allclose(on_axis_canting(tr, None), np.tile([0.0, 0.0, 1.0], (12, 1)))
    # The facet centres' normals match the slope of the paraboloid z = r^2 / (4 f): (-x/2f, -y/2f, 1).
    slope = np.stack((-tr[:, 0] / (2 * f), -tr[:, 1] / (2 * f), np.ones(12)), -1)
    np.testing.assert_allclose(n, slope / np.linalg.norm(slope, axis=1, keepdims=True), atol=1e-12)


def test_facet_layout_and_canting_error_directions():
    tr, sz = facet_layout(2, 3, 1.0, 0.5, 0.1)
    np.testing.assert_allclose(tr[0], [-1.1, 0.3, 0.0])  # row-major from the top-left
    np.testing.assert_allclose(tr[-1], [1.1, -0.3, 0.0])
    np.testing.assert_allclose(tr.mean(0), 0.0, atol=1e-15)
    np.testing.assert_allclose(sz, np.tile([1.0, 0.5], (6, 1)))
    normal = torch.tensor([[0.0, 0.0, 1.0]] * 2, dtype=DT)
    e = 2e-3
    frames = facet_frames(normal, torch.tensor([[e, 0.0], [0.0, e]], dtype=DT))
    torch.testing.assert_close(frames.transpose(-1, -2) @ frames, torch.eye(3, dtype=DT).expand(2, 3, 3))
    # canting_error[:, 0] moves the normal up (+y), canting_error[:, 1] moves it right (+x), by atan(e) ~ e.
    moved = math.sin(math.atan(e))
    assert frames[0, 1, 2].item() == pytest.approx(moved, rel=1e-9) and abs(frames[0, 0, 2]) < 1e-15
    assert frames[1, 0, 2].item() == pytest.approx(moved, rel=1e-9) and abs(frames[1, 1, 2]) < 1e-15


@pytest.mark.parametrize("distance", [None, 63.0, 200.0])
def test_canting_distance_recovered_from_facet_normals(distance):
    h = ideal_heliostat(rows=4, cols=6, width=0.8, height=0.6, gap=0.02, canting_focal_distance=distance)
    found = canting_focal_distance(h)
    if distance is None:
        assert found is None
    else:
        assert found == pytest.approx(distance, rel=1e-3)


def test_surface_shape_has_no_mean_height_or_mean_slope():
    heights = without_planes(torch.randn(3, 6, 6, generator=torch.Generator().manual_seed(0), dtype=torch.float64))
    b, db = (torch.as_tensor(a) for a in bspline_basis((np.arange(400) + 0.5) / 400, 6))
    surface = torch.einsum("gi,fij,hj->fgh", b, heights, b)  # (F, 401, 401) over the unit facet
    slope_u = torch.einsum("gi,fij,hj->fgh", db, heights, b)
    slope_v = torch.einsum("gi,fij,hj->fgh", b, heights, db)
    for field in (surface, slope_u, slope_v):
        assert field.mean((-2, -1)).abs().max() < 1e-3 * heights.abs().max()
    assert torch.allclose(without_planes(heights), heights, atol=1e-12)  # a projection
