"""Aim points that keep a receiver under its flux limit: spots precomputed once, shifted by the aim.

Moving a heliostat's aim point by (u, v) on the receiver plane (m, right and up) moves its spot by
the same (u, v): the reflected central ray passes through the aim point, and for aim moves of a few
metres at slant ranges of 40 m and more the mirror turns by under 3 degrees, so the spot's shape
(cosine, astigmatism, blocking) barely changes. Each heliostat's spot is therefore traced once, aimed
at the receiver centre, on a receiver grid extended on every side by the largest aim move, cut to a
patch around its support (`SpotPatches`), and the receiver's flux map for any aim offsets is the sum
of the patches shifted bilinearly (`render`): differentiable in the offsets, cheap (N x P x P adds
per map, no ray), exact for whole-pixel moves of an unchanged spot. Rule `optimise_aim` judges every
aim it chooses by tracing the true field at those aim points, so the shift's own error is measured,
not assumed (aim.json's `model_peak_over_limit` beside `truth_peak_over_limit`).

The limit is one value or a map (`limit_map`: a grid of values stretched over the receiver, as where
a receiver's panels or tubes take different fluxes); "the peak over the limit" is then the largest
ratio of flux to the local limit, and every test below compares flux with the limit pixel by pixel.

The choice (`optimise`): maximise the power on the receiver with the peak flux at most the limit,
aim points within `region` of the receiver's half extent, by projected Adam on the (N, 2) offsets
from a start aiming, with a quadratic penalty on the flux above the limit whose weight grows
geometrically over the steps (a penalty method: early steps spread the spots, late ones enforce the
limit); the result is the best iterate that keeps the limit on the model's map (the lowest peak when
none does). With a target distribution (`target_shares`: the share of the reflected power each pixel
should get) the power term gives way to the squared difference from that target carrying all the
reflected power, so that spillage counts as a miss, and "best" means the highest `target_accuracy`;
each iterate is judged with the offsets rounded to whole pixels: a bilinear shift by a fraction of a pixel
averages neighbouring pixels and so lowers the peak it promises, a whole-pixel one does not (the aim
points are then placed to a pixel, 4 cm on the default receiver, under the 10 cm by which a tracking
error of 1 mrad moves a spot at 100 m). Its cost is `steps` renders and their gradients: O(steps N P^2), no ray.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

SUPPORT = 0.999  # a patch holds this share of its spot's power on the extended grid
POWER_TOLERANCE = 1e-4  # relative gain in power (or target accuracy) for which the optimiser leaves its best aiming

Limit = float | Tensor  # W/m^2: one value, or a (rows, columns) map on the receiver grid


def _stretched(cells: list[list[float]], shape: tuple[int, int], dtype: torch.dtype,
               device: torch.device | str) -> Tensor:
    """(rows, columns) the grid of `cells` (the top row first, columns left to right as seen from the
    field, rows of equal length), each cell covering an equal share of the receiver, on the receiver's
    `shape` grid: each pixel takes the cell its centre lies in."""
    grid = torch.as_tensor(cells, dtype=dtype, device=device)  # (R, C)
    rows, cols = shape
    r = (torch.arange(rows, device=device) * grid.shape[0]) // rows
    c = (torch.arange(cols, device=device) * grid.shape[1]) // cols
    return grid[r[:, None], c[None, :]]


def limit_map(limit_kw_m2: float | list[list[float]], shape: tuple[int, int], dtype: torch.dtype = torch.float64,
              device: torch.device | str = "cpu") -> Limit:
    """The receiver's flux limit (W/m^2) from config `optimise_aim.limit_kw_m2`: a number as it is, or
    rows of kW/m^2 as a (rows, columns) map on the receiver's `shape` grid (`_stretched`)."""
    if not isinstance(limit_kw_m2, list):
        return float(limit_kw_m2) * 1e3
    return _stretched(limit_kw_m2, shape, dtype, device) * 1e3


def target_shares(target: list[list[float]], shape: tuple[int, int], dtype: torch.dtype = torch.float64,
                  device: torch.device | str = "cpu") -> Tensor:
    """(rows, columns) the share of the reflected power each receiver pixel should get (sums to 1), from
    config `optimise_aim.target`: rows of relative flux (>= 0, laid out as a limit map, `_stretched`)."""
    weights = _stretched(target, shape, dtype, device)
    return weights / weights.sum()


def target_accuracy(flux: Tensor, shares: Tensor, power_w: float, pixel_area_m2: float) -> float:
    """How close the (rows, columns) flux (W/m^2) comes to the target distribution: 1 - sum|F - T| / sum T,
    T the target `shares` carrying the reflected `power_w` (W) over pixels of `pixel_area_m2`; 1 is the
    target met, power spilled off the receiver counts as missing."""
    wanted = shares * (power_w / pixel_area_m2)
    return float(1 - (flux - wanted).abs().sum() / wanted.sum())


