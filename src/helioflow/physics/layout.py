"""Heliostat field layouts: pivot positions (ENU, metres) of N heliostats north of a tower at the origin.

Bearings are measured from north towards east; a layout fills the sector of bearings within
±sector_deg / 2 of north, outside a minimum radius from the tower. Two heliostats whose pivots are
at least the mirror's diagonal apart cannot touch, however they turn (each mirror stays inside the
sphere of half its diagonal around its pivot): `min_spacing` gives that distance, and every
generator keeps all pivots at least `spacing` apart.

  radial_staggered  rings of heliostats, every other ring shifted by half the azimuthal step
                    (the DELSOL / Collado "no-blocking" pattern), in zones of constant azimuthal step;
  fermat_spiral     the biomimetic layout of Noone et al. (2012, Solar Energy 86:792): heliostat k at
                    radius a sqrt(k + k0) and angle k times the golden angle, a set so that the
                    nearest neighbours are `spacing` apart (constant density; Noone's density
                    grading is not modelled).
"""

from __future__ import annotations

import csv
import math
import os

import torch
from torch import Tensor

from helioflow.errors import ConfigError, DataError

GOLDEN_ANGLE = math.pi * (3.0 - math.sqrt(5.0))  # rad, 137.5 deg
SUNFLOWER_NEAREST = 1.68  # closest-pair distance / a in the bulk of a golden-angle spiral (1.675-1.677)


def min_spacing(width: float, height: float, clearance: float = 0.0) -> float:
    """Pivot-to-pivot distance (m) at which two mirrors of width x height (m) cannot collide: their
    diagonal plus a clearance (m). Valid for mirrors that turn about their centre."""
    return math.hypot(width, height) + clearance


def _check_layout(n: int, spacing: float, min_radius: float, sector_deg: float) -> None:
    if isinstance(n, bool) or not isinstance(n, int) or n < 1:
        raise ConfigError(f"field layout: n={n!r}; expected an integer >= 1")
    if not spacing > 0:
        raise ConfigError(f"field layout: spacing={spacing!r} m; expected > 0")
    if not min_radius >= spacing / 2:
        raise ConfigError(f"field layout: min_radius={min_radius!r} m; expected >= spacing / 2 "
                          f"= {spacing / 2} m")
    if not 0 < sector_deg <= 360:
        raise ConfigError(f"field layout: sector_deg={sector_deg!r}; expected 0 < sector_deg <= 360")


def _enu(radius: Tensor, bearing: Tensor, height: float) -> Tensor:
    """(n,) radii (m) and bearings from north towards east (rad) -> (n, 3) ENU positions."""
    up = torch.full_like(radius, height)
    return torch.stack((radius * torch.sin(bearing), radius * torch.cos(bearing), up), -1)


def radial_staggered(n: int, spacing: float, min_radius: float, sector_deg: float = 180.0,
                     height: float = 0.0) -> Tensor:
    """A radially staggered field of n heliostats.

    Zone z starts at radius R_z with the azimuthal step dphi_z = 2 asin(spacing / (2 R_z)) (chord =
    spacing). Its rings lie spacing * sqrt(3) / 2 apart, every other ring shifted by dphi_z / 2:
    neighbours in adjacent rings are then at least spacing apart. A zone ends where the arc between
    neighbours reaches 2 spacing; the next zone starts one full spacing further out with its own step.
    The outermost ring keeps the heliostats nearest north.

    Args:
        n: number of heliostats.
        spacing: least pivot-to-pivot distance (m), see min_spacing.
        min_radius: radius of the first ring (m), >= spacing / 2.
        sector_deg: angular width of the field, centred on north (deg).
        height: pivot height above the tower base (m).

    Returns:
        (n, 3) float64 ENU pivot positions (m), ring by ring from the tower outwards.
    """
    _check_layout(n, spacing, min_radius, sector_deg)
    half_sector = math.radians(sector_deg) / 2
    radii, bearings = [], []
    count, zone_start, ring = 0, float(min_radius), 0
    radius = zone_start
    step = 2 * math.asin(spacing / (2 * zone_start))
    while count < n:
        shift = step / 2 if ring % 2 else 0.0
        m = torch.arange(-math.ceil(math.pi / step) - 1, math.ceil(math.pi / step) + 2, dtype=torch.float64)
        phi = m * step + shift
        # |phi| <= pi - step / 2 keeps the two ends of a full circle a step apart
        phi = phi[(phi.abs() <= half_sector + 1e-12) & (phi.abs() <= math.pi - step / 2 + 1e-12)]
        phi = phi[phi.abs().argsort(stable=True)][: n - count]
        radii.append(torch.full_like(phi, radius))
        bearings.append(phi)
        count += len(phi)
        if radius * step >= 2 * spacing:  # the next ring starts a new zone with a finer step
            zone_start = radius + spacing
            radius, ring = zone_start, 0
            step = 2 * math.asin(spacing / (2 * zone_start))
        else:
            radius, ring = radius + spacing * math.sqrt(3) / 2, ring + 1
    return _enu(torch.cat(radii), torch.cat(bearings), height)


