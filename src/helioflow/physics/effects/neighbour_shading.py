"""Shading and blocking of a calibrated heliostat by its neighbours: a mask on the mirror.

Why: a calibration image shows one heliostat, but at low sun its neighbours cast shadows on it and
stand in the way of its beam to the target, so its lower part sends less light exactly at the sun
positions where calibration would learn most. Where the neighbours' positions are known (PAINT's
directory lists every heliostat's; a dataset's `neighbours_enu_m`), each is taken as a heliostat
of the same design at its own pivot, tracking the same aim point: its mirror is the rectangle that
spans the design's facets. A surface point is shaded when the ray from it towards the sun meets a
neighbour's mirror, blocked when its reflected ray does. No parameter is fitted: the geometry is
known.
"""

from __future__ import annotations

from dataclasses import replace

import torch
from torch import Tensor

from helioflow.errors import ConfigError
from helioflow.physics.effects.base import Build, Effect
from helioflow.physics.heliostat import Heliostat, orientation
from helioflow.physics.raytrace import MirrorPoints


def mirror_rectangle(heliostat: Heliostat) -> tuple[Tensor, Tensor]:
    """(centre (3,) in the heliostat frame, half extents (2,) along its right and up axes) of the
    rectangle that spans all facets (m)."""
    half = heliostat.facet_size / 2.0
    low = (heliostat.facet_translation[:, :2] - half).amin(0)
    high = (heliostat.facet_translation[:, :2] + half).amax(0)
    centre = torch.cat(((low + high) / 2.0, heliostat.facet_translation[:, 2].mean()[None]))
    return centre, (high - low) / 2.0


def lit(points: MirrorPoints, heliostat: Heliostat, neighbours: Tensor) -> Tensor:
    """1 where a point's ray towards the sun and its reflected ray pass every neighbour's mirror, else
    0; the broadcast shape of `points`' tensors without their last axis."""
    shape = torch.broadcast_shapes(points.world.shape, points.to_sun.shape, points.reflected.shape)
    suns = points.sun.reshape(-1, 3)
    world, to_sun, reflected = (x.expand(shape).reshape(len(suns), -1, 3)
                                for x in (points.world, points.to_sun, points.reflected))
    centre, half = (x.to(world) for x in mirror_rectangle(heliostat))
    free = torch.ones(world.shape[:2], dtype=torch.bool, device=world.device)
    design = heliostat.ideal()
    for pivot in neighbours.to(world):
        rot = orientation(replace(design, position=pivot), suns.to(world), points.aim.to(world))  # (S', 3, 3)
        middle = pivot + rot @ centre  # (S', 3)
        for direction in (to_sun, reflected):
            along = torch.einsum("spi,si->sp", direction, rot[:, :, 2])
            t = torch.einsum("spi,si->sp", middle[:, None] - world, rot[:, :, 2]) / torch.where(
                along.abs() < 1e-12, torch.full_like(along, 1e-12), along)
            local = torch.einsum("spi,sij->spj", world + t[..., None] * direction - middle[:, None], rot)
            free &= ~((t > 0) & (local[..., 0].abs() <= half[0]) & (local[..., 1].abs() <= half[1]))
    return free.to(world.dtype).reshape(shape[:-1])


def apply(build: Build, params: dict) -> None:
    """A mask on the mirror: the points the neighbours leave lit (ConfigError without neighbours)."""
    if build.neighbours is None:
        raise ConfigError("neighbour_shading needs the neighbours' positions: a PAINT dataset lists them (the "
                          "other heliostats' folders within 30 m); this dataset has none")
    heliostat, neighbours = build.heliostat, build.neighbours
    if len(neighbours):
        build.masks.append(lambda points: lit(points, heliostat, neighbours))


EFFECT = Effect(
    name="neighbour_shading", order=78, acts_on="mirror mask", parameters=(), identifiable=True,
    doc="shading and blocking by neighbouring heliostats of known position, in calibration images", apply=apply,
    tried_as={}, needs=("neighbours", "no neighbour is known within 30 m (a PAINT import lists the other heliostats' "
                                     "folders of its directory)"),
    missing_text="shading and blocking by its neighbours (their positions are known)",
    signature_text="the measured spots lose flux on one side at some sun positions only",
    separated_from={"soiling": "images at high sun (no shading there), or after a cleaning",
                    "surface": "images at high sun (no shading there)"},
)
