"""Frames and rotations in the local east-north-up (ENU) frame.

Axes: x = east, y = north, z = up, metres, origin at the tower base. Sun position: azimuth 0 =
south, +90 deg = east, -90 deg = west; elevation above the horizon (PAINT's and ARTIST's
convention). Angles are radians here; config and files carry degrees.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import Tensor

EAST, NORTH, UP = 0, 1, 2

WGS84_A = 6378137.0  # semi-major axis (m)
WGS84_F = 1.0 / 298.257223563  # flattening
WGS84_E2 = WGS84_F * (2.0 - WGS84_F)  # first eccentricity squared


def sun_vector(azimuth: Tensor, elevation: Tensor) -> Tensor:
    """Unit vector from the ground towards the sun.

    Args:
        azimuth: (...) rad, 0 = south, +pi/2 = east.
        elevation: (...) rad above the horizon.

    Returns:
        (..., 3) ENU unit vector: east = cos(el) sin(az), north = -cos(el) cos(az), up = sin(el).
        The incoming ray direction is its negative.
    """
    ce = torch.cos(elevation)
    return torch.stack((ce * torch.sin(azimuth), -ce * torch.cos(azimuth), torch.sin(elevation)), dim=-1)


def azimuth_elevation(vector: Tensor) -> tuple[Tensor, Tensor]:
    """Inverse of :func:`sun_vector` for (..., 3) vectors (any length): (azimuth, elevation) in rad."""
    v = vector / vector.norm(dim=-1, keepdim=True)
    return torch.atan2(v[..., EAST], -v[..., NORTH]), torch.asin(v[..., UP].clamp(-1.0, 1.0))


def normalize(v: Tensor) -> Tensor:
    """(..., 3) vectors scaled to unit length."""
    return v / v.norm(dim=-1, keepdim=True)


def reflect(direction: Tensor, normal: Tensor) -> Tensor:
    """Mirror reflection d - 2 (d.n) n of (..., 3) directions about (..., 3) unit normals."""
    return direction - 2.0 * (direction * normal).sum(-1, keepdim=True) * normal


def rotation_about_axis(axis: Tensor, angle: Tensor) -> Tensor:
    """Rodrigues rotation matrices.

    Args:
        axis: (3,) or (..., 3) unit axis.
        angle: (...) rad, right-handed about the axis.

    Returns:
        (..., 3, 3) rotation matrices R with R @ v rotating v about the axis.
    """
    axis = axis.expand(*angle.shape, 3)
    x, y, z = axis.unbind(-1)
    c, s = torch.cos(angle), torch.sin(angle)
    t = 1.0 - c
    rows = (
        torch.stack((t * x * x + c, t * x * y - s * z, t * x * z + s * y), -1),
        torch.stack((t * x * y + s * z, t * y * y + c, t * y * z - s * x), -1),
        torch.stack((t * x * z - s * y, t * y * z + s * x, t * z * z + c), -1),
    )
    return torch.stack(rows, dim=-2)


def plane_axes(normal: Tensor) -> tuple[Tensor, Tensor]:
    """In-plane axes (right, up) of a plane with (..., 3) unit `normal`.

    right = up x normal: horizontal, pointing to the right of a viewer standing in front of the
    plane and looking at it (against the normal) — as the calibration camera in the field sees
    the target; east when the plane is horizontal. up = normal x right (the in-plane up).
    Image columns run along `right`, rows along `up` (top row highest).
    """
    z = torch.zeros_like(normal)
    z[..., UP] = 1.0
    right = torch.cross(z, normal, dim=-1)
    horizontal_plane = right.norm(dim=-1, keepdim=True) < 1e-9
    east = torch.zeros_like(normal)
    east[..., EAST] = 1.0
    right = normalize(torch.where(horizontal_plane, east, right))
    return right, torch.cross(normal, right, dim=-1)


def wgs84_to_enu(lat_deg, lon_deg, alt_m, ref_lat_deg: float, ref_lon_deg: float, ref_alt_m: float) -> np.ndarray:
    """WGS84 geodetic coordinates -> local ENU metres around a reference point (exact, via ECEF).

    Args:
        lat_deg, lon_deg, alt_m: arrays of equal shape (...) or scalars; degrees and metres.
        ref_lat_deg, ref_lon_deg, ref_alt_m: origin of the local frame.

    Returns:
        (..., 3) float64 array (east, north, up) in metres.
    """
    xyz = _ecef(np.asarray(lat_deg, float), np.asarray(lon_deg, float), np.asarray(alt_m, float))
    ref = _ecef(np.float64(ref_lat_deg), np.float64(ref_lon_deg), np.float64(ref_alt_m))
    d = xyz - ref
    lat0, lon0 = math.radians(ref_lat_deg), math.radians(ref_lon_deg)
    sl, cl, sp, cp = math.sin(lon0), math.cos(lon0), math.sin(lat0), math.cos(lat0)
    east = -sl * d[..., 0] + cl * d[..., 1]
    north = -sp * cl * d[..., 0] - sp * sl * d[..., 1] + cp * d[..., 2]
    up = cp * cl * d[..., 0] + cp * sl * d[..., 1] + sp * d[..., 2]
    return np.stack((east, north, up), axis=-1)


def _ecef(lat_deg: np.ndarray | np.floating, lon_deg: np.ndarray | np.floating,
          alt_m: np.ndarray | np.floating) -> np.ndarray:
    lat, lon = np.radians(lat_deg), np.radians(lon_deg)
    n = WGS84_A / np.sqrt(1.0 - WGS84_E2 * np.sin(lat) ** 2)
    return np.stack(
        (
            (n + alt_m) * np.cos(lat) * np.cos(lon),
            (n + alt_m) * np.cos(lat) * np.sin(lon),
            (n * (1.0 - WGS84_E2) + alt_m) * np.sin(lat),
        ),
        axis=-1,
    )