def fermat_spiral(n: int, spacing: float, min_radius: float, sector_deg: float = 180.0,
                  height: float = 0.0) -> Tensor:
    """A Fermat-spiral (sunflower) field of n heliostats after Noone et al. (2012).

    Point k of the spiral lies at radius a sqrt(k) and bearing k * GOLDEN_ANGLE; the field keeps the
    points k >= (min_radius / a)^2 that fall inside the sector, nearest first. The density is one
    heliostat per pi a^2 square metres; a starts at spacing / SUNFLOWER_NEAREST and grows until no
    two of the n heliostats are closer than `spacing` (for large fields the closest pair is then
    `spacing` apart to about 1e-9; a few heliostats may stand further apart).

    Args and Returns: as radial_staggered.
    """
    _check_layout(n, spacing, min_radius, sector_deg)
    half_sector = math.radians(sector_deg) / 2
    a = spacing / SUNFLOWER_NEAREST  # the bulk of a sunflower has its closest pairs ~1.676 a apart
    positions = _spiral(n, a, min_radius, half_sector, height)
    while n > 1 and (closest := nearest_distances(positions).min().item()) < spacing:
        a *= spacing / closest * (1 + 1e-9)
        positions = _spiral(n, a, min_radius, half_sector, height)
    return positions


def _spiral(n: int, a: float, min_radius: float, half_sector: float, height: float) -> Tensor:
    """The first n spiral points k >= (min_radius / a)^2 inside the sector: (n, 3) ENU (m)."""
    kept: list[Tensor] = []
    start, found = math.ceil((min_radius / a) ** 2), 0
    batch = max(64, int(2.5 * n * math.pi / half_sector))
    while found < n:
        k = torch.arange(start, start + batch, dtype=torch.float64)
        inside = _bearing(k).abs() <= half_sector
        kept.append(k[inside])
        found += int(inside.sum())
        start += batch
    k = torch.cat(kept)[:n]
    return _enu(a * torch.sqrt(k), _bearing(k), height)


def _bearing(k: Tensor) -> Tensor:
    """Bearing (rad, in [-pi, pi)) of spiral point k."""
    return torch.remainder(k * GOLDEN_ANGLE + math.pi, 2 * math.pi) - math.pi


def nearest_distances(positions: Tensor) -> Tensor:
    """(n,) distance (m) from each of the (n, 3) positions to its nearest other one (float64; a k-d
    tree: O(n log n) time, O(n) memory). Needs n >= 2."""
    from scipy.spatial import cKDTree

    points = positions.detach().cpu().double().numpy()
    distances, _ = cKDTree(points).query(points, k=2)
    return torch.from_numpy(distances[:, 1])


def positions_from_list(rows, source: str = "field.positions") -> Tensor:
    """Explicit pivot positions: a sequence of [east, north] or [east, north, up] (m; up defaults to
    0) -> (n, 3) float64.

    Raises ConfigError naming `source` for an empty list, a row of another length or a value that
    is not a finite number.
    """
    values = []
    for i, row in enumerate(rows):
        try:
            numbers = [float(x) for x in row]
        except (TypeError, ValueError):
            numbers = []
        if len(numbers) not in (2, 3) or not all(math.isfinite(x) for x in numbers):
            raise ConfigError(f"{source}: row {i} = {row!r}; expected [east, north] or [east, north, up] "
                              "as finite numbers (m)")
        values.append(numbers + [0.0] * (3 - len(numbers)))
    if not values:
        raise ConfigError(f"{source}: no heliostat positions; expected n >= 1 rows [east, north(, up)] (m)")
    return torch.tensor(values, dtype=torch.float64)


def load_positions(path: str | os.PathLike) -> Tensor:
    """Pivot positions from a CSV file: one heliostat per row, columns east, north[, up] in metres;
    a first row that is not numeric is taken as a header. Returns (n, 3) float64 ENU (m).

    Raises DataError naming the file for a missing file or a malformed row.
    """
    try:
        with open(path, newline="") as f:
            rows = [row for row in csv.reader(f) if row and any(cell.strip() for cell in row)]
    except OSError as err:
        raise DataError(f"{path}: cannot read the heliostat positions: {err.strerror}")
    if rows:
        try:
            [float(cell) for cell in rows[0]]
        except ValueError:
            rows = rows[1:]
    try:
        return positions_from_list(rows, source=str(path))
    except ConfigError as err:
        raise DataError(str(err))
