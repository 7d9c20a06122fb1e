"""A slow, plainly exact reference tracer, to check the fast tracer (raytrace.py) against.

Why it exists: raytrace.trace buys its speed with approximations that are easy to get subtly
wrong — surface normals held constant over a sampling cell, ray directions perturbed to first
order in the sun and slope angles and projected onto the target once per cell, a recycled pool
of random numbers, FFT footprints. This module traces every ray from scratch with none of that,
in plain numpy, one line of physics per step, so that a disagreement between the two points at
the fast tracer (or at a shared convention, which the geometry and heliostat tests pin down).

Per ray:
  1. a facet with probability proportional to its area, a uniform point on it;
  2. the exact surface point and normal there: facet paraboloid (x^2 + y^2) / (4 f) plus the
     B-spline deformation (heliostat.bspline_basis at that point, analytic slopes), placed by the
     facet frame (heliostat.facet_frames: canting and canting error) and rotated into ENU by the
     heliostat's kinematics (heliostat.orientation, tested separately);
  3. the incoming direction: the sun's central direction turned by an exact rotation through a
     sun-shape deviation (sun.sample_deviations);
  4. the normal turned by an exact rotation through an isotropic N(0, slope_error) tilt about
     two tangent axes;
  5. the full reflection law r = d - 2 (d.n) n, the exact ray-plane intersection;
  6. a bilinear (tent) splat into the pixel centres: flux = power / pixel area, with
     power = dni * reflectivity * total mirror area * cos(incidence at the point) / n_rays
     (incidence between the central sun direction and the unperturbed surface normal), times
     the transmittance of the heliostat-to-target-centre slant range if one is given.

Its expected image equals the fast tracer's (both are the flux tent-averaged over pixels); only
the Monte Carlo noise differs.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from helioflow.physics.heliostat import Heliostat, bspline_basis, facet_frames, orientation
from helioflow.physics.raytrace import MirrorPoints
from helioflow.physics.sun import sample_deviations
from helioflow.physics.target import Target

BLOCK = 200_000  # rays traced at once


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _np(t: torch.Tensor) -> np.ndarray:
    return t.detach().cpu().double().numpy()


def _perpendicular_basis(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors perpendicular to unit v (3,) and to each other."""
    helper = np.array([1.0, 0.0, 0.0]) if abs(v[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = _unit(np.cross(v, helper))
    return e1, np.cross(v, e1)


def _rotate_towards(v: np.ndarray, tangent: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """Rotate unit vectors v (N, 3) by `angle` (N,) towards the unit tangents (N, 3) (perpendicular to v)."""
    return np.cos(angle)[:, None] * v + np.sin(angle)[:, None] * tangent


def reference_trace(
    heliostat: Heliostat,
    target: Target,
    azimuth_rad: float,
    elevation_rad: float,
    optics,
    n_rays: int,
    seed: int,
    aim_point=None,
) -> np.ndarray:
    """Flux image (H, W) in W/m^2 of one heliostat at one sun position, by exact per-ray tracing.

    Args:
        heliostat: the heliostat (any float dtype; evaluated in float64).
        target: the target plane and its pixel grid.
        azimuth_rad, elevation_rad: sun position (azimuth 0 = south, +pi/2 = east).
        optics: raytrace.Optics (sun shape, slope error, dni, reflectivity, transmittance, mirror mask).
        n_rays: number of rays.
        seed: seeds both the numpy generator and the torch generator of the sun deviations.
        aim_point: (3,) ENU aim point; default the target's (Target.aim_point).

    Returns:
        (H, W) float64 array, tent-averaged flux per pixel, rows top-first.
    """
    rng = np.random.default_rng(seed)
    torch_gen = torch.Generator().manual_seed(seed)

    # Sun, kinematics (independent ENU formula for the sun: east, north, up).
    ce = math.cos(elevation_rad)
    sun = np.array([ce * math.sin(azimuth_rad), -ce * math.cos(azimuth_rad), math.sin(elevation_rad)])
    aim = target.aim_point if aim_point is None else torch.as_tensor(aim_point)
    aim = aim.to(torch.float64)
    helio64 = heliostat.to("cpu", torch.float64)
    rot = _np(orientation(helio64, torch.as_tensor(sun)[None], aim)[0])  # heliostat frame -> ENU
    position = _np(helio64.position)

    # Facets.
    size = _np(helio64.facet_size)  # (F, 2)
    translation = _np(helio64.facet_translation)  # (F, 3)
    # (F, 3, 3), columns = facet right, up, normal in the heliostat frame
    frames = _np(facet_frames(helio64.facet_normal, helio64.canting_error))
    control = _np(helio64.control_heights)  # (F, C, C) [row along up (top first), column along right]
    n_control = control.shape[-1]
    focal = heliostat.facet_focal_length
    area = size[:, 0] * size[:, 1]
    area_total = area.sum()

    # Target plane (independent of geometry.plane_axes: right = up x normal, or east if horizontal).
    centre, t_normal = _np(target.center), _unit(_np(target.normal))
    right = np.cross([0.0, 0.0, 1.0], t_normal)
    right = np.array([1.0, 0.0, 0.0]) if np.linalg.norm(right) < 1e-9 else _unit(right)
    up = np.cross(t_normal, right)
    rows, cols = target.resolution
    pw, ph = target.width / cols, target.height / rows

    transmittance = 1.0
    if optics.transmittance is not None:
        slant = torch.as_tensor(np.linalg.norm(centre - position), dtype=torch.float64)
        transmittance = float(optics.transmittance(slant))
    power_per_ray = optics.dni * optics.reflectivity * area_total * transmittance / n_rays
    e1, e2 = _perpendicular_basis(sun)

    image = np.zeros(rows * cols)
    for start in range(0, n_rays, BLOCK):
        n = min(BLOCK, n_rays - start)
        # 1. facet and point: parameters (s_up, s_right) uniform on [0, 1]^2.
        facet = rng.choice(len(area), size=n, p=area / area_total)
        s_right, s_up = rng.random(n), rng.random(n)
        w, h = size[facet, 0], size[facet, 1]
        x, y = (s_right - 0.5) * w, (0.5 - s_up) * h  # along facet right, up

        # 2. exact height and slopes; z(s_up, s_right) = sum_ij B_i(s_up) C_ij B_j(s_right).
        b_up, db_up = bspline_basis(s_up, n_control)
        b_right, db_right = bspline_basis(s_right, n_control)
        c = control[facet]  # (n, C, C)
        z = np.einsum("ni,nij,nj->n", b_up, c, b_right)
        dz_dx = np.einsum("ni,nij,nj->n", b_up, c, db_right) / w  # d s_right / dx = 1 / w
        dz_dy = -np.einsum("ni,nij,nj->n", db_up, c, b_right) / h  # d s_up / dy = -1 / h
        if focal is not None:
            z = z + (x**2 + y**2) / (4.0 * focal)
            dz_dx = dz_dx + x / (2.0 * focal)
            dz_dy = dz_dy + y / (2.0 * focal)
        local_point = np.stack((x, y, z), -1)
        local_normal = _unit(np.stack((-dz_dx, -dz_dy, np.ones(n)), -1))
        f_frame = frames[facet]  # (n, 3, 3)
        point_h = translation[facet] + np.einsum("nij,nj->ni", f_frame, local_point)
        normal_h = np.einsum("nij,nj->ni", f_frame, local_normal)
        point = position + point_h @ rot.T
        normal = _unit(normal_h @ rot.T)
        cos_incidence = np.clip(normal @ sun, 0.0, None)

        # 3. incoming direction: the sun direction rotated by the deviation's length towards its direction.
        dev = sample_deviations(optics.sun, n, torch_gen, dtype=torch.float64).numpy()  # (n, 2) rad
        dev_len = np.linalg.norm(dev, axis=1)
        dev_dir = np.where(dev_len[:, None] > 0, dev / np.maximum(dev_len, 1e-300)[:, None], 0.0)
        towards = dev_dir[:, :1] * e1 + dev_dir[:, 1:] * e2
        to_sun = _rotate_towards(np.broadcast_to(sun, (n, 3)), towards, dev_len)
        incoming = -to_sun

        # 4. slope error: the normal rotated by |b| towards b1 t1 + b2 t2, b ~ N(0, slope_error^2 I).
        if optics.slope_error > 0:
            b = rng.standard_normal((n, 2)) * optics.slope_error
            facet_right = f_frame[:, :, 0] @ rot.T  # any tangent basis will do: the tilt is isotropic
            t1 = _unit(facet_right - np.sum(facet_right * normal, axis=1, keepdims=True) * normal)
            t2 = np.cross(normal, t1)
            b_len = np.linalg.norm(b, axis=1)
            b_dir = np.where(b_len[:, None] > 0, b / np.maximum(b_len, 1e-300)[:, None], 0.0)
            normal_ray = _rotate_towards(normal, b_dir[:, :1] * t1 + b_dir[:, 1:] * t2, b_len)
        else:
            normal_ray = normal

        # 5. reflection and intersection with the target plane.
        reflected = incoming - 2.0 * np.sum(incoming * normal_ray, axis=1, keepdims=True) * normal_ray
        approach = reflected @ t_normal
        with np.errstate(divide="ignore", invalid="ignore"):
            t = ((centre - point) @ t_normal) / approach
        hit_ok = (approach < 0) & (t > 0)
        hit = point + np.where(hit_ok, t, 0.0)[:, None] * reflected
        u, v = (hit - centre) @ right, (hit - centre) @ up

        # 6. tent splat: continuous pixel indices, pixel (i, j) centred at (i, j).
        col = (u + target.width / 2) / pw - 0.5
        row = (target.height / 2 - v) / ph - 0.5
        power = np.where(hit_ok, power_per_ray * cos_incidence, 0.0)
        if optics.mirror_mask is not None:  # each ray's own point, incoming and reflected direction
            at = [torch.as_tensor(a) for a in (point_h, point, to_sun, reflected)]
            mask = optics.mirror_mask(MirrorPoints(at[0], at[1], at[2], at[3], aim, torch.as_tensor(sun)[None]))
            power = power * mask.double().numpy()
        c0, r0 = np.floor(col), np.floor(row)
        fc, fr = col - c0, row - r0
        corners = ((0, 0, (1 - fr) * (1 - fc)), (0, 1, (1 - fr) * fc), (1, 0, fr * (1 - fc)), (1, 1, fr * fc))
        for dr, dc, weight in corners:
            rr, cc = r0 + dr, c0 + dc
            inside = hit_ok & (rr >= 0) & (rr < rows) & (cc >= 0) & (cc < cols)
            pixel = (rr[inside] * cols + cc[inside]).astype(np.int64)
            image += np.bincount(pixel, weights=(power * weight)[inside], minlength=rows * cols)
    return image.reshape(rows, cols) / (pw * ph)
