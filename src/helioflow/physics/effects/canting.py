"""Facet canting errors: each facet tilted about its own right and up axes."""

from __future__ import annotations

from dataclasses import replace

import torch
from torch import Tensor

from helioflow.physics.effects.base import FIT, Build, Effect, Parameter, TensorRole
from helioflow.physics.heliostat import Heliostat

PARAMETERS = (Parameter("facet_tilts_mrad", None, -20.0, 20.0, role="tensor", array=True,
                        doc="(F, 2) tilts about each facet's right/up axes"),)


def absent(build: Build) -> None:
    build.heliostat = replace(build.heliostat, canting_error=torch.zeros_like(build.heliostat.canting_error))


def initial(params: dict, heliostat: Heliostat):
    """(F, 2) mrad zeros, all free."""
    if params.get("facet_tilts_mrad") != FIT:
        return None
    device = heliostat.facet_size.device
    return (torch.zeros(heliostat.n_facets, 2, device=device),
            torch.ones(heliostat.n_facets, 2, dtype=torch.bool, device=device))


def zero_mean(tilts: Tensor) -> Tensor:
    """(F, 2) facet tilts without their mean: a common tilt is a tracking error, not canting."""
    return tilts - tilts.mean(dim=0)


EFFECT = Effect(
    "canting", 40, "mirror normals", PARAMETERS, True, "per-facet tilt errors; unset: the heliostat's own",
    apply=lambda build, params: None, absent=absent,
    tensor=TensorRole("facet_tilts_mrad", "canting_error", 0.01, initial, zero_mean),
    tried_as={"facet_tilts_mrad": FIT}, neutral={"facet_tilts_mrad": FIT},
    min_facets=(2, "one facet: its tilt is a tracking error"),
    missing_text="facet canting errors",
    signature_text="the measured spots have a different structure (facets' images do not overlap as the model's do)",
    plausible={"facet_tilts_mrad_rms": (0.0, 6.0, "facet tilts of more than 6 mrad RMS")},
    separated_from={"surface": "images of single facets (the others covered), or at another distance"},
)
