"""The slope error's blur of a reflected beam, which is narrower across the plane of incidence.

A random tilt b of the surface normal (per-axis std sigma, the `slope_error`) turns the reflected ray
by 2 b in the plane of incidence but by 2 b cos(theta_i) across it (the derivative of the reflection
law, g_k = -2 [(i.t_k) n + (i.n) t_k] for a tilt along the surface tangent t_k, i the incoming
direction). Per ray the reflected direction's covariance is sigma^2 G with

    G = g_1 g_1^T + g_2 g_2^T = 4 [ |i_p|^2 n n^T + (i.n) (n i_p^T + i_p n^T) + (i.n)^2 (I - n n^T) ],

i_p = i - (i.n) n; G has eigenvalues 4 (in the plane of incidence), 4 cos^2(theta_i) (across it) and
0 (along the reflected ray).

The kernel tracers convolve deposits with a footprint whose angular density, the sun shape convolved
with an isotropic Gaussian, is tabulated radially (sun.radial_density). So the slope error is split
(`split`): an isotropic part sigma c goes into the table, c the group's cos(theta_i) rounded down to
a multiple of 1/LEVELS (a group's own, so that a result does not depend on how rays are batched,
and few tables), and the remainder sigma^2 (G - 4 c^2 (I - r r^T)), positive semi-definite, is
blurred (raytrace.blurred) after mapping it onto the target plane (`on_plane`). For a Gaussian
slope error this is exact; each group of rays takes the mean G of its rays, as it takes their mean
ray for the footprint. The field tracer keeps the isotropic 2 sigma blur (docs/physics.md).
"""

from __future__ import annotations

import torch
from torch import Tensor

LEVELS = 16  # the isotropic part's cos(theta_i) is rounded down to a multiple of 1 / LEVELS


def tilt_covariance(incoming: Tensor, normal: Tensor) -> Tensor:
    """(..., 3, 3) G (module docstring) of unit incoming directions and unit normals (..., 3), in
    their frame: the covariance of the reflected direction per unit variance of the normal's tilt."""
    cos = (incoming * normal).sum(-1)[..., None, None]  # i.n
    perp = incoming - cos[..., 0] * normal
    outer = normal[..., :, None] * normal[..., None, :]
    cross = normal[..., :, None] * perp[..., None, :]
    eye = torch.eye(3, dtype=normal.dtype, device=normal.device)
    return 4 * ((perp * perp).sum(-1)[..., None, None] * outer + cos * (cross + cross.transpose(-1, -2))
                + cos**2 * (eye - outer))


def split(tilt: Tensor, unit: Tensor, slope_error: float) -> tuple[Tensor, Tensor]:
    """(isotropic slope error for the density table (B,) rad, remainder (B, 3, 3) rad^2): the split
    of the module docstring for B groups' mean G `tilt` (B, 3, 3) and mean rays `unit` (B, 3)."""
    across = torch.linalg.eigvalsh(tilt.detach().double())[:, 1].clamp(0.0, 4.0)  # 4 cos^2(theta_i)
    cos = (torch.floor(across.sqrt() / 2 * LEVELS).clamp_min(1.0) / LEVELS).to(unit)  # (B,)
    plane = torch.eye(3, dtype=unit.dtype, device=unit.device) - unit[:, :, None] * unit[:, None, :]
    value, vector = torch.linalg.eigh(tilt - 4 * cos[:, None, None] ** 2 * plane)
    remainder = vector @ torch.diag_embed(value.clamp_min(0.0)) @ vector.transpose(1, 2)  # >= 0 to round-off
    return slope_error * cos, slope_error**2 * remainder


def on_plane(covariance: Tensor, unit: Tensor, path: Tensor) -> Tensor:
    """(B, 2, 2) covariance (m^2) on the target's (right, up) of where rays hit it, for a covariance
    (B, 3, 3) (rad^2) of their directions about the mean ray `unit` (B, 3), all on the target's
    (normal, right, up), at path length `path` (B,) m: a direction change d moves the hit by
    path (d_t - unit_t d_n / unit_n) (the oblique projection along the ray)."""
    zero, one = torch.zeros_like(path), torch.ones_like(path)
    slant = -unit[:, 1:] / unit[:, :1]  # (B, 2)
    m = torch.stack((torch.stack((slant[:, 0], one, zero), -1), torch.stack((slant[:, 1], zero, one), -1)), 1)
    return path[:, None, None] ** 2 * (m @ covariance @ m.transpose(1, 2))


def in_cells(covariance: Tensor, cell: Tensor) -> Tensor:
    """(B, 2, 2) covariance on the target's (right, up) (m^2) in (row, column) cells of a grid whose
    rows run down: cell (B, 2) cell width and height (m)."""
    scale = torch.stack((-1.0 / cell[:, 1], 1.0 / cell[:, 0]), -1)  # row = -up / height, column = right / width
    swapped = covariance.flip(-1, -2)  # (up, right) order
    return swapped * scale[:, :, None] * scale[:, None, :]
