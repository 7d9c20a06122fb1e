"""The fast, differentiable tracer: heliostat surfaces -> flux images on a target plane.

How a ray is traced. For every sun position s and surface point p the central reflected ray
r0 = reflect(-sun, n) is computed once. A ray's direction is perturbed to first order in small
angles (exact to O(angle^3) in direction, since only the direction matters for the intersection):

    d = r0 + a1 h1 + a2 h2 + b1 g1 + b2 g2

with (a1, a2) the sun-shape deviation of the incoming ray (h_k = reflection of the sun-plane axes
e_k), (b1, b2) the slope-error tilt of the normal along the surface tangents t_k
(g_k = -2[(i.t_k) n + (i.n) t_k], the derivative of the reflection law), and its origin jittered
uniformly over the point's surface cell. All of this is projected once onto the target's normal
and axes, so that a ray costs a handful of multiply-adds, one division and the splat.

Splatting:
  bilinear  each ray's power goes to its four nearest pixel centres with bilinear weights
            (Monte Carlo, differentiable in the hit positions). The expected image is the flux
            averaged with a one-pixel tent filter.
  kernel    each surface point's central ray deposits the analytic beam-spread footprint
            (sun shape convolved with the slope error, see sun.radial_density): flux density
            power * f(theta) * cos(gamma) / r^2 at the target, theta the angle off the central ray.
            Per sun position the central rays are deposited bilinearly and convolved (FFT) with the
            pixel-averaged footprint of the heliostat's reference ray (pivot to aim point) and its
            first-order change with each ray's direction and path (`splat_footprints`), so both
            modes estimate nearly the same image; noise-free with far fewer rays. Slope error enters
            isotropically (2 sigma), which overestimates the spread across the plane of incidence by
            1/cos(incidence) at oblique incidence.

Pixels. Each splat averages the flux over pixels with its own filter: the bilinear deposit with a
tent (TENT_VARIANCE = pixel^2/6 per axis), the kernel splat with the tent of its central rays'
deposit and the q x q average of its footprint (KERNEL_PIXEL_VARIANCE = pixel^2/6 + (q^2 - 1)/(12 q^2)).
Images carry their own filter (Target.pixel_variance): a camera's pixel integrates its square, a box
of pixel^2/12. Where the target names a narrower filter than the kernel splat's, the footprint is
sharpened by the three-tap filter that removes the difference (`pixel_average`), clamped at 0 and
renormalised: for footprints smooth on the scale of a pixel the spot's power, centroid and second
moments are then those of the named filter (without it a 1.5-pixel camera blur fits 2 % low on an
independent Monte Carlo's images). The bilinear splat keeps its tent.

Random numbers come from a cached pool of 2^20 exact sample rows; each (sun position, point)
reads K consecutive rows from an offset drawn from the trace's seed, and its sun and slope
directions are turned by random angles and its jitter axes flipped at random (all three
distributions are isotropic, so this is exact): seeds matter at any ray count. A fixed seed gives
identical images; memory is bounded by `chunk_rays` whatever the ray count.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Literal, overload

import torch
from torch import Tensor

from helioflow.physics.geometry import normalize, plane_axes, reflect, sun_vector
from helioflow.physics.heliostat import Heliostat, orientation, sample_surface
from helioflow.physics.sun import SunShape, radial_density, sample_deviations, support_radius
from helioflow.physics.target import TENT_VARIANCE, Target

SPLATS = ("bilinear", "kernel")
POOL_SIZE = 2**20
EXPANSION_ANGLE = 1e-2  # rad: finite-difference step of a footprint's change with a ray's direction
EXPANSION_PATH = 1e-2  # the same for its path, relative to the reference ray's
POOL_SEED = 20240815
FOOTPRINT_SUPERSAMPLING = 2  # footprints are box-averaged over q x q points per pixel
# pixel^2 per axis by which the kernel splat averages the flux over pixels: its central rays' tent
# and its footprint's q x q average
KERNEL_PIXEL_VARIANCE = TENT_VARIANCE + (FOOTPRINT_SUPERSAMPLING**2 - 1) / (12 * FOOTPRINT_SUPERSAMPLING**2)


@dataclass(frozen=True)
class Optics:
    """The physics a trace applies, resolved from the effect list (see effects.py).

    Attributes:
        sun: sun shape of the incoming rays.
        slope_error: per-axis std of the surface normal's random tilt (rad).
        dni: direct normal irradiance (W/m^2).
        reflectivity: mirror reflectivity (1).
        transmittance: slant range (m) -> atmospheric transmittance; None = lossless.
        mirror_mask: MirrorPoints -> the share of its power each surface point sends (soiling,
            shading by a neighbour: an effect that acts as a mask on the mirror); None = all.
    """

    sun: SunShape
    slope_error: float = 0.0
    dni: float = 1000.0
    reflectivity: float = 1.0
    transmittance: Callable[[Tensor], Tensor] | None = None
    mirror_mask: Callable[[MirrorPoints], Tensor] | None = None


@dataclass(frozen=True)
class MirrorPoints:
    """Where a mask on the mirror is evaluated (Optics.mirror_mask): tensors that broadcast against
    each other over leading dimensions (..., 3), e.g. (S, P, 3) for S sun positions and P points.

    Attributes:
        local: the points in the heliostat frame (right, up, normal; m).
        world: the points in ENU (m).
        to_sun: unit vectors towards the sun (the sun's centre, or a ray's own direction).
        reflected: unit reflected directions (central, or a ray's own).
        aim: (3,) the aim point (ENU, m).
        sun: (S', 3) unit vectors towards the sun's centre, one per sun position; `world` reshapes
            to (S', ..., 3) along them (S' = S for the fast tracers, 1 for the reference's one sun).
    """

    local: Tensor
    world: Tensor
    to_sun: Tensor
    reflected: Tensor
    aim: Tensor
    sun: Tensor


@dataclass
class _Rays:
    """Per (sun position, surface point) coefficients, projected on the target: shapes (S, P, ...)."""

    along: Tensor  # (S, P, 5, 3) projections (normal, right, up) of r0, h1, h2, g1, g2
    offset: Tensor  # (S, P, 3) (c - o).n, (o - c).right, (o - c).up of the cell centre
    jitter: Tensor  # (S, P, 2, 3) the same projections of the two cell half-extent vectors
    power: Tensor  # (S, P) power reflected by the cell towards the target (W)


@overload
def trace(heliostats: Heliostat | Sequence[Heliostat], target: Target, azimuth: Tensor, elevation: Tensor,
          optics: Optics, *, rays: int, splat: str = "bilinear", cells_per_side: int = 32, seed: int = 0,
          chunk_rays: int = 2**19, aim_point: Tensor | None = None, with_launched: Literal[False] = False,
          mirror_weight: Tensor | None = None) -> Tensor: ...


@overload
def trace(heliostats: Heliostat | Sequence[Heliostat], target: Target, azimuth: Tensor, elevation: Tensor,
          optics: Optics, *, rays: int, splat: str = "bilinear", cells_per_side: int = 32, seed: int = 0,
          chunk_rays: int = 2**19, aim_point: Tensor | None = None, with_launched: Literal[True],
          mirror_weight: Tensor | None = None) -> tuple[Tensor, Tensor]: ...


@overload
def trace(heliostats: Heliostat | Sequence[Heliostat], target: Target, azimuth: Tensor, elevation: Tensor,
          optics: Optics, *, rays: int, splat: str = "bilinear", cells_per_side: int = 32, seed: int = 0,
          chunk_rays: int = 2**19, aim_point: Tensor | None = None, with_launched: bool = False,
          mirror_weight: Tensor | None = None) -> Tensor | tuple[Tensor, Tensor]: ...


def trace(
    heliostats: Heliostat | Sequence[Heliostat],
    target: Target,
    azimuth: Tensor,
    elevation: Tensor,
    optics: Optics,
    *,
    rays: int,
    splat: str = "bilinear",
    cells_per_side: int = 32,
    seed: int = 0,
    chunk_rays: int = 2**19,
    aim_point: Tensor | None = None,
    with_launched: bool = False,
    mirror_weight: Tensor | None = None,
) -> Tensor | tuple[Tensor, Tensor]:
    """Flux images of heliostats on a target, one per sun position.

    Args:
        heliostats: one heliostat or several (their flux adds up).
        target: the plane the images lie on.
        azimuth, elevation: (S,) sun position (rad; azimuth 0 = south, +pi/2 = east).
        optics: sun shape, slope error, DNI, reflectivity, attenuation.
        rays: rays per heliostat and sun position (bilinear); kernel splatting uses one ray per
            surface cell and ignores it.
        splat: "bilinear" or "kernel".
        cells_per_side: each facet is sampled on a grid of this many cells per side.
        seed: seed of the random pool; the same seed gives identical images.
        chunk_rays: rays (or kernel evaluations) held in memory at once.
        aim_point: (3,) ENU aim point; default the target's (Target.aim_point).
        with_launched: also return the (S,) power (W) reflected towards the target plane: the
            cells' power whose central ray meets the plane, wherever on it. The image holds what
            lands inside it; the rest is lost beside it.
        mirror_weight: (P,) weight of each surface point's power, on top of the optics' own mirror
            mask (one heliostat only; e.g. one region's light), P = F * cells_per_side^2 in
            `sample_surface`'s order (facet, row from the top, column from the left).

    Returns:
        (S, H, W) flux density (W/m^2), averaged over pixels (see Pixels above), differentiable in the
        heliostats' tensors (and the launched power (S,) W, with_launched).
    """
    if splat not in SPLATS:
        raise ValueError(f"splat must be one of {SPLATS}, got {splat!r}")
    heliostats = [heliostats] if isinstance(heliostats, Heliostat) else list(heliostats)
    dtype, device = heliostats[0].facet_size.dtype, heliostats[0].facet_size.device
    aim = target.aim_point.to(dtype=dtype, device=device) if aim_point is None else aim_point
    rows, cols = target.resolution
    sun = sun_vector(azimuth.to(dtype=dtype, device=device), elevation.to(dtype=dtype, device=device))
    generator = torch.Generator(device="cpu").manual_seed(seed)
    images, launched = [], []
    if mirror_weight is not None:
        optics = replace(optics, mirror_mask=weighted_mask(optics.mirror_mask, mirror_weight))
    samples = [sample_surface(h, cells_per_side) for h in heliostats]  # once, not per sun batch
    per_batch = _sun_chunk(heliostats, cells_per_side)
    for start in range(0, len(sun), per_batch):
        s_sun = sun[start : start + per_batch]
        image = torch.zeros(len(s_sun), rows, cols, dtype=dtype, device=device)
        power = torch.zeros(len(s_sun), dtype=dtype, device=device)
        for heliostat, surface in zip(heliostats, samples):
            coeffs = _project(heliostat, surface, s_sun, target, aim, optics)
            if with_launched:
                towards = coeffs.along[:, :, 0, 0]
                meets = (coeffs.offset[:, :, 0] / towards > 0) & (towards < 0)
                power = power + torch.where(meets, coeffs.power, 0.0).sum(-1)
            if splat == "bilinear":
                image = image + _splat_bilinear(coeffs, target, optics, rays, generator, chunk_rays)
            else:
                image = image + _splat_kernel(coeffs, target, optics, reference_ray(heliostat.position, aim, target))
        images.append(image)
        launched.append(power)
    flux = torch.cat(images) / target.pixel_area
    return (flux, torch.cat(launched)) if with_launched else flux


def _sun_chunk(heliostats: Sequence[Heliostat], cells_per_side: int) -> int:
    """Sun positions per batch so that the (S, P, 25) coefficient tensors stay below ~64 MB."""
    points = heliostats[0].n_facets * cells_per_side**2
    return max(1, 2**24 // (25 * points))


def weighted_mask(mask: Callable[[MirrorPoints], Tensor] | None, weight: Tensor) -> Callable[[MirrorPoints], Tensor]:
    """The mirror mask `mask` (None: none) times a fixed (P,) weight of the surface points."""

    def masked(points: MirrorPoints) -> Tensor:
        w = weight.to(points.world)
        return w if mask is None else mask(points) * w

    return masked


def mirror_points(heliostat: Heliostat, samples, sun: Tensor, aim: Tensor) -> tuple[MirrorPoints, Tensor, Tensor]:
    """(the surface points as a mirror mask sees them, for the (S, 3) unit sun vectors: local (P, 3),
    world (S, P, 3), to_sun (S, 1, 3), reflected (S, P, 3); the (S, 3, 3) orientations; the (S, P, 3)
    world normals)."""
    rot = orientation(heliostat, sun, aim)  # (S, 3, 3)
    origin = heliostat.position + torch.einsum("sij,pj->spi", rot, samples.points)  # (S, P, 3)
    n = torch.einsum("sij,pj->spi", rot, samples.normals)  # (S, P, 3)
    return MirrorPoints(samples.points, origin, sun[:, None, :], reflect(-sun[:, None, :], n), aim, sun), rot, n


def _project(heliostat: Heliostat, samples, sun: Tensor, target: Target, aim: Tensor, optics: Optics) -> _Rays:
    """Coefficients of every (sun position, surface point) pair; see the module docstring."""
    points, rot, n = mirror_points(heliostat, samples, sun, aim)
    dtype = rot.dtype
    centre, normal = target.center.to(dtype), target.normal.to(dtype)
    right, up = (a.to(dtype) for a in target.axes())
    frame = torch.stack((normal, right, up), dim=-1)  # (3, 3) columns = target normal, right, up
    origin, r0 = points.world, points.reflected
    half = torch.einsum("sij,pkj->spki", rot, samples.half_extent)  # (S, P, 2, 3)
    incoming = -sun[:, None, :]  # (S, 1, 3)
    cos_in = -(incoming * n).sum(-1)  # (S, P)
    e1, e2 = plane_axes(sun)
    h1, h2 = reflect(e1[:, None, :], n), reflect(e2[:, None, :], n)
    t1 = normalize(half[:, :, 0] - (half[:, :, 0] * n).sum(-1, keepdim=True) * n)
    t2 = torch.cross(n, t1, dim=-1)
    i_dot_n = (incoming * n).sum(-1, keepdim=True)
    g1 = -2.0 * ((incoming * t1).sum(-1, keepdim=True) * n + i_dot_n * t1)
    g2 = -2.0 * ((incoming * t2).sum(-1, keepdim=True) * n + i_dot_n * t2)
    along = torch.stack((r0, h1, h2, g1, g2), dim=2) @ frame  # (S, P, 5, 3)
    rel = (origin - centre) @ frame  # (S, P, 3)
    offset = torch.stack((-rel[..., 0], rel[..., 1], rel[..., 2]), dim=-1)
    jit = half @ frame
    jitter = torch.stack((-jit[..., 0], jit[..., 1], jit[..., 2]), dim=-1)
    power = optics.dni * optics.reflectivity * samples.area * cos_in.clamp_min(0.0)
    if optics.transmittance is not None:
        power = power * optics.transmittance((centre - heliostat.position).norm())
    if optics.mirror_mask is not None:
        power = power * optics.mirror_mask(points)
    return _Rays(along, offset, jitter, power)


@functools.lru_cache(maxsize=4)
def sample_pool(sun: SunShape, slope_error: float, n: int) -> Tensor:
    """(6, n) float64 random rows: sun deviation (2, rad), slope tilt (2, rad), cell jitter (2, in [-1, 1]).

    Drawn once per (sun shape, slope error, size) from a fixed seed and cached: drawing exact
    Buie samples costs more than tracing them. A trace's seed picks where each surface point
    reads in the pool, so different seeds still give independent-looking images.
    """
    generator = torch.Generator().manual_seed(POOL_SEED)
    deviation = sample_deviations(sun, n, generator, dtype=torch.float64).T
    slope = torch.randn(2, n, generator=generator, dtype=torch.float64) * slope_error
    jitter = torch.rand(2, n, generator=generator, dtype=torch.float64) * 2.0 - 1.0
    return torch.cat((deviation, slope, jitter))


def _splat_bilinear(
    c: _Rays, target: Target, optics: Optics, rays: int, generator: torch.Generator, chunk_rays: int
) -> Tensor:
    """Monte Carlo rays splatted bilinearly: (S, H, W) power per pixel (W)."""
    n_sun, n_points = c.power.shape
    dtype, device = c.power.dtype, c.power.device
    per_point = max(1, math.ceil(rays / n_points))
    pool_size = POOL_SIZE
    pool = sample_pool(optics.sun, float(optics.slope_error), pool_size).to(device=device, dtype=dtype)
    # Only the random components that do something are drawn: sun (0, 1), slope (2, 3), jitter (4, 5).
    active = [0, 1] * (optics.sun.kind != "point") + [2, 3] * (optics.slope_error > 0) + [4, 5]
    direction, position = _randomly_turned(*_pixel_coefficients(c, target), generator)
    image = torch.zeros(n_sun, *target.resolution, dtype=dtype, device=device)
    # (S, points, draws) rays at once, at most about chunk_rays: whole points' draws when they fit,
    # else one point at a time in runs of draws (many rays on few points)
    per_run = max(1, min(per_point, chunk_rays // n_sun))
    points_per_chunk = max(1, chunk_rays // (per_run * n_sun))
    for p0 in range(0, n_points, points_per_chunk):
        sl = slice(p0, p0 + points_per_chunk)
        n_chunk = c.power[:, sl].shape[1]
        start = torch.randint(0, pool_size, (n_sun, n_chunk, 1), generator=generator).to(device)
        for k0 in range(0, per_point, per_run):
            k = torch.arange(k0, min(k0 + per_run, per_point), device=device)
            idx = (start + k).bitwise_and_(pool_size - 1)  # (S, Pc, K)
            draws = {i: torch.take(pool[i], idx) for i in active}
            axis = [_affine(direction[m], draws, sl, (0, 1, 2, 3)) for m in range(3)]
            pos = [_affine(position[m], draws, sl, (4, 5)) for m in range(3)]
            t = pos[0] / axis[0]
            power = torch.where((t > 0) & (axis[0] < 0), c.power[:, sl, None] / per_point, 0.0)
            col = torch.addcmul(pos[1], t, axis[1])
            row = torch.addcmul(pos[2], t, axis[2])
            image = image + deposit(col.reshape(n_sun, -1), row.reshape(n_sun, -1), power.reshape(n_sun, -1),
                                    target.resolution)
    return image


def deposit(col: Tensor, row: Tensor, power: Tensor, resolution: tuple[int, int]) -> Tensor:
    """Bilinear splat of weighted hits into images.

    Args:
        col, row: (B, N) padded pixel coordinates: (1, 1) is the centre of the top-left pixel.
        power: (B, N) weight of each hit (W).
        resolution: (H, W).

    Returns:
        (B, H, W) power per pixel; hits beyond the border ring are dropped.
    """
    rows, cols = resolution
    n_images = col.shape[0]
    stride, plane = cols + 3, (rows + 3) * (cols + 3)
    col = col.clamp(0.0, cols + 1)
    row = row.clamp(0.0, rows + 1)
    col0, row0 = col.floor(), row.floor()
    wc, wr = col - col0, row - row0
    base = torch.addcmul(col0, row0, torch.tensor(float(stride), dtype=col.dtype)).long()
    base = (base + (torch.arange(n_images, device=col.device) * plane)[:, None]).reshape(-1)
    wc, wr, power = wc.reshape(-1), wr.reshape(-1), power.reshape(-1)
    pr1 = power * wr
    pr0 = power - pr1
    w11 = pr1 * wc
    w01 = pr0 * wc
    flat = torch.zeros(n_images * plane, dtype=col.dtype, device=col.device)
    for shift, weight in ((0, pr0 - w01), (1, w01), (stride, pr1 - w11), (stride + 1, w11)):
        flat = flat.index_add(0, base + shift, weight)
    return flat.view(n_images, rows + 3, cols + 3)[:, 1 : rows + 1, 1 : cols + 1]


def _pixel_coefficients(c: _Rays, target: Target
                        ) -> tuple[list[dict[str | int, Tensor]], list[dict[str | int, Tensor]]]:
    """Ray coefficients rescaled so that the hit lands in padded pixel coordinates.

    Returns, for m = 0 (target normal), 1 (column), 2 (row): direction[m] = {term: (S, P, 1)}
    with term "base" for r0 and 0..3 for the sun and slope components, and position[m] =
    {term: (S, P, 1)} with "base" for the cell centre and 4, 5 for the jitter components.
    Column = (u + width/2)/pixel_width + 1/2, row = (height/2 - v)/pixel_height + 1/2 (one ring
    of padding left and top).
    """
    pw, ph = target.pixel_size
    scale = (1.0, 1.0 / pw, -1.0 / ph)
    shift = (0.0, target.width / (2 * pw) + 0.5, target.height / (2 * ph) + 0.5)
    direction: list[dict[str | int, Tensor]] = []
    position: list[dict[str | int, Tensor]] = []
    for m in range(3):
        d: dict[str | int, Tensor] = {"base": c.along[:, :, 0, m, None] * scale[m]}
        d.update({i: c.along[:, :, i + 1, m, None] * scale[m] for i in range(4)})
        direction.append(d)
        position.append({"base": c.offset[:, :, m, None] * scale[m] + shift[m],
                         4: c.jitter[:, :, 0, m, None] * scale[m], 5: c.jitter[:, :, 1, m, None] * scale[m]})
    return direction, position


def _randomly_turned(direction: list[dict], position: list[dict], generator: torch.Generator):
    """Turn each (sun position, point)'s sun-deviation axes and slope-tilt axes by independent
    random angles and flip its jitter axes at random; the draws it reads are isotropic, so the
    ray distribution is unchanged while pool samples are never reused in the same orientation."""
    shape = direction[0]["base"].shape
    angle = torch.rand((2, *shape), generator=generator, dtype=torch.float64) * (2 * math.pi)
    cos, sin = (f(angle).to(direction[0]["base"]) for f in (torch.cos, torch.sin))
    flip = (torch.randint(0, 2, (2, *shape), generator=generator) * 2 - 1).to(direction[0]["base"])
    for m in range(3):
        d = direction[m]
        for k, (i, j) in enumerate(((0, 1), (2, 3))):
            d[i], d[j] = cos[k] * d[i] + sin[k] * d[j], cos[k] * d[j] - sin[k] * d[i]
        position[m][4], position[m][5] = flip[0] * position[m][4], flip[1] * position[m][5]
    return direction, position


def _affine(coeff: dict, draws: dict, sl: slice, terms: tuple[int, ...]) -> Tensor:
    """coeff["base"] + sum_i draws[i] * coeff[i] over the drawn terms: (S, Pc, K)."""
    out = None
    for i in terms:
        if i in draws:
            out = torch.addcmul(coeff["base"][:, sl] if out is None else out, draws[i], coeff[i][:, sl])
    return coeff["base"][:, sl].expand(-1, -1, next(iter(draws.values())).shape[-1]) if out is None else out


def _splat_kernel(c: _Rays, target: Target, optics: Optics, reference: tuple[Tensor, Tensor]) -> Tensor:
    """Analytic footprints of the cells' central rays: (S, H, W) power per pixel, pixel-averaged (W).

    The footprint of a ray, power * f(theta) * cos(gamma) / r^2, changes little across a heliostat
    (its direction and path length vary by a few mrad and percent), so each sun position's central
    rays are deposited bilinearly on a canvas that extends the target by half its size on each side,
    and the canvas is convolved (FFT) with the footprint of the heliostat's `reference_ray` and its
    first-order change with each ray's direction and path (`splat_footprints`). Flux from rays that
    land outside the canvas is not followed.
    """
    col, row, power, unit, path = central_hits(c, padded_canvas(target))
    return splat_footprints(col, row, power, target, optics, reference, (unit, path))


def reference_ray(position: Tensor, aim: Tensor, target: Target) -> tuple[Tensor, Tensor]:
    """The ray from a heliostat's pivot `position` (3,) to the `aim` point (3,) (ENU, m): its unit
    direction (3,) on the target's (normal, right, up) and its length (m) to the target plane.
    A tracking heliostat's reflected rays leave near it whatever the sun's position, so its
    footprint, and its footprint's change with a ray's direction and path, serve every image."""
    dtype = position.dtype
    frame = torch.stack((target.normal.to(dtype), *(a.to(dtype) for a in target.axes())), -1)
    towards = normalize(aim - position)
    unit = towards @ frame
    return unit, ((target.center.to(dtype) - position) @ frame[:, 0]) / unit[0]


def central_hits(c: _Rays, canvas: Target) -> tuple[Tensor, Tensor, Tensor, Tensor, Tensor]:
    """Where each (sun position, point)'s central ray meets the canvas: column and row (S, P) in its
    padded pixel coordinates (see `deposit`), power (S, P) (W; 0 for a ray away from the plane), unit
    direction (S, P, 3) on the target's (normal, right, up) and path length (S, P) (m)."""
    direction, position = _pixel_coefficients(c, canvas)
    t = position[0]["base"] / direction[0]["base"]  # (S, P, 1); the normal axis is not rescaled
    power = torch.where((t > 0) & (direction[0]["base"] < 0), c.power[..., None], 0.0)[..., 0]
    col = torch.addcmul(position[1]["base"], t, direction[1]["base"])[..., 0]
    row = torch.addcmul(position[2]["base"], t, direction[2]["base"])[..., 0]
    central = c.along[:, :, 0, :]
    length = central.norm(dim=-1)
    return col, row, power, central / length[..., None], t[..., 0] * length


def padded_canvas(target: Target) -> Target:
    """The target extended by half its size on each side, same pixels: where `splat_footprints`
    deposits (pixel coordinates on it are the target's plus half its resolution)."""
    rows, cols = target.resolution
    pad_r, pad_c = rows // 2, cols // 2
    return replace(target, width=target.width * (cols + 2 * pad_c) / cols,
                   height=target.height * (rows + 2 * pad_r) / rows, resolution=(rows + 2 * pad_r, cols + 2 * pad_c))


def footprint_expansion(reference: tuple[Tensor, Tensor],
                        rays: tuple[Tensor, Tensor]) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """What expands each ray's footprint about the reference ray's to first order
    (`splat_footprints`): the rays whose footprints give the central differences, their steps, and
    each ray's deviations from the reference ray.

    The deviations: the ray's direction across the reference ray, along the target's right and
    (nearly) up axes (rad), and its path's excess over the reference's (m). The finite differences
    step by EXPANSION_ANGLE (rad) and EXPANSION_PATH (relative) whatever rays are traced, so that
    the images of parts of a heliostat (its facets) add up to the whole's.

    Args:
        reference: unit (3,) direction on the target's (normal, right, up) and path (m), `reference_ray`.
        rays: unit (S, N, 3) directions and (S, N) paths (m) of the rays (`central_hits`).

    Returns:
        units (7, 3) and paths (7,): the reference ray, then that ray moved by -/+ one step of each
        deviation in turn; steps (3,) (rad, rad, m); deviations (S, N, 3) of each ray.
    """
    ref, ref_path = reference
    unit, path = rays
    right = normalize(ref.new_tensor([0.0, 1.0, 0.0]) - ref[1] * ref)  # across the reference ray
    up = torch.linalg.cross(ref, right)
    offset = unit - ref
    deviations = torch.stack(((offset * right).sum(-1), (offset * up).sum(-1), path - ref_path), -1)
    steps = torch.stack((ref.new_tensor(EXPANSION_ANGLE), ref.new_tensor(EXPANSION_ANGLE), EXPANSION_PATH * ref_path))
    units, paths = [ref], [ref_path]
    for j, axis in enumerate((right, up, None)):
        for sign in (-1.0, 1.0):
            units.append(ref if axis is None else normalize(ref + sign * steps[j] * axis))
            paths.append(ref_path + sign * steps[j] if axis is None else ref_path)
    return torch.stack(units), torch.stack(paths), steps, deviations


def splat_footprints(col: Tensor, row: Tensor, power: Tensor, target: Target, optics: Optics,
                     reference: tuple[Tensor, Tensor], rays: tuple[Tensor, Tensor] | None = None) -> Tensor:
    """Rays of B images deposited bilinearly on the padded canvas (`padded_canvas`), each spread by
    its footprint: (B, H, W) power per pixel (W) of the target, averaged over pixels with
    KERNEL_PIXEL_VARIANCE or the target's narrower pixel filter.

    With `rays`, a ray's footprint is the reference ray's to first order in how the ray differs
    from it (its direction across the reference ray, two angles, and its path length: deviations
    d_j, `footprint_expansion`), K ~ K_ref + sum_j d_j dK/dj, each derivative a central
    difference. The flux is the canvas of the rays' power convolved with K_ref plus, for each j, the
    canvas of power * d_j convolved with dK/dj (one inverse FFT for the sum). Without the first
    order a heliostat's spot misses how its footprint grows from one side of its image to the other
    (longer paths, more oblique rays), and so a skewness: on AA39 with one footprint per facet the
    spot's third moment up was 60 % too large for a 3.3 mrad sun against the reference tracer, and a
    fit moved the spot 0.04 mrad to match its shape. The expansion is about a ray fixed by the
    geometry and linear in the rays, so the images of parts of a heliostat (its facets) add up to
    the whole's; exactly but where the first order's own negative flux at the footprints' ends,
    ~1e-5 of the peak under a Buie sun, is clamped to 0 (a part's image and the whole's then differ
    by that much where the flux vanishes).

    Args:
        col, row: (B, N) padded pixel coordinates on the canvas (see `deposit`).
        power: (B, N) power of each ray (W).
        target, optics: the target and the beam spread.
        reference: unit (3,) or (B, 3) direction on the target's (normal, right, up) and path () or
            (B,) (m) of the ray whose footprint spreads the rays (`reference_ray`).
        rays: unit (B, N, 3) directions and (B, N) paths (m) of the rays (`central_hits`); None:
            the reference's footprint alone (one convolution per image).
    """
    rows, cols = target.resolution
    pad_r, pad_c = rows // 2, cols // 2
    radius = support_radius(optics.sun, optics.slope_error)
    if radius == 0.0:  # a point sun without slope error: no spread
        return deposit(col - pad_c, row - pad_r, power, target.resolution)
    if rays is None:
        units, paths, weights = reference[0][..., None, :], reference[1][..., None], power[:, None]
    else:
        units, paths, steps, deviations = footprint_expansion(reference, rays)
        weights = torch.cat((power[:, None], power[:, None] * deviations.permute(0, 2, 1)), 1)  # (B, 4, N)
    # The footprint reaches at most support * path / cos(incidence on the target); rays farther
    # than that (and the bilinear pixel) beside the target add nothing to it, so the canvas is cut
    # down to that margin.
    spread = radius * paths / units[..., 0].abs()
    pw, ph = target.pixel_size
    widest = float(spread.detach().max())
    jr, jc = min(rows + pad_r, math.ceil(widest / ph) + 1), min(cols + pad_c, math.ceil(widest / pw) + 1)
    mr, mc = min(pad_r, jr + 1), min(pad_c, jc + 1)
    density = density_lookup(optics.sun, float(optics.slope_error))
    kernel = footprint(density, units.reshape(-1, 3), paths.reshape(-1),
                       units.new_tensor(target.pixel_size).expand(paths.numel(), 2), (jr, jc))
    if target.pixel_variance is not None and target.pixel_variance < KERNEL_PIXEL_VARIANCE:
        # the images' own pixel filter, not the splat's: the excess taken off the footprint (clamped
        # at 0 where the footprint is sharp on the scale of a pixel, renormalised below)
        kernel = pixel_average(kernel, KERNEL_PIXEL_VARIANCE - target.pixel_variance).clamp_min(0.0)
    # A footprint that lies wholly inside the kernel window carries exactly the ray's power;
    # renormalising removes the lattice error of sampling a hard-edged sun disc on pixels.
    inside = spread.reshape(-1) < min(jr * ph, jc * pw)
    total = kernel.sum((-2, -1)) * target.pixel_area
    kernel = torch.where(inside[:, None, None], kernel / total[:, None, None].clamp_min(1e-30), kernel)
    kernel = kernel.reshape(*paths.shape, *kernel.shape[-2:])
    if rays is not None:  # K_ref, then dK/dj by central differences
        kernel = torch.cat((kernel[:1], (kernel[2::2] - kernel[1::2]) / (2 * steps[:, None, None])))[None]
    deposited = deposit((col - (pad_c - mc))[:, None].expand_as(weights).flatten(0, 1),
                        (row - (pad_r - mr))[:, None].expand_as(weights).flatten(0, 1),
                        weights.flatten(0, 1), (rows + 2 * mr, cols + 2 * mc))
    # the target's (B, rows, cols) of the (B, rows + 2 mr + 2 jr, cols + 2 mc + 2 jc) convolution centred
    # on the canvas; the clamp removes the FFT's round-off and the first order's own negative flux where
    # the footprints end
    flux = convolve(deposited.reshape(*weights.shape[:2], *deposited.shape[-2:]), kernel,
                    ((jr + mr, rows), (jc + mc, cols))).clamp_min(0.0)
    return flux * target.pixel_area


def pixel_average(images: Tensor, excess: float) -> Tensor:
    """(B, H, W) images (or footprints) averaged over pixels with a filter `excess` pixel^2 per axis
    wider than wanted -> the same with the excess removed: each axis convolved with [-c, 1 + 2c, -c],
    c = excess / 2, which keeps the power and the centroid and lowers the variance by exactly `excess`
    (higher moments right to leading order in the pixel size). Zero beyond the border; the side taps
    are negative, so a footprint sharp on the scale of a pixel gets negative values beside its edges."""
    c = excess / 2
    padded = torch.nn.functional.pad(images, (1, 1, 1, 1))  # (B, H + 2, W + 2)
    rows = (1 + 2 * c) * padded[:, 1:-1] - c * (padded[:, :-2] + padded[:, 2:])
    return (1 + 2 * c) * rows[..., 1:-1] - c * (rows[..., :-2] + rows[..., 2:])


@functools.lru_cache(maxsize=8)
def _density_table(sun: SunShape, slope_error: float, n: int = 8192) -> tuple[Tensor, float]:
    """(n,) float64 values of the beam-spread density (1/sr) on a uniform angle grid from 0 to the
    support radius, and the grid step (rad); cached per sun shape and slope error."""
    radius = support_radius(sun, slope_error)
    theta = torch.linspace(0.0, radius, n, dtype=torch.float64)
    return radial_density(sun, slope_error)(theta), radius / (n - 1)


def density_lookup(sun: SunShape, slope_error: float) -> Callable[[Tensor], Tensor]:
    """theta (rad, any shape, >= 0) -> density (1/sr) by linear interpolation in the cached table, 0
    beyond it; differentiable in theta."""
    table, step = _density_table(sun, slope_error)
    last = len(table) - 1
    rise = table[1:] - table[:-1]

    def density(theta: Tensor) -> Tensor:
        values, slopes = (t.to(device=theta.device, dtype=theta.dtype) for t in (table, rise))
        x = theta * (1.0 / step)
        i = x.detach().long().clamp_max(last - 1)  # floor for x >= 0
        value = torch.take(values, i) + torch.take(slopes, i) * (x - i)
        return torch.where(x <= last, value, 0.0)

    return density


def footprint(density, unit: Tensor, path: Tensor, pixel: Tensor, reach: tuple[int, int],
              supersampling: int = FOOTPRINT_SUPERSAMPLING) -> Tensor:
    """Flux (W/m^2 per W) of one ray around its hit point, at pixel offsets: the beam spread's
    angular density at the angle theta between the ray and the direction to the point, times the
    solid angle per target area there, |n . (P - M)| / |P - M|^3 (M the mirror point, P the target
    point, n the target normal); both exact in the offset along the ray, to first order in theta^2
    (relative error ~1.5 theta^2: 1e-4 at 8 mrad, 3e-3 at the Buie aureole's 43.6 mrad edge). The
    far side of an oblique footprint is thus stretched more than the near side, which moves the
    spot's centroid by ~ sigma^2 tan(g) / cos^2(g) (sigma the beam spread, g the ray's incidence on
    the target: 0.03 mrad for a 3.3 mrad sun at 50 degrees); the footprint is not point-symmetric.

    Args:
        density: theta (rad) -> angular density (1/sr) of the beam spread.
        unit: (B, 3) unit ray direction projected on the target's (normal, right, up).
        path: (B,) distance from the mirror to the hit point (m).
        pixel: (B, 2) pixel width and height (m) of each ray's grid.
        reach: (Jr, Jc) offsets -Jr..Jr rows and -Jc..Jc columns.
        supersampling: the average over each pixel is taken over q x q points.

    Returns:
        (B, 2 Jr + 1, 2 Jc + 1) averaged over each pixel; row offset i means the pixel lies i rows
        below the hit.
    """
    dtype, device = unit.dtype, unit.device
    sub = (torch.arange(supersampling, dtype=dtype, device=device) + 0.5) / supersampling - 0.5
    du = (torch.arange(-reach[1], reach[1] + 1, dtype=dtype, device=device)[:, None] + sub).reshape(-1)
    dv = -(torch.arange(-reach[0], reach[0] + 1, dtype=dtype, device=device)[:, None] + sub).reshape(-1)
    du, dv = du * pixel[:, 0, None], dv * pixel[:, 1, None]  # (B, Wk * q), (B, Hk * q) in m
    eu, ev = unit[:, 1, None, None], unit[:, 2, None, None]
    r = path[:, None, None]
    du, dv = du[:, None, :], dv[:, :, None]
    along = eu * du + ev * dv  # (P - M) = path e + d: its component along e is path + e . d
    across2 = (du**2 + dv**2 - along**2).clamp_min(1e-24)  # and |e x (P - M)|^2 = |d|^2 - (e . d)^2
    inv_along = 1.0 / (r + along)
    # tan(theta) and |P - M|^-3 to first order in theta^2
    theta = across2.sqrt() * inv_along
    fine = density(theta) * (unit[:, 0, None, None].abs() * r * inv_along**3)  # (B, Hk q, Wk q)
    columns = sum(fine[..., i::supersampling] for i in range(supersampling))  # (B, Hk q, Wk)
    return sum(columns[:, i::supersampling] for i in range(supersampling)) / supersampling**2


def convolve(images: Tensor, kernels: Tensor, window: tuple[tuple[int, int], tuple[int, int]] | None = None) -> Tensor:
    """Linear convolutions of (B, J, H, W) images with (B, J, Hk, Wk) kernels via FFT, summed over J
    (in the Fourier domain: one inverse transform): the full (B, H+Hk-1, W+Wk-1), or only its
    `window` ((first row, rows), (first column, columns)) of it. A window is taken from a circular
    convolution of the shortest fast length L that leaves it free of wrap-around (L >= first + n
    and L >= full - first per axis, and no shorter than either input): for a 64 px image spread by
    a Buie sun's 109 px footprint, 150 instead of 240 per axis."""
    full = (images.shape[-2] + kernels.shape[-2] - 1, images.shape[-1] + kernels.shape[-1] - 1)
    window = window or ((0, full[0]), (0, full[1]))
    size = tuple(_fft_size(max(first + n, whole - first, images.shape[axis], kernels.shape[axis]))
                 for (first, n), whole, axis in zip(window, full, (-2, -1)))
    spectrum = (torch.fft.rfft2(images, s=size) * torch.fft.rfft2(kernels, s=size)).sum(1)
    (r0, rows), (c0, cols) = window
    return torch.fft.irfft2(spectrum, s=size)[..., r0 : r0 + rows, c0 : c0 + cols]


def _fft_size(n: int) -> int:
    """The smallest m >= n whose prime factors are 2, 3 and 5 (fast FFT lengths)."""
    m = n
    while True:
        k = m
        for p in (2, 3, 5):
            while k % p == 0:
                k //= p
        if k == 1:
            return m
        m += 1
