"""Carrying a heliostat's focal spot from the calibration target to the receiver.

A learned model knows a heliostat's spot on the calibration target (centre C_c, the heliostat's
aim point during calibration) for any sun position. In the field the heliostat at pivot h aims at
its aim point A on the receiver for a design sun s_d (unit vector towards the sun); the controller
commands the mirror normal n = (s_d + t_r) / |s_d + t_r|, t_r = (A - h) / |A - h|.

1. Equivalent calibration sun. For s_eq = 2 (n.t_c) n - t_c, t_c = (C_c - h) / |C_c - h|, the
   heliostat aiming at the calibration target commands the same normal n, so the same joint
   angles: the real heliostat takes the same pose, and its tracking, canting and surface errors
   act on its mirror as they do at the design point. The model is asked for the spot at s_eq
   (`equivalent_sun`); s_eq below the horizon has no calibration image that could stand in.

2. Directions near a beam t are written in gnomonic coordinates a = (d.e1, d.e2) / (d.t) (rad) in
   an orthonormal basis (e1, e2) of the plane normal to t. The spot on the target, seen from the
   pivot, has a power-weighted centroid c (the pointing error: an ideal heliostat's central ray
   hits C_c, a = 0) and a shape a - c around it. They are carried differently:

   - pointing, as a normal error: a normal error dn (normal to n) turns the reflected ray by
     L_s dn = 2 (dn.s) n + 2 (n.s) dn, which depends on the incidence, so the centroid is carried
     as c_r = L_{s_d} L_{s_eq}^-1 c (exact to first order for tracking and canting errors);
   - shape, as lengths: the spot of a flat or slightly curved mirror is mostly its outline,
     projected along the beam and blurred by the sun shape and slope error. A point D_c (a - c) of
     the plane normal to t_c (D_c = |C_c - h|) is moved along t_c into the mirror plane (normal n)
     and projected along t_r onto the plane normal to t_r: K. Exact for the outline; the blur, an
     angle, comes out scaled by D_c instead of D_r = |A - h|. When D_r > D_c the missing blur is
     added as a Gaussian of std spread * sqrt(D_r^2 - D_c^2) (m) on the receiver (exact for
     Gaussian spreads, and for the variance of any other). `spread` is the per-axis std (rad) of
     the core of the beam spread the caller believes in (`core_spread`): a Buie sun's aureole
     holds a tenth of the power but dominates its second moment, and blurring by it flattens the
     peaks by ~9 %.
     A receiver nearer than the target would need a deconvolution, which is not attempted.

   So b = c_r + K (a - c) D_c / D_r: receiver directions b are mapped back to target directions a.

3. Resampling (`carry_spot`). Each receiver pixel centre is mapped back to a point on the target,
   the target flux is read there (bilinear, `oversample`^2 points per pixel) and multiplied by
   |det d(u_c, v_c) / d(u_r, v_r)| (finite differences over the pixel grid), so power is
   conserved up to what falls outside either plane.

4. Power. The target flux carries the sunlight of incidence n.s_eq; at the design point the
   mirror receives n.s_d: the carried spot is scaled by (n.s_d) / (n.s_eq). What the
   single-heliostat calibration never saw (shading, blocking, the change of atmospheric
   transmittance from D_c to D_r) is for the caller to apply.

Measured carrying error (true spot traced on the target, carried, against the true spot traced
on the receiver; flat 2 m x 2 m heliostats 45 to 110 m from a tower with the target 20 m and the
receiver 35 m up, 1 mrad tracking errors, sun at (0, 60), (75, 30), (-75, 30) deg;
tests/physics/test_carry.py): with 0.5 mm surface deformation flux accuracy 0.944-0.968 (0.939-0.953
without the extra blur), peak flux within -4 % to -1 % (0 to +4 % without); an undeformed mirror
0.983-0.988 (0.965-0.974 without). The floor between the two tracers themselves (raytrace kernel on
the target, field_flux on the receiver) is 0.97-0.98. Carrying the whole spot as angles instead
(with L_{s_d} L_{s_eq}^-1, or with the rotation taking t_c to t_r) gave 0.64-0.93: it scales the
mirror's outline by D_r / D_c and distorts it by the change of incidence.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import Tensor

from helioflow.physics.geometry import normalize, plane_axes
from helioflow.physics.sun import BUIE_DISC_MRAD, SunShape, effective_sigma, radial_density
from helioflow.physics.target import Target, gaussian_blur


def core_spread(sun: SunShape, slope_error: float) -> float:
    """Per-axis std (rad) of the core of the beam spread: the sun shape's (a Buie sun's disc only)
    with twice the slope error in quadrature. A Buie sun's aureole, a CSR share of the power
    spread over 40 mrad, is a faint haze whose change of scale hardly moves the flux, but it
    dominates the second moment (4.4 mrad at CSR 0.1 against 2.2 mrad for the disc)."""
    if sun.kind == "buie":
        theta = torch.linspace(0.0, BUIE_DISC_MRAD * 1e-3, 4001, dtype=torch.float64)
        weight = radial_density(sun)(theta) * theta
        sigma = math.sqrt(
            float(torch.trapezoid(weight * theta**2, theta) / torch.trapezoid(weight, theta)) / 2
        )
    else:
        sigma = effective_sigma(sun)
    return math.hypot(sigma, 2 * slope_error)


def commanded_normal(position: Tensor, aim: Tensor, sun: Tensor) -> Tensor:
    """(3,) unit mirror normal the controller commands: bisector of the sun vector (3,) and the
    direction from the pivot (3,) m to the aim point (3,) m."""
    return normalize(sun + normalize(aim - position))


def equivalent_sun(position: Tensor, aim: Tensor, sun: Tensor, target_centre: Tensor) -> Tensor:
    """(3,) unit sun vector s_eq for which the heliostat at `position`, aiming at the calibration
    target centre, commands the normal it commands aiming at `aim` under `sun` (module docstring)."""
    n = commanded_normal(position, aim, sun)
    t = normalize(target_centre - position)
    return normalize(2 * (n @ t) * n - t)


def _reflection_map(n: Tensor, sun: Tensor, beam: Tensor) -> Tensor:
    """(2, 2) L_s: normal errors (basis plane_axes(n)) -> reflected-ray turns (basis plane_axes(beam))."""
    g = torch.stack(plane_axes(n))  # (2, 3)
    turned = 2 * (g @ sun)[:, None] * n + 2 * (n @ sun) * g  # (2, 3): L_s g_j
    return torch.stack(plane_axes(beam)) @ turned.T


def _outline_map(n: Tensor, beam_c: Tensor, beam_r: Tensor) -> Tensor:
    """(2, 2) K: lengths normal to beam_c -> along beam_c into the mirror plane -> projected normal to beam_r."""
    e = torch.stack(plane_axes(beam_c))  # (2, 3)
    lifted = e - (e @ n)[:, None] / (beam_c @ n) * beam_c
    projected = lifted - (lifted @ beam_r)[:, None] * beam_r
    return torch.stack(plane_axes(beam_r)) @ projected.T


def _gnomonic(points: Tensor, origin: Tensor, beam: Tensor) -> Tensor:
    """(..., 3) points -> (..., 2) gnomonic coordinates of their directions from `origin` about `beam`."""
    d = points - origin
    e = torch.stack(plane_axes(beam))  # (2, 3)
    return (d @ e.T) / (d @ beam)[..., None]


def _plane_points(target: Target, oversample: int, dtype) -> Tensor:
    """(H * k, W * k, 3) ENU points at the centres of each pixel's k x k sub-pixels (k = oversample)."""
    rows, cols = target.resolution
    fine = Target(
        target.center, target.normal, target.width, target.height, (rows * oversample, cols * oversample)
    )
    u, v = fine.pixel_centres(dtype, target.center.device)
    right, up = (a.to(dtype) for a in target.axes())
    return target.center.to(dtype) + u[None, :, None] * right + v[:, None, None] * up


