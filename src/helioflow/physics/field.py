"""Field flux: all heliostats of a field traced at once onto a flat receiver, with shading,
blocking and atmospheric attenuation, and the power budget of every heliostat.

Optical model. Each facet is sampled on a grid of cells (heliostat.sample_surface). Per sun
position and cell the central ray is followed exactly: its incoming sunlight may be shaded, its
reflected ray blocked, then it meets the receiver plane. As in raytrace's `kernel` splatting, the
beam spread (sun shape convolved with the slope error, sun.radial_density) enters as the analytic
footprint of each central ray, flux = power * f(theta) * cos(gamma) / r^2. The approximation that
makes a field cheap: per heliostat one footprint, that of its power-weighted mean ray (raytrace
takes one per facet; across a heliostat the ray direction changes by its size over the slant
range, ~1 %), and each heliostat's spot is computed on its own grid of WINDOW x WINDOW cells that
covers the spot's reach on the receiver, with cells an integer number k of receiver pixels wide,
then interpolated bilinearly onto the receiver pixels. Near heliostats (small spots) get k = 1,
the receiver's own pixels, which reproduces raytrace's kernel image; far ones, whose spots are
smooth on the scale of the slope-error blur, get coarser cells. For one heliostat the field tracer
and raytrace.trace(splat="kernel") agree to 2e-4 in power on the receiver and 45-56 dB PSNR
(tests/physics/test_field.py); both blur by the slope error isotropically (see raytrace). Shading
and blocking act on whole cells (their central rays); the sun's finite size (penumbra), the
tower's shadow and blocking by facets of the same heliostat are neglected.

Shading and blocking. Shading: the ray from a cell towards the sun hits a neighbour's facet
rectangle (either side) first. Blocking: the cell's reflected central ray hits a neighbour's facet
rectangle before the receiver. Only neighbours that can be hit are tested: for heliostat h and a
direction d (the sun, or h -> its aim point) a neighbour g can intercept a ray from h only if its
pivot lies within radius_h + radius_g (+ the widening of the beam towards the receiver) of the line
through h's pivot along d (radius = bounding sphere of the mirror about its pivot); of those the
`neighbours` nearest along d are kept. The filter is O(N^2) per sun position in row chunks (a few
ms for 1000 heliostats); the ray tests are O(N * cells * neighbours * facets).

Power budget (per heliostat and sun position, W), with DNI the direct normal irradiance and
cos_i the cosine of incidence of the sunlight on each cell:
    incident    DNI * sum(cell area * cos_i): sunlight falling on the mirror area, shaded or not
    shaded      the part of `incident` that a neighbour intercepts first (defined on the incident
                light, before reflection, so that it stays out of the identity below)
    reflected   reflectivity * (incident - shaded)
    blocked     the part of `reflected` whose ray hits a neighbour
    attenuated  (reflected - blocked) * (1 - transmittance(slant range from pivot to aim point))
    on_receiver flux integrated over the receiver (sum of the image * pixel area)
    spilled     reflected - blocked - attenuated - on_receiver: the transmitted power that misses the
                receiver (including rays that never meet its plane)
so that reflected = on_receiver + spilled + blocked + attenuated holds exactly.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
import torch
from torch import Tensor

from helioflow.physics.geometry import normalize, reflect, sun_vector
from helioflow.physics.heliostat import (
    REST_FRAME,
    Heliostat,
    facet_frames,
    ideal_joint_angles,
    joint_rotation,
    sample_surface,
)
from helioflow.physics.raytrace import Optics, density_lookup, deposit, footprint
from helioflow.physics.sun import support_radius
from helioflow.physics.target import Target

WINDOW = 64  # cells per side of a heliostat's spot grid
BUDGET_TERMS = ("incident", "shaded", "reflected", "blocked", "attenuated", "on_receiver", "spilled")


@dataclass
class FieldHeliostats:
    """The heliostats of a field as batched tensors (N heliostats, P surface cells, F facets each).

    Geometry is in each heliostat's own frame (right, up, normal at rest), as in heliostat.py; every
    heliostat keeps its own canting, surface and tracking errors.

    Attributes:
        position: (N, 3) ENU pivot positions (m).
        mount: N mount types (heliostat.MOUNTS).
        tracking_error: (N, 5) kinematic errors (rad), TRACKING_PARAMETERS order.
        points: (N, P, 3) cell centres (m).
        normals: (N, P, 3) unit surface normals at the cell centres.
        area: (N, P) cell areas (m^2).
        facet_centre: (N, F, 3) facet centres (m).
        facet_axes: (N, F, 3, 3) facet frames, columns = facet right, up, normal.
        facet_half_size: (N, F, 2) half width and half height of each facet (m).
        radius: (N,) radius of a sphere about the pivot that holds the whole mirror (m).
    """

    position: Tensor
    mount: tuple[str, ...]
    tracking_error: Tensor
    points: Tensor
    normals: Tensor
    area: Tensor
    facet_centre: Tensor
    facet_axes: Tensor
    facet_half_size: Tensor
    radius: Tensor

    def __len__(self) -> int:
        return len(self.position)

    @staticmethod
    def stack(heliostats: Sequence[Heliostat], cells_per_side: int = 8, dtype: torch.dtype | None = None
              ) -> FieldHeliostats:
        """Batch a list of heliostats that share the facet count and control-point grid.

        Args:
            heliostats: N heliostats, each with its own position and errors.
            cells_per_side: each facet is sampled on cells_per_side^2 equal cells.
            dtype: dtype of the tensors; default that of the first heliostat.
        """
        if not heliostats:
            raise ValueError("a field needs at least one heliostat")
        first = heliostats[0]
        for i, h in enumerate(heliostats):
            if (h.facet_translation.shape, h.control_heights.shape) != \
                    (first.facet_translation.shape, first.control_heights.shape):
                raise ValueError(f"heliostat {i}: {h.n_facets} facets, control grid "
                                 f"{tuple(h.control_heights.shape)}; heliostat 0: {first.n_facets}, "
                                 f"{tuple(first.control_heights.shape)}. A field's heliostats must share "
                                 "the facet layout")
        dtype = dtype or first.facet_size.dtype
        points, normals, area = _sample(heliostats, cells_per_side)

        def stack(name: str) -> Tensor:
            return torch.stack([getattr(h, name) for h in heliostats]).to(dtype)

        translation, size = stack("facet_translation"), stack("facet_size")
        axes = torch.stack([facet_frames(h.facet_normal, h.canting_error) for h in heliostats]).to(dtype)
        # a paraboloid facet rises (w^2 + h^2) / (16 f) at its corners
        inverse_focal = torch.tensor([0.0 if h.facet_focal_length is None else 1 / h.facet_focal_length
                                      for h in heliostats], dtype=dtype, device=size.device)
        sag = (size**2).sum(-1).amax(-1) * inverse_focal / 16
        radius = (translation.norm(dim=-1) + size.norm(dim=-1) / 2).amax(-1) + sag
        return FieldHeliostats(stack("position"), tuple(h.mount for h in heliostats), stack("tracking_error"),
                               points.to(dtype), normals.to(dtype), area.to(dtype), translation, axes,
                               size / 2, radius)


def _sample(heliostats: Sequence[Heliostat], cells_per_side: int) -> tuple[Tensor, Tensor, Tensor]:
    """heliostat.sample_surface of every heliostat: points (N, P, 3), normals (N, P, 3), areas (N, P).

    Heliostats with the same facet focal length are sampled at once, as one heliostat with all
    their facets (sampling treats facets independently)."""
    first = heliostats[0]
    n, n_points = len(heliostats), first.n_facets * cells_per_side**2
    like = first.facet_size
    points, normals = like.new_empty(n, n_points, 3), like.new_empty(n, n_points, 3)
    area = like.new_empty(n, n_points)
    focal = [h.facet_focal_length for h in heliostats]
    for f in dict.fromkeys(focal):
        group = [h for h, fh in zip(heliostats, focal) if fh == f]
        index = [i for i, fh in enumerate(focal) if fh == f]
        names = ("facet_translation", "facet_size", "facet_normal", "control_heights", "canting_error")
        merged = replace(first, facet_focal_length=f,
                         **{name: torch.cat([getattr(h, name) for h in group]) for name in names})
        s = sample_surface(merged, cells_per_side)
        points[index] = s.points.reshape(len(group), n_points, 3)
        normals[index] = s.normals.reshape(len(group), n_points, 3)
        area[index] = s.area.reshape(len(group), n_points)
    return points, normals, area


@dataclass
class FieldFlux:
    """A field's flux maps and power budgets.

    Attributes:
        flux: (S, H, W) flux density on the receiver (W/m^2), rows top first.
        budget: {term: (S, N) W} for each of BUDGET_TERMS (see the module docstring).
        spots: (S, K, H, W) flux (W/m^2) of the K heliostats asked for by field_flux(spots=...),
            each on its own (their shares of `flux`); None when none were asked for.
    """

    flux: Tensor
    budget: dict[str, Tensor]
    spots: Tensor | None = None

    def totals(self) -> dict[str, Tensor]:
        """{term: (S,) W}: the budget summed over the heliostats."""
        return {k: v.sum(-1) for k, v in self.budget.items()}


def flat_receiver(center, normal, width: float, height: float, resolution=(128, 128),
                  dtype=torch.float64) -> Target:
    """A flat receiver: centre (3,) ENU (m), normal (3,) towards the field (any length), width and
    height (m), resolution (rows, columns); a Target, so images follow the target conventions."""
    return Target(torch.as_tensor(center, dtype=dtype), normalize(torch.as_tensor(normal, dtype=dtype)),
                  float(width), float(height), tuple(resolution))


def orientations(field: FieldHeliostats, sun: Tensor, aim: Tensor) -> Tensor:
    """(N, 3, 3) heliostat frame -> ENU rotations (columns = mirror right, up, normal) for the unit
    sun vector (3,) and the aim points (N, 3) (m); batched heliostat.orientation."""
    commanded = normalize(sun + normalize(aim - field.position))
    rot = torch.empty(len(field), 3, 3, dtype=sun.dtype, device=sun.device)
    rest = REST_FRAME.to(dtype=sun.dtype, device=sun.device)
    for mount in dict.fromkeys(field.mount):
        idx = torch.tensor([i for i, m in enumerate(field.mount) if m == mount], device=sun.device)
        a1, a2 = ideal_joint_angles(mount, commanded[idx])
        rot[idx] = joint_rotation(mount, a1, a2, field.tracking_error[idx].T) @ rest
    return rot


def field_flux(
    field: FieldHeliostats,
    receiver: Target,
    azimuth: Tensor,
    elevation: Tensor,
    optics: Optics,
    *,
    blocking_shading: bool = True,
    aim_points: Tensor | None = None,
    neighbours: int = 8,
    chunk: int = 16,
    spots: Sequence[int] = (),
) -> FieldFlux:
    """Flux maps of a whole field on a flat receiver, one per sun position, and the power budget.

    Args:
        field: the heliostats (FieldHeliostats.stack).
        receiver: the receiver plane (flat_receiver); its normal points towards the field.
        azimuth, elevation: (S,) sun positions (rad; azimuth 0 = south, +pi/2 = east), elevation > 0.
        optics: sun shape, slope error, DNI, reflectivity and attenuation (effects.resolve).
        blocking_shading: trace shading and blocking between neighbours (effect `blocking_shading`).
        aim_points: (N, 3) or (3,) ENU aim points (m); default the receiver centre.
        neighbours: neighbours tested per heliostat and direction (see the module docstring).
        chunk: heliostats traced at once; memory grows with it (a few MB per heliostat at
            WINDOW = 64), not with N.
        spots: indices of K heliostats whose spots are also returned one by one.

    Returns:
        FieldFlux with flux (S, H, W) W/m^2, budget {term: (S, N) W} and spots (S, K, H, W) W/m^2.
    """
    if (elevation <= 0).any():
        raise ValueError(f"sun below the horizon: elevation {elevation.tolist()} rad; expected > 0")
    dtype, device = field.position.dtype, field.position.device
    aim = receiver.center if aim_points is None else aim_points
    aim = aim.to(dtype=dtype, device=device).expand(len(field), 3)
    suns = sun_vector(azimuth.to(dtype=dtype, device=device), elevation.to(dtype=dtype, device=device))
    wanted = torch.as_tensor(list(spots), dtype=torch.long, device=device)
    images, budgets, singles = [], [], []
    for sun in suns:
        image, budget, single = _trace_sun(field, receiver, sun, aim, optics, blocking_shading, neighbours,
                                           chunk, wanted)
        images.append(image)
        budgets.append(budget)
        singles.append(single)
    return FieldFlux(torch.stack(images), {k: torch.stack([b[k] for b in budgets]) for k in BUDGET_TERMS},
                     torch.stack(singles) if len(wanted) else None)


def _trace_sun(field, receiver, sun, aim, optics, blocking_shading, neighbours, chunk, wanted):
    """One sun position: (H, W) flux (W/m^2), {term: (N,) W} and the (K, H, W) spots of the heliostats
    `wanted` ((K,) long)."""
    n = len(field)
    rot = orientations(field, sun, aim)  # (N, 3, 3)
    rects = _facet_rectangles(field, rot)
    shade_idx = block_idx = None
    if blocking_shading and n > 1:
        k = min(neighbours, n - 1)
        # a reflected ray ends on the receiver: its beam widens from the mirror to the receiver's size
        distance = (aim - field.position).norm(dim=-1)
        half_diagonal = math.hypot(receiver.width, receiver.height) / 2
        shade_idx = _candidates(field.position, sun.expand(n, 3), field.radius, torch.zeros_like(distance), k)
        block_idx = _candidates(field.position, normalize(aim - field.position), field.radius,
                                half_diagonal / distance, k)
    image = torch.zeros(receiver.resolution, dtype=field.position.dtype, device=field.position.device)
    single = image.new_zeros(len(wanted), *receiver.resolution)
    budget = {key: torch.zeros(n, dtype=image.dtype, device=image.device) for key in BUDGET_TERMS}
    for start in range(0, n, chunk):
        rows = torch.arange(start, min(start + chunk, n), device=image.device)
        candidates = None if shade_idx is None else tuple((i[rows], v[rows])
                                                           for i, v in (shade_idx, block_idx))
        part, terms = _trace_chunk(field, rows, rot, rects, receiver, sun, aim, optics, candidates)
        image = image + part.sum(0)
        k, j = torch.nonzero(wanted[:, None] == rows[None, :], as_tuple=True)
        single[k] = part[j]
        for key, value in terms.items():
            budget[key][rows] = value
    return image, budget, single


def _facet_rectangles(field: FieldHeliostats, rot: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """Facet rectangles in ENU: centres (N, F, 3) m, axes (N, F, 3, 3) (columns right, up, normal),
    half sizes (N, F, 2) m. The facets' sag (mm) is neglected."""
    centre = field.position[:, None, :] + torch.einsum("nij,nfj->nfi", rot, field.facet_centre)
    return centre, torch.einsum("nij,nfjk->nfik", rot, field.facet_axes), field.facet_half_size


