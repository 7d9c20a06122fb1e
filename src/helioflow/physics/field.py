"""Field flux: all heliostats of a field traced at once onto a flat receiver, with shading,
blocking and atmospheric attenuation, and the power budget of every heliostat.

Optical model. Each facet is sampled on a grid of cells (heliostat.sample_surface). Per sun
position and cell the central ray is followed exactly: its incoming sunlight may be shaded, its
reflected ray blocked, then it meets the receiver plane. As in raytrace's `kernel` splatting, the
beam spread (sun shape convolved with the slope error, sun.radial_density) enters as the analytic
footprint of each central ray, flux = power * f(theta) * cos(gamma) / r^2. The approximation that
makes a field cheap: per heliostat one footprint, that of its power-weighted mean ray (raytrace
adds its first-order change across the heliostat: across a heliostat the ray direction changes by
its size over the slant range, ~1 %, which skews the spot; see raytrace.splat_footprints), with its
own slope error where FieldHeliostats.slope_error gives one, and each
heliostat's spot is computed on its own grid of WINDOW x WINDOW cells that covers the spot's reach
on the receiver, with cells an integer number k of receiver pixels wide, then interpolated
bilinearly onto the receiver pixels. Near heliostats (small spots) get k = 1, the receiver's own
pixels, which reproduces raytrace's kernel image; far ones, whose spots are smooth on the scale of
the slope-error blur, get coarser cells. The footprint is evaluated only as
far as it reaches (heliostats are traced in chunks of similar slant range, so a chunk shares that
extent), averaged over q x q points per cell where it is sharp on the scale of a cell and sampled at
the cell centre where its finest structure (sun.finest_scale) spans SMOOTH_CELLS cells or more
(tests/physics/test_field.py: 70 dB against supersampling everywhere); the interpolation onto the
receiver is separable, so a chunk's spots sum into the map as one matrix product. For one heliostat the field tracer
and raytrace.trace(splat="kernel") agree to 2e-4 in power on the receiver (6e-4 for a far spot
that spills: the kernel tracer adds the footprint's first-order change across the heliostat, the
field tracer does not) and 45-56 dB PSNR
(tests/physics/test_field.py); both blur by the slope error isotropically (see raytrace). Shading
and blocking act on whole cells (their central rays); the sun's finite size (penumbra), the
tower's shadow and blocking by facets of the same heliostat are neglected.

Shading and blocking. Shading: the ray from a cell towards the sun hits a neighbour's facet
rectangle (either side) first. Blocking: the cell's reflected central ray hits a neighbour's facet
rectangle before the receiver. Only neighbours that can be hit are tested: for heliostat h and a
direction d (the sun, or h -> its aim point) a neighbour g can intercept a ray from h only if its
pivot lies within radius_h + radius_g (+ the widening of the beam towards the receiver) of the line
through h's pivot along d (radius = bounding sphere of the mirror about its pivot); of those the
`neighbours` nearest along d are kept; the pairs are found with a k-d tree (O(N log N)). A cell's
ray is tested against a candidate's facets only if it passes through the candidate's bounding
sphere, so the ray tests grow with the rays that come near a neighbour.

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
from typing import Any

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
from helioflow.physics.raytrace import (
    FOOTPRINT_SUPERSAMPLING,
    Optics,
    _fft_size,
    density_lookup,
    deposit,
    footprint,
)
from helioflow.physics.sun import finest_scale, support_radius
from helioflow.physics.target import Target

WINDOW = 64  # at most this many cells per side of a heliostat's spot grid
SMOOTH_CELLS = 2.0  # footprints whose finest structure spans this many cells are sampled once per cell
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
        slope_error: (N,) each heliostat's own slope error (rad, per axis; the beam spread it adds
            to the sun's), or None: the optics' slope error for every heliostat (field_flux).
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
    slope_error: Tensor | None = None

    def __len__(self) -> int:
        return len(self.position)

    @staticmethod
    def stack(heliostats: Sequence[Heliostat], cells_per_side: int = 8, dtype: torch.dtype | None = None,
              slope_error: Sequence[float] | None = None) -> FieldHeliostats:
        """Batch a list of heliostats that share the facet count and control-point grid.

        Args:
            heliostats: N heliostats, each with its own position and errors.
            cells_per_side: each facet is sampled on cells_per_side^2 equal cells.
            dtype: dtype of the tensors; default that of the first heliostat.
            slope_error: N slope errors (rad), each heliostat's own; None: the optics' for all.
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
        if slope_error is not None and len(slope_error) != len(heliostats):
            raise ValueError(f"{len(slope_error)} slope errors for {len(heliostats)} heliostats")
        own = None if slope_error is None else torch.tensor(list(slope_error), dtype=dtype, device=size.device)
        return FieldHeliostats(stack("position"), tuple(h.mount for h in heliostats), stack("tracking_error"),
                               points.to(dtype), normals.to(dtype), area.to(dtype), translation, axes,
                               size / 2, radius, own)


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
        merged_tensors: dict[str, Any] = {name: torch.cat([getattr(h, name) for h in group]) for name in names}
        merged = replace(first, facet_focal_length=f, **merged_tensors)
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

    def asked_spots(self) -> Tensor:
        """`spots` of a trace that asked for them (ValueError for one that did not)."""
        if self.spots is None:
            raise ValueError("the field was traced without the heliostats' own spots (field_flux(spots=...))")
        return self.spots

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
    chunk: int = 32,
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
    shade_idx: tuple[Tensor, Tensor] | None = None
    block_idx: tuple[Tensor, Tensor] | None = None
    distance = (aim - field.position).norm(dim=-1)
    if blocking_shading and n > 1:
        k = min(neighbours, n - 1)
        # a reflected ray ends on the receiver: its beam widens from the mirror to the receiver's size
        half_diagonal = math.hypot(receiver.width, receiver.height) / 2
        shade_idx = _candidates(field.position, sun.expand(n, 3), field.radius, torch.zeros_like(distance), k)
        block_idx = _candidates(field.position, normalize(aim - field.position), field.radius,
                                half_diagonal / distance, k)
    image = torch.zeros(receiver.resolution, dtype=field.position.dtype, device=field.position.device)
    single = image.new_zeros(len(wanted), *receiver.resolution)
    budget = {key: torch.zeros(n, dtype=image.dtype, device=image.device) for key in BUDGET_TERMS}
    # chunks of heliostats at similar distances share the footprint's extent (see _convolve_footprint)
    order = torch.argsort(distance)
    for start in range(0, n, chunk):
        rows = order[start:start + chunk]
        candidates = None if shade_idx is None or block_idx is None else tuple((i[rows], v[rows])
                                                                               for i, v in (shade_idx, block_idx))
        spots, terms = _trace_chunk(field, rows, rot, rects, receiver, sun, aim, optics, candidates)
        image = image + spots.total()
        k, j = torch.nonzero(wanted[:, None] == rows[None, :], as_tuple=True)
        single[k] = spots.images(j)
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

    The pairs tested are found with a k-d tree, in O(N log N): a qualifying neighbour lies at an
    along of at most along_max = (reach_max + dz) / (direction_z - widening) (dz: the largest
    difference of pivot heights), because the bundle rises by direction_z per metre along it while
    the neighbour's pivot can lie at most dz + reach above (reach_max: the largest radius_h + radius_g),
    and never farther than the field's extent. The part of the bundle from -reach_max to there is
    covered by balls centred on its line, one per 2 reach_max of length, each holding its stretch of
    the widening bundle: the pivots in them are the pairs tested, about as many as lie near the
    line, however far it runs across the field.
    """
    from scipy.spatial import cKDTree

    n = len(origin)
    reach_max = 2 * float(radius.max())
    points = origin.detach().double().cpu().numpy()
    line, grow = direction.detach().double().cpu().numpy(), widening.detach().double().cpu().numpy()
    extent = float(np.linalg.norm(points.max(0) - points.min(0)))
    rise = line[:, 2] - grow
    along_max = np.full(n, extent)
    rising = rise > 1e-6
    along_max[rising] = np.minimum((reach_max + np.ptp(points[:, 2])) / rise[rising], extent)
    spacing = 2 * reach_max
    balls = np.ceil((along_max + reach_max) / spacing).astype(np.int64)  # (N,) balls per row, >= 1
    row = np.repeat(np.arange(n), balls)
    centre = -reach_max + spacing * (np.arange(len(row)) - np.repeat(np.cumsum(balls) - balls, balls) + 0.5)
    perp = reach_max + np.maximum(centre + spacing / 2, 0.0) * grow[row]  # the bundle's radius at the ball's far end
    found = cKDTree(points).query_ball_point(points[row] + centre[:, None] * line[row],
                                             r=np.hypot(perp, spacing / 2) * (1 + 1e-9), return_sorted=False)
    near_sets: list[set[int]] = [set() for _ in range(n)]
    for h, hits in zip(row.tolist(), found):
        near_sets[h].update(hits)
    near = [list(s) for s in near_sets]
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


def _hits(origin: Tensor, direction: Tensor, field: FieldHeliostats, rects, index: Tensor, valid: Tensor
          ) -> Tensor:
    """Whether each ray hits one of the candidate facet rectangles (either side) at t > 0.

    Only the rays that pass through a candidate's bounding sphere (field.radius about its pivot) are
    tested against its facets: the work grows with the rays that come near a neighbour, not with
    rays x candidates x facets.

    Args:
        origin: (B, P, 3) ray origins (m); direction: (B, P, 3) unit directions.
        field: the heliostats (pivots and radii); rects: their facet rectangles (_facet_rectangles).
        index, valid: (B, K) candidate heliostats.

    Returns:
        (B, P) bool.
    """
    hits = torch.zeros(origin.shape[:2], dtype=origin.dtype, device=origin.device)
    pair, slot = torch.nonzero(valid, as_tuple=True)  # (M,) ray bundle b and its candidate
    other = index[pair, slot]
    rel = field.position[other, None, :] - origin[pair]  # (M, P, 3) candidate pivot from each ray's origin
    along = (rel * direction[pair]).sum(-1)
    radius = field.radius[other, None]
    near = (along > -radius) & ((rel * rel).sum(-1) - along**2 < radius**2)  # (M, P)
    which, cell = torch.nonzero(near, as_tuple=True)  # (Q,) ray-candidate pairs to test facet by facet
    bundle, other = pair[which], other[which]
    centre, axes, half = (r[other] for r in rects)  # (Q, F, 3), (Q, F, 3, 3), (Q, F, 2)
    # ray origin and direction relative to the facet centre, on the facet axes (right, up, normal)
    o = torch.einsum("qfi,qfij->qfj", origin[bundle, cell][:, None, :] - centre, axes)  # (Q, F, 3)
    d = torch.einsum("qi,qfij->qfj", direction[bundle, cell], axes)
    denom = d[..., 2]
    parallel = denom.abs() <= 1e-12
    t = -o[..., 2] / torch.where(parallel, torch.ones_like(denom), denom)
    inside = ((o[..., :2] + t[..., None] * d[..., :2]).abs() <= half).all(-1)
    hit = (inside & ~parallel & (t > 1e-9)).any(-1)  # (Q,)
    hits.index_put_((bundle, cell), hit.to(hits.dtype), accumulate=True)
    return hits > 0


def _trace_chunk(field, rows, rot, rects, receiver, sun, aim, optics, candidates):
    """Heliostats `rows` ((B,) long): their spots (_Spots, W/m^2) and {term: (B,) W}."""
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
        lit = ~_hits(points, sun.expand_as(points), field, rects, shade_index, shade_valid)
        free = ~_hits(points, ray, field, rects, block_index, block_valid)
    reflected = optics.reflectivity * incident * lit
    sent = reflected * free
    transmittance = torch.ones(len(rows), dtype=sent.dtype, device=sent.device)
    if optics.transmittance is not None:
        transmittance = optics.transmittance((aim[rows] - field.position[rows]).norm(dim=-1))
    arriving = sent * transmittance[:, None]
    own = None if field.slope_error is None else field.slope_error[rows]
    spots = _spots(points, ray, arriving, receiver, optics, own)
    on_receiver = spots.sums() * receiver.pixel_area
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


@dataclass
class _Spots:
    """B heliostats' flux on the receiver, each kept on its own grid of C x C cells (C <= WINDOW) and
    rendered by bilinear interpolation: spot_b = row_weights_b @ cells_b @ col_weights_b^T.

    Attributes:
        cells: (B, C, C) flux (W/m^2) at the cell centres.
        row_weights: (B, H, C) and col_weights: (B, W, C) interpolation weights of the
            receiver's pixel centres (zero beyond the first and last cell centres).
    """

    cells: Tensor
    row_weights: Tensor
    col_weights: Tensor

    def images(self, which: Tensor) -> Tensor:
        """(K, H, W) spots of the heliostats `which` ((K,) long)."""
        return self.row_weights[which] @ self.cells[which] @ self.col_weights[which].transpose(1, 2)

    def total(self) -> Tensor:
        """(H, W) the sum of the B spots, as one matrix product (no (B, H, W) intermediate)."""
        rows = self.row_weights.permute(1, 0, 2).flatten(1)  # (H, B C)
        return rows @ (self.cells @ self.col_weights.transpose(1, 2)).flatten(0, 1)

    def sums(self) -> Tensor:
        """(B,) each spot summed over the receiver's pixels (W/m^2)."""
        return torch.einsum("bc,bcd,bd->b", self.row_weights.sum(1), self.cells, self.col_weights.sum(1))