def carry_spot(
    image: Tensor,
    target: Target,
    receiver: Target,
    position: Tensor,
    aim: Tensor,
    sun: Tensor,
    spread: float = 0.0,
    oversample: int = 2,
) -> Tensor:
    """The spot `image` on the calibration target, carried to the receiver (module docstring).

    Args:
        image: (Hc, Wc) flux (W/m^2) on `target` for the equivalent sun (equivalent_sun), with the
            heliostat aimed at the target centre.
        target, receiver: the two planes (image conventions of physics.target).
        position: (3,) pivot (m); aim: (3,) aim point on the receiver (m); sun: (3,) design sun vector.
        spread: per-axis std (rad) of the beam's angular spread, for the blur the longer path adds.
        oversample: sub-pixels per receiver pixel side at which the target flux is read.

    Returns:
        (Hr, Wr) flux (W/m^2) on the receiver, scaled by the change of incidence n.s_d / n.s_eq.
    """
    dtype = image.dtype
    position, aim, sun = (x.to(dtype) for x in (position, aim, sun))
    centre, normal = target.center.to(dtype), target.normal.to(dtype)
    n = commanded_normal(position, aim, sun)
    beam_c, beam_r = normalize(centre - position), normalize(aim - position)
    s_eq = 2 * (n @ beam_c) * n - beam_c
    pointing = _reflection_map(n, sun, beam_r) @ torch.linalg.inv(_reflection_map(n, s_eq, beam_c))
    shape = _outline_map(n, beam_c, beam_r) * ((centre - position).norm() / (aim - position).norm())
    # the spot's centroid c, as a direction from the pivot
    a_pixels = _gnomonic(_plane_points(target, 1, dtype), position, beam_c)  # (Hc, Wc, 2)
    weight = image.clamp_min(0) / image.clamp_min(0).sum().clamp_min(1e-30)
    c = (weight[..., None] * a_pixels).sum((0, 1))
    # receiver sub-pixels -> directions b -> target directions a -> target plane (u, v)
    b = _gnomonic(_plane_points(receiver, oversample, dtype), position, beam_r)
    a = c + (b - pointing @ c) @ torch.linalg.inv(shape).T
    e1, e2 = plane_axes(beam_c)
    d = normalize(beam_c + a[..., :1] * e1 + a[..., 1:] * e2)
    hit = position + ((centre - position) @ normal / (d @ normal))[..., None] * d - centre
    right, up = (x.to(dtype) for x in target.axes())
    uv = torch.stack((hit @ right, hit @ up), -1)  # (Hr k, Wr k, 2) m
    grid = torch.stack((uv[..., 0] * 2 / target.width, -uv[..., 1] * 2 / target.height), -1)
    flux = F.grid_sample(
        image[None, None], grid[None], mode="bilinear", padding_mode="zeros", align_corners=False
    )[0, 0]
    pw, ph = (p / oversample for p in receiver.pixel_size)
    du = torch.gradient(uv, dim=1)[0] / pw  # d(u_c, v_c) / d u_r (columns run along right)
    dv = -torch.gradient(uv, dim=0)[0] / ph  # d(u_c, v_c) / d v_r (rows run down)
    jacobian = (du[..., 0] * dv[..., 1] - du[..., 1] * dv[..., 0]).abs()
    rows, cols = receiver.resolution
    carried = (flux * jacobian).reshape(rows, oversample, cols, oversample).mean((1, 3))
    d_c, d_r = (centre - position).norm(), (aim - position).norm()
    if spread > 0 and d_r > d_c:
        sigma_m = spread * float((d_r**2 - d_c**2).sqrt())
        carried = gaussian_blur(carried[None], sigma_m / math.sqrt(receiver.pixel_area))[0]
    return carried * (n @ sun) / (n @ s_eq)
