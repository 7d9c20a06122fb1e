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
(`split`): an isotropic part sigma c, c the smallest cos(theta_i) of the batch rounded down to a
multiple of 1/32 (so that the tables are reused), goes into the table, and the remainder
sigma^2 G - 4 sigma^2 c^2 (I - r r^T), positive semi-definite, is a Gaussian applied to the
convolution's spectrum (`gaussian_spectrum`) after mapping it onto the target plane
(`on_plane`). For a Gaussian slope error this is exact; each group of rays takes the mean G of its
rays, as it takes their mean ray for the footprint.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

COS_STEP = 1.0 / 32.0  # the isotropic part's cos(theta_i) is rounded down to a multiple of this


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


def split(spread: Tensor, unit: Tensor, slope_error: float) -> tuple[float, Tensor]:
    """(isotropic slope error for the density table (rad), remainder (B, 3, 3) rad^2): the split of
    the module docstring for B groups' mean G `spread` (B, 3, 3) and mean rays `unit` (B, 3)."""
    across = torch.linalg.eigvalsh(spread.detach().double())[:, 1].clamp(0.0, 4.0)  # 4 cos^2(theta_i)
    cos = math.floor(float(across.min().sqrt()) / 2 / COS_STEP) * COS_STEP if len(across) else 1.0
    cos = max(cos, COS_STEP)  # a grazing ray (theta_i > 88 deg) keeps a little isotropic spread
    plane = torch.eye(3, dtype=unit.dtype, device=unit.device) - unit[:, :, None] * unit[:, None, :]
    return slope_error * cos, slope_error**2 * (spread - 4 * cos**2 * plane)


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


def gaussian_spectrum(covariance: Tensor, shape: tuple[int, int]) -> Tensor:
    """(B, N_r, N_c // 2 + 1) the rfft2 of a Gaussian of covariance (B, 2, 2) in (row, column) cells on
    a periodic grid of shape (N_r, N_c), centred on cell (0, 0): multiplying a spectrum by it
    convolves with the Gaussian (power kept)."""
    rows = torch.fft.fftfreq(shape[0], dtype=covariance.dtype, device=covariance.device)[:, None]
    cols = torch.fft.rfftfreq(shape[1], dtype=covariance.dtype, device=covariance.device)[None, :]
    c = covariance[:, :, :, None, None]
    q = rows**2 * c[:, 0, 0] + 2 * rows * cols * c[:, 0, 1] + cols**2 * c[:, 1, 1]
    return torch.exp(-2 * math.pi**2 * q.clamp_min(0.0))  # >= 0 but for grazing rays (see split)