def _candidates(origin: Tensor, direction: Tensor, radius: Tensor, widening: Tensor, k: int
                ) -> tuple[Tensor, Tensor]:
    """Neighbours that a ray bundle from each heliostat along its direction may hit.

    Neighbour g of h qualifies if its pivot lies within radius_h + radius_g + along * widening_h of
    the line through h's pivot along direction_h, and along > -(radius_h + radius_g), with along the
    distance of g's pivot along that line; the k qualifying ones with the smallest `along` are kept.

    Args:
        origin: (N, 3) pivots (m); direction: (N, 3) unit directions; radius: (N,) mirror radii (m);
        widening: (N,) growth of the bundle's radius per metre along it.

    Returns:
        index (N, k) long and valid (N, k) bool (an invalid entry's index is meaningless).

    The pairs tested are found with a k-d tree, in O(N log N): a qualifying neighbour lies within
    along_max (1 + widening) + 2 reach_max of the pivot, where along_max = (reach_max + dz) /
    (direction_z - widening) (dz: the largest difference of pivot heights), because the bundle rises
    by direction_z per metre along it while the neighbour's pivot can lie at most dz + reach above;
    rows whose bundle does not rise (direction_z <= widening) test every heliostat.
    """
    from scipy.spatial import cKDTree

    n = len(origin)
    reach_max = 2 * float(radius.max())
    dz = float(origin[:, 2].max() - origin[:, 2].min())
    rise = (direction[:, 2] - widening).double()
    along_max = (reach_max + dz) / rise.clamp_min(1e-12)
    ball = torch.where(rise > 1e-6, along_max * (1 + widening.double()) + 2 * reach_max,
                       torch.full_like(rise, math.inf))
    points = origin.detach().double().cpu().numpy()
    near = cKDTree(points).query_ball_point(points, r=np.minimum(ball.cpu().numpy(), 1e300), return_sorted=False)
    index = torch.zeros(n, k, dtype=torch.long, device=origin.device)
    valid = torch.zeros(n, k, dtype=torch.bool, device=origin.device)
    order = sorted(range(n), key=lambda h: len(near[h]))
    start = 0
    while start < n:  # rows of similar candidate counts, padded to the longest: at most ~2^22 pairs a chunk
        step = max(1, min(4096, 2**22 // max(1, len(near[order[min(start + 4095, n - 1)]]))))
        chunk = order[start:start + step]
        start += step
        rows = torch.tensor(chunk, device=origin.device)
        width = max(1, len(near[chunk[-1]]))
        cand = torch.tensor([near[h] + [h] * (width - len(near[h])) for h in chunk],
                            device=origin.device)  # (B, M), padded with the row itself (never qualifies)
        rel = origin[cand] - origin[rows, None, :]  # (B, M, 3)
        along = (rel * direction[rows, None, :]).sum(-1)
        perp2 = (rel * rel).sum(-1) - along**2
        reach = radius[rows, None] + radius[cand]
        ok = ((along > -reach) & (perp2 < (reach + along.clamp_min(0) * widening[rows, None]) ** 2)
              & (cand != rows[:, None]))
        key = torch.where(ok, along, torch.full_like(along, math.inf))
        m = min(k, width)
        values, idx = torch.topk(key, m, dim=1, largest=False)
        index[rows, :m] = torch.gather(cand, 1, idx)
        valid[rows, :m] = torch.isfinite(values)
    return index, valid


def _hits(origin: Tensor, direction: Tensor, rects, index: Tensor, valid: Tensor) -> Tensor:
    """Whether each ray hits one of the candidate facet rectangles (either side) at t > 0.

    Args:
        origin: (B, P, 3) ray origins (m); direction: (B, P, 3) unit directions.
        rects: facet rectangles of all heliostats (see _facet_rectangles).
        index, valid: (B, K) candidate heliostats.

    Returns:
        (B, P) bool.
    """
    centre, axes, half = (r[index] for r in rects)  # (B, K, F, 3), (B, K, F, 3, 3), (B, K, F, 2)
    # ray origin and direction, and the facet centre, on the facet axes (right, up, normal)
    o = torch.einsum("bpi,bkfij->bpkfj", origin, axes)  # (B, P, K, F, 3)
    d = torch.einsum("bpi,bkfij->bpkfj", direction, axes)
    c = torch.einsum("bkfi,bkfij->bkfj", centre, axes)[:, None]  # (B, 1, K, F, 3)
    denom = d[..., 2]
    parallel = denom.abs() <= 1e-12
    t = (c[..., 2] - o[..., 2]) / torch.where(parallel, torch.ones_like(denom), denom)
    local = (o[..., :2] + t[..., None] * d[..., :2] - c[..., :2]).abs()
    inside = (local <= half[:, None]).all(-1)
    return (inside & ~parallel & (t > 1e-9) & valid[:, None, :, None]).flatten(2).any(-1)


def _trace_chunk(field, rows, rot, rects, receiver, sun, aim, optics, candidates):
    """Heliostats `rows` ((B,) long): their spots (B, H, W) (W/m^2) and {term: (B,) W}."""
    r = rot[rows]
    points = field.position[rows, None, :] + torch.einsum("bij,bpj->bpi", r, field.points[rows])  # (B, P, 3)
    normals = torch.einsum("bij,bpj->bpi", r, field.normals[rows])
    cos_in = (normals @ sun).clamp_min(0.0)  # (B, P)
    incident = optics.dni * field.area[rows] * cos_in
    ray = reflect(-sun, normals)  # (B, P, 3) central reflected rays
    lit = torch.ones_like(cos_in, dtype=torch.bool)
    free = torch.ones_like(lit)
    if candidates is not None:
        (shade_index, shade_valid), (block_index, block_valid) = candidates
        lit = ~_hits(points, sun.expand_as(points), rects, shade_index, shade_valid)
        free = ~_hits(points, ray, rects, block_index, block_valid)
    reflected = optics.reflectivity * incident * lit
    sent = reflected * free
    transmittance = torch.ones(len(rows), dtype=sent.dtype, device=sent.device)
    if optics.transmittance is not None:
        transmittance = optics.transmittance((aim[rows] - field.position[rows]).norm(dim=-1))
    arriving = sent * transmittance[:, None]
    spots = _spots(points, ray, arriving, receiver, optics)  # (B, H, W)
    on_receiver = spots.sum((-2, -1)) * receiver.pixel_area
    terms = {
        "incident": incident.sum(-1),
        "shaded": (incident * ~lit).sum(-1),
        "reflected": reflected.sum(-1),
        "blocked": (reflected * ~free).sum(-1),
        "attenuated": sent.sum(-1) * (1 - transmittance),
        "on_receiver": on_receiver,
    }
    terms["spilled"] = terms["reflected"] - terms["blocked"] - terms["attenuated"] - on_receiver
    return spots, terms


def _spots(points: Tensor, ray: Tensor, power: Tensor, receiver: Target, optics: Optics) -> Tensor:
    """Flux (B, H, W) W/m^2 of B heliostats' cells on the receiver (see the module docstring).

    Args:
        points: (B, P, 3) cell centres (m); ray: (B, P, 3) unit central reflected rays;
        power: (B, P) power arriving at the receiver plane (W).
    """
    rows, cols = receiver.resolution
    pw, ph = receiver.pixel_size
    centre, normal = receiver.center.to(points.dtype), receiver.normal.to(points.dtype)
    right, up = (a.to(points.dtype) for a in receiver.axes())
    toward = ray @ normal  # (B, P) < 0 for rays that travel towards the receiver's face
    t = ((centre - points) @ normal) / torch.where(toward < 0, toward, -torch.ones_like(toward))
    power = torch.where((toward < 0) & (t > 0), power, torch.zeros_like(power))
    hit = points + t[..., None] * ray - centre
    x = (hit @ right) / pw + cols / 2  # (B, P) continuous pixel coordinates: pixel j spans [j, j + 1)
    y = (receiver.height / 2 - hit @ up) / ph
    # One footprint per heliostat: that of its power-weighted mean ray.
    total = power.sum(-1, keepdim=True)
    weight = torch.where(total > 0, power / total.clamp_min(1e-30), 1 / power.shape[1])
    unit = normalize((weight[..., None] * ray).sum(1)) @ torch.stack((normal, right, up), dim=-1)  # (B, 3)
    path = (weight * t).sum(-1)
    reach = support_radius(optics.sun, optics.slope_error) * path / unit[:, 0].abs().clamp_min(1e-6)  # (B,) m
    lit = power > 0
    (x0, kx), (y0, ky) = _window(x, lit, reach / pw, cols), _window(y, lit, reach / ph, rows)
    # Deposit: padded grid coordinates, (1, 1) = centre of the first cell.
    cells = deposit((x - x0) / kx + 0.5, (y - y0) / ky + 0.5, power, (WINDOW, WINDOW))  # (B, WINDOW, WINDOW)
    cell = torch.cat((kx * pw, ky * ph), -1)  # (B, 2) cell width, height (m)
    if optics.sun.kind == "point" and optics.slope_error == 0:
        flux = cells / (cell[:, 0] * cell[:, 1])[:, None, None]  # the beam does not spread
    else:
        flux = _convolve_footprint(cells, unit, path, cell, reach, optics)
    # Bilinear interpolation of the cell averages at the receiver's pixel centres (align_corners:
    # -1 and 1 are the centres of the first and last cells).
    gx = ((torch.arange(cols, dtype=x.dtype, device=x.device) + 0.5 - x0) / kx - 0.5) * 2 / (WINDOW - 1) - 1
    gy = ((torch.arange(rows, dtype=x.dtype, device=x.device) + 0.5 - y0) / ky - 0.5) * 2 / (WINDOW - 1) - 1
    grid = torch.stack(torch.broadcast_tensors(gx[:, None, :], gy[:, :, None]), dim=-1)  # (B, H, W, 2)
    return torch.nn.functional.grid_sample(flux[:, None], grid, mode="bilinear", padding_mode="zeros",
                                           align_corners=True)[:, 0]


def _window(x: Tensor, lit: Tensor, reach: Tensor, pixels: int) -> tuple[Tensor, Tensor]:
    """Along one receiver axis, each spot's grid of WINDOW cells of k pixels: it covers the lit
    deposits and, within the receiver, everything the footprint reaches, with one cell of margin.

    Args:
        x: (B, P) deposit coordinates in pixels (pixel j spans [j, j + 1)); lit: (B, P) which carry power;
        reach: (B,) the footprint's reach in pixels; pixels: the receiver's size in pixels.

    Returns:
        first pixel coordinate of the grid x0 (B, 1) and cell size k (B, 1) in pixels (integers >= 1).
    """
    inf = torch.full_like(x, math.inf)
    centre = pixels / 2  # a heliostat with no lit cell: any window, it deposits nothing
    lo = torch.where(lit, x, inf).amin(-1).nan_to_num(centre, centre, centre)
    hi = torch.where(lit, x, -inf).amax(-1).nan_to_num(centre, centre, centre)
    lo = torch.minimum(lo, (lo - reach).clamp(0, pixels))
    hi = torch.maximum(hi, (hi + reach).clamp(0, pixels))
    k = ((hi.ceil() - lo.floor()) / (WINDOW - 2)).ceil().clamp_min(1)
    return (lo.floor() - k)[:, None], k[:, None]


def _convolve_footprint(cells: Tensor, unit: Tensor, path: Tensor, cell: Tensor, reach: Tensor,
                        optics: Optics) -> Tensor:
    """(B, WINDOW, WINDOW) deposited power (W) convolved with each heliostat's footprint: flux (W/m^2).

    Args:
        unit: (B, 3) mean ray on the receiver's (normal, right, up); path: (B,) its length (m);
        cell: (B, 2) cell width and height (m); reach: (B,) the footprint's reach (m).
    """
    kernel = footprint(density_lookup(optics.sun, float(optics.slope_error)), unit, path, cell,
                       (WINDOW - 1, WINDOW - 1))
    # A footprint wholly inside its window carries exactly the ray's power (cf. raytrace).
    inside = reach < (WINDOW - 1) * cell.amin(-1)
    norm = kernel.sum((-2, -1)) * cell[:, 0] * cell[:, 1]
    kernel = torch.where(inside[:, None, None], kernel / norm[:, None, None].clamp_min(1e-30), kernel)
    # Circular convolution of period 2 WINDOW: the wrapped sums land outside the crop.
    size = (2 * WINDOW, 2 * WINDOW)
    flux = torch.fft.irfft2(torch.fft.rfft2(cells, s=size) * torch.fft.rfft2(kernel, s=size), s=size)
    crop = slice(WINDOW - 1, 2 * WINDOW - 1)
    return flux[:, crop, crop].clamp_min(0.0)  # both factors are >= 0: the clamp removes FFT round-off