def limit_text(limit_kw_m2: float | list[list[float]]) -> str:
    """Config `optimise_aim.limit_kw_m2` in words: "5 kW/m²", or "a 2 x 1 map of 4-8 kW/m²"."""
    if not isinstance(limit_kw_m2, list):
        return f"{limit_kw_m2:g} kW/m²"
    values = [v for row in limit_kw_m2 for v in row]
    return f"a {len(limit_kw_m2)} x {len(limit_kw_m2[0])} map of {min(values):g}-{max(values):g} kW/m²"


@dataclass
class Goal:
    """What an aiming is for (config optimise_aim): keep `limit` (W/m^2, one value or a (rows, columns)
    map) and either maximise the power on the receiver (`target` None) or approach the `target`
    distribution ((rows, columns) shares of the reflected power, `target_shares`)."""

    limit: Limit
    target: Tensor | None = None

    @staticmethod
    def from_settings(settings: dict, shape: tuple[int, int], device: torch.device | str = "cpu") -> Goal:
        """The goal of config optimise_aim's `limit_kw_m2` and `target` on a receiver grid of `shape`."""
        target = settings.get("target")
        return Goal(limit_map(settings["limit_kw_m2"], shape, device=device),
                    None if target is None else target_shares(target, shape, device=device))


def peak_over_limit(flux: Tensor, limit: Limit) -> float:
    """The largest ratio of the (..., rows, columns) flux (W/m^2) to the limit (W/m^2)."""
    return float((flux / limit).max())


@dataclass
class PatchGroup:
    """Heliostats whose spots fit one patch size P (SpotPatches.from_maps groups them by size).

    Attributes:
        members: (n,) their indices among the N heliostats.
        shifted: (4, n, P + 1, P + 1) each patch padded by one row and column, and moved by (0, 0),
            (0, 1), (1, 0) and (1, 1) pixels (rows, columns): the four terms of a bilinear shift.
        corner: (n, 2) (row, column) of each patch's top-left pixel on the receiver grid at zero aim
            offset (rows from the top edge, columns to the right as seen from the field; negative or
            beyond the receiver on the extended grid).
    """

    members: Tensor
    shifted: Tensor
    corner: Tensor