def _optics_groups(optics: Optics, slope_error: Tensor | None) -> list[tuple[Tensor | slice, Optics]]:
    """[(members: (B,) bool or slice(None) for all, their optics)]: heliostats with the same slope
    error share a footprint; slope_error (B,) rad, each heliostat's own, or None: all take `optics`."""
    values = None if slope_error is None else slope_error.unique()
    if values is None or len(values) == 1:  # one footprint for all: no masked copies
        return [(slice(None), optics if values is None else replace(optics, slope_error=float(values[0])))]
    return [(slope_error == value, replace(optics, slope_error=float(value))) for value in values]


def _spots(points: Tensor, ray: Tensor, power: Tensor, receiver: Target, optics: Optics,
           slope_error: Tensor | None = None) -> _Spots:
    """Flux of B heliostats' cells on the receiver (see the module docstring).

    Args:
        points: (B, P, 3) cell centres (m); ray: (B, P, 3) unit central reflected rays;
        power: (B, P) power arriving at the receiver plane (W);
        slope_error: (B,) each heliostat's own slope error (rad), or None: the optics'.
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
    groups = _optics_groups(optics, slope_error)
    radius = path.new_empty(len(path))
    for members, own in groups:
        radius[members] = support_radius(own.sun, own.slope_error)
    reach = radius * path / unit[:, 0].abs().clamp_min(1e-6)  # (B,) m
    lit = power > 0
    (x0, kx, nx), (y0, ky, ny) = _window(x, lit, reach / pw, cols), _window(y, lit, reach / ph, rows)
    size = int(torch.maximum(nx.max(), ny.max()))  # the chunk's grid: as many cells as its widest window needs
    # Deposit: padded grid coordinates, (1, 1) = centre of the first cell.
    cells = deposit((x - x0) / kx + 0.5, (y - y0) / ky + 0.5, power, (size, size))  # (B, C, C)
    cell = torch.cat((kx * pw, ky * ph), -1)  # (B, 2) cell width, height (m)

    def spread(m, own: Optics) -> Tensor:  # the heliostats m of one slope error
        if own.sun.kind == "point" and own.slope_error == 0:
            return cells[m] / (cell[m, 0] * cell[m, 1])[:, None, None]  # the beam does not spread
        return _convolve_footprint(cells[m], unit[m], path[m], cell[m], reach[m], own)

    if len(groups) == 1:
        flux = spread(*groups[0])
    else:
        flux = torch.empty_like(cells)
        for m, own in groups:
            flux[m] = spread(m, own)
    return _Spots(flux, _interpolation(rows, y0, ky, size), _interpolation(cols, x0, kx, size))


def _interpolation(pixels: int, first: Tensor, k: Tensor, size: int) -> Tensor:
    """(B, pixels, size) weights of linear interpolation from the centres of `size` cells of k (B, 1)
    pixels starting at pixel coordinate `first` (B, 1) to the centres of the receiver's `pixels`
    pixels along one axis; zero beyond the first and last cell centres."""
    centre = (torch.arange(pixels, dtype=first.dtype, device=first.device) + 0.5 - first) / k - 0.5  # (B, pixels)
    offset = centre[..., None] - torch.arange(size, dtype=first.dtype, device=first.device)
    return (1 - offset.abs()).clamp_min(0.0)


def _window(x: Tensor, lit: Tensor, reach: Tensor, pixels: int) -> tuple[Tensor, Tensor, Tensor]:
    """Along one receiver axis, each spot's grid of at most WINDOW cells of k pixels: it covers the lit
    deposits and, within the receiver, everything the footprint reaches, with one cell of margin.

    Args:
        x: (B, P) deposit coordinates in pixels (pixel j spans [j, j + 1)); lit: (B, P) which carry power;
        reach: (B,) the footprint's reach in pixels; pixels: the receiver's size in pixels.

    Returns:
        first pixel coordinate of the grid x0 (B, 1), cell size k (B, 1) in pixels (integers >= 1) and
        the number of cells needed (B,) (<= WINDOW; a grid may have more, all beyond the reach).
    """
    inf = torch.full_like(x, math.inf)
    centre = pixels / 2  # a heliostat with no lit cell: any window, it deposits nothing
    lo = torch.where(lit, x, inf).amin(-1).nan_to_num(centre, centre, centre)
    hi = torch.where(lit, x, -inf).amax(-1).nan_to_num(centre, centre, centre)
    lo = torch.minimum(lo, (lo - reach).clamp(0, pixels))
    hi = torch.maximum(hi, (hi + reach).clamp(0, pixels))
    span = hi.ceil() - lo.floor()
    k = (span / (WINDOW - 2)).ceil().clamp_min(1)
    return (lo.floor() - k)[:, None], k[:, None], (span / k).ceil() + 2


def _convolve_footprint(cells: Tensor, unit: Tensor, path: Tensor, cell: Tensor, reach: Tensor,
                        optics: Optics) -> Tensor:
    """(B, C, C) deposited power (W) convolved with each heliostat's footprint: flux (W/m^2).

    Args:
        unit: (B, 3) mean ray on the receiver's (normal, right, up); path: (B,) its length (m);
        cell: (B, 2) cell width and height (m); reach: (B,) the footprint's reach (m).
    """
    # The kernel reaches J cells each way (J < C); a circular convolution of period >= C + J
    # keeps the wrapped sums outside the crop.
    size = cells.shape[-1]
    reach_cells = int(min(size - 1, math.ceil(float((reach / cell.amin(-1)).max())) + 1))
    # A footprint smooth on the scale of a cell is sampled at the cell centres, a sharper one averaged
    # over q x q points per cell (raytrace.FOOTPRINT_SUPERSAMPLING).
    density = density_lookup(optics.sun, float(optics.slope_error))
    smooth = finest_scale(optics.sun, float(optics.slope_error)) * path >= SMOOTH_CELLS * cell.amax(-1)  # (B,)
    kernel = cells.new_empty(len(cells), 2 * reach_cells + 1, 2 * reach_cells + 1)
    for rows, q in ((smooth, 1), (~smooth, FOOTPRINT_SUPERSAMPLING)):
        if rows.any():
            kernel[rows] = footprint(density, unit[rows], path[rows], cell[rows], (reach_cells, reach_cells), q)
    # A footprint wholly inside its grid carries exactly the ray's power (cf. raytrace).
    inside = reach < reach_cells * cell.amin(-1)
    norm = kernel.sum((-2, -1)) * cell[:, 0] * cell[:, 1]
    kernel = torch.where(inside[:, None, None], kernel / norm[:, None, None].clamp_min(1e-30), kernel)
    period = (_fft_size(size + reach_cells),) * 2
    flux = torch.fft.irfft2(torch.fft.rfft2(cells, s=period) * torch.fft.rfft2(kernel, s=period), s=period)
    crop = slice(reach_cells, reach_cells + size)
    return flux[:, crop, crop].clamp_min(0.0)  # both factors are >= 0: the clamp removes FFT round-off