@dataclass
class SpotPatches:
    """N heliostats' spots, aimed at the receiver centre, as patches on the receiver's pixel grid.

    Attributes:
        groups: the heliostats by patch size (PatchGroup).
        count: N.
        shape: (rows, columns) of the receiver.
        pixel_m: (width, height) of a receiver pixel (m).
    """

    groups: list[PatchGroup]
    count: int
    shape: tuple[int, int]
    pixel_m: tuple[float, float]

    @staticmethod
    def from_maps(maps: Tensor, shape: tuple[int, int], pixel_m: tuple[float, float]) -> SpotPatches:
        """Patches from (N, He, We) spots on an extended grid of receiver-sized pixels whose centre
        is the receiver's centre (He - rows and We - columns even). Each spot's patch is the smallest
        square holding SUPPORT of its power (capped at the grid), its side rounded up to a power of
        2^(1/4) so that the heliostats fall into a few groups of one size."""
        n, he, we = maps.shape
        rows, cols = shape
        if (he - rows) % 2 or (we - cols) % 2 or he < rows or we < cols:
            raise ValueError(f"spots on a {he} x {we} grid do not extend a {rows} x {cols} receiver evenly")
        lo_r, hi_r = _support(maps.sum(2))
        lo_c, hi_c = _support(maps.sum(1))
        need = torch.maximum(hi_r - lo_r, hi_c - lo_c) + 1
        size = torch.clamp(torch.ceil(2 ** (torch.ceil(4 * torch.log2(need.double())) / 4)).long(), max=min(he, we))
        top = torch.clamp((lo_r + hi_r + 1 - size) // 2, min=0)
        left = torch.clamp((lo_c + hi_c + 1 - size) // 2, min=0)
        top, left = torch.minimum(top, he - size), torch.minimum(left, we - size)
        origin = torch.tensor([(he - rows) // 2, (we - cols) // 2], device=maps.device)
        groups = []
        for p in torch.unique(size).tolist():
            members = torch.nonzero(size == p).flatten()
            window = torch.arange(p, device=maps.device)
            r = (top[members][:, None] + window)[:, :, None]
            c = (left[members][:, None] + window)[:, None, :]
            patches = maps[members[:, None, None], r, c]
            corner = (torch.stack((top[members], left[members]), -1) - origin).to(maps.dtype)
            groups.append(PatchGroup(members, _shifted(patches), corner))
        return SpotPatches(groups, n, shape, pixel_m)

    @staticmethod
    def merge(parts: list[SpotPatches]) -> SpotPatches:
        """One SpotPatches of parts made from consecutive heliostats (e.g. from_maps on chunks of a
        large field), groups of one patch size joined."""
        by_size: dict[int, list[PatchGroup]] = {}
        count = 0
        for part in parts:
            for g in part.groups:
                by_size.setdefault(g.shifted.shape[-1], []).append(PatchGroup(g.members + count, g.shifted, g.corner))
            count += part.count
        groups = [PatchGroup(torch.cat([g.members for g in gs]), torch.cat([g.shifted for g in gs], 1),
                             torch.cat([g.corner for g in gs])) for gs in by_size.values()]
        return SpotPatches(groups, count, parts[0].shape, parts[0].pixel_m)

    def power_w(self) -> Tensor:
        """(N,) each spot's power on its patch (W)."""
        power = torch.zeros(self.count, dtype=self.groups[0].shifted.dtype, device=self.groups[0].shifted.device)
        for g in self.groups:
            power[g.members] = g.shifted[0].sum((-2, -1))
        return power * self.pixel_m[0] * self.pixel_m[1]


def _shifted(patches: Tensor) -> Tensor:
    """(4, n, P + 1, P + 1) the (n, P, P) patches padded and moved by (0, 0), (0, 1), (1, 0), (1, 1) px."""
    pad = torch.nn.functional.pad
    return torch.stack([pad(patches, (dc, 1 - dc, dr, 1 - dr)) for dr in (0, 1) for dc in (0, 1)])


def _support(profiles: Tensor) -> tuple[Tensor, Tensor]:
    """(N,) first and last index of the central SUPPORT share of each (N, L) non-negative profile."""
    cum = profiles.cumsum(-1)
    total = cum[:, -1:].clamp_min(1e-300)
    tail = (1 - SUPPORT) / 2
    lo = (cum / total < tail).sum(-1)
    hi = (cum / total < 1 - tail).sum(-1)
    return lo, torch.minimum(hi, torch.full_like(hi, profiles.shape[-1] - 1))


def render(spots: SpotPatches, offsets: Tensor) -> Tensor:
    """(rows, columns) receiver flux (W/m^2): every patch moved by its aim offset and summed.

    The patches are added onto a canvas that extends the receiver by the largest patch on every
    side (a patch further out is entirely off the receiver and is placed at the canvas edge), so
    that one index_add per group places them without bounds checks.

    Args:
        spots: the patches (SpotPatches).
        offsets: (N, 2) aim offsets (u right, v up) from the receiver centre (m); differentiable.
    """
    rows, cols = spots.shape
    margin = max(g.shifted.shape[-1] for g in spots.groups)
    width = cols + 2 * margin
    canvas = torch.zeros((rows + 2 * margin) * width, dtype=offsets.dtype, device=offsets.device)
    for g in spots.groups:
        shift = offsets[g.members]
        row = g.corner[:, 0] - shift[:, 1] / spots.pixel_m[1]  # up moves the spot to lower rows
        col = g.corner[:, 1] + shift[:, 0] / spots.pixel_m[0]
        r0, c0 = torch.floor(row.detach()), torch.floor(col.detach())
        fr, fc = (row - r0)[:, None, None], (col - c0)[:, None, None]
        moved = (1 - fr) * ((1 - fc) * g.shifted[0] + fc * g.shifted[1]) + fr * (
            (1 - fc) * g.shifted[2] + fc * g.shifted[3])
        size = g.shifted.shape[-1]
        top = torch.clamp(r0.long(), -size, rows) + margin
        left = torch.clamp(c0.long(), -size, cols) + margin
        local = (torch.arange(size, device=offsets.device)[:, None] * width
                 + torch.arange(size, device=offsets.device)[None, :]).flatten()
        index = ((top * width + left)[:, None] + local[None, :]).flatten()
        canvas = canvas.index_add(0, index, moved.reshape(-1).to(offsets.dtype))
    return canvas.view(rows + 2 * margin, width)[margin:margin + rows, margin:margin + cols]


@dataclass
class AimResult:
    """An optimised aiming.

    Attributes:
        offsets: (N, 2) aim offsets (u right, v up) from the receiver centre (m).
        peak_over_limit: the largest ratio of the model's flux at those offsets to the limit.
        on_receiver_w: the model's power on the receiver (W).
        feasible: whether the model's map keeps the limit.
        target_accuracy: with a target distribution, how close the model's map comes to it
            (`target_accuracy`); None without.
    """

    offsets: Tensor
    peak_over_limit: float
    on_receiver_w: float
    feasible: bool
    target_accuracy: float | None = None


def optimise(
    spots: SpotPatches,
    start: Tensor,
    limit_w_m2: Limit,
    *,
    region: float,
    steps: int,
    learning_rate_m: float | None = None,
    penalty: tuple[float, float] = (1.0, 1e6),
    seed: int = 0,
    target: Tensor | None = None,
) -> AimResult:
    """Aim offsets that maximise the power on the receiver with the peak at most `limit_w_m2`, or, with
    a `target`, that bring the map closest to that distribution with the peak at most the limit.

    Args:
        spots: the heliostats' spots (SpotPatches).
        start: (N, 2) start offsets (m), e.g. the plant's default aiming.
        limit_w_m2: the flux limit (W/m^2): one value or a (rows, columns) map (`limit_map`).
        region: aim points within this share of the receiver's half width and half height.
        steps: Adam steps.
        learning_rate_m: Adam's step (m); default 2 % of the receiver's smaller side.
        penalty: the weight of the excess flux penalty at the first and the last step (grows
            geometrically between them).
        seed: seeds the sub-pixel move of the start from which the descent begins.
        target: (rows, columns) the share of the spots' power each pixel should get (`target_shares`):
            the descent then minimises the squared difference to it (relative to the target's own), and
            the aiming kept is the one that keeps the limit with the highest `target_accuracy`.
    """
    rows, cols = spots.shape
    half = torch.tensor(
        [region * cols * spots.pixel_m[0] / 2, region * rows * spots.pixel_m[1] / 2],
        dtype=spots.groups[0].shifted.dtype, device=spots.groups[0].shifted.device,
    )
    start = torch.max(torch.min(start.to(half), half), -half)
    pixel = torch.tensor(spots.pixel_m, dtype=half.dtype, device=half.device)
    # the start (to a pixel) is judged first; the descent begins from it moved by up to a pixel (seeded), for
    # heliostats of alike spots aimed alike get alike gradients and would never part
    jitter = torch.rand(start.shape, generator=torch.Generator().manual_seed(seed), dtype=half.dtype) * 2 - 1
    offsets = start.clone().requires_grad_(True)
    step_m = learning_rate_m or 0.02 * min(cols * spots.pixel_m[0], rows * spots.pixel_m[1])
    adam = torch.optim.Adam([offsets], lr=step_m)
    # the step shrinks to a twentieth by the last step (cosine), so that the late steps settle
    anneal = torch.optim.lr_scheduler.CosineAnnealingLR(adam, max(steps, 1), eta_min=step_m / 20)
    pixel_area = spots.pixel_m[0] * spots.pixel_m[1]
    total = float(spots.power_w().sum())
    wanted = None if target is None else target.to(half) * (total / pixel_area)  # (rows, columns) W/m^2
    growth = math.log(penalty[1] / penalty[0]) / max(steps - 1, 1)
    best: tuple[bool, Tensor, float, float, float] | None = None
    for step in range(steps + 1):
        with torch.no_grad():  # judged at whole-pixel moves, where the shifted spot is exact
            snapped = torch.round(offsets / pixel) * pixel
            judged = render(spots, snapped)
        peak, power = peak_over_limit(judged, limit_w_m2), float(judged.sum()) * pixel_area
        feasible = peak <= 1.0
        score = power if target is None else target_accuracy(judged, target, total, pixel_area)
        if best is None or _better(feasible, peak, score, best[0], best[2], best[3]):
            best = (feasible, snapped, peak, score, power)
        if step == steps:
            break
        if step == 0:
            with torch.no_grad():
                offsets.add_(jitter.to(half.device) * pixel)
        flux = render(spots, offsets)
        weight = penalty[0] * math.exp(growth * step)
        excess = torch.relu(flux / limit_w_m2 - 1)
        if wanted is None:
            loss = -flux.sum() * pixel_area / total + weight * (excess**2).mean()
        else:
            loss = ((flux - wanted) ** 2).mean() / (wanted**2).mean() + weight * (excess**2).mean()
        adam.zero_grad()
        loss.backward()
        adam.step()
        anneal.step()
        with torch.no_grad():
            offsets.copy_(torch.max(torch.min(offsets, half), -half))
    assert best is not None
    feasible, chosen, peak, score, power = best
    return AimResult(chosen, peak, power, feasible, None if target is None else score)


def _better(feasible: bool, peak: float, score: float, best_feasible: bool, best_peak: float, best_score: float
            ) -> bool:
    """Whether an iterate beats the best so far: keeping the limit first, then a higher score (the power
    on the receiver, or the target accuracy) by more than POWER_TOLERANCE of it (an aiming that keeps
    the limit is not moved for round-off), or, while none keeps it, a lower peak over the limit."""
    if feasible != best_feasible:
        return feasible
    if feasible:
        return score > best_score + POWER_TOLERANCE * abs(best_score)
    return peak < best_peak
