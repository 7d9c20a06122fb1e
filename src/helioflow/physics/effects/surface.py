"""Smooth deformations of the mirror: B-spline control-point heights on every facet."""

from __future__ import annotations

from dataclasses import replace

import torch

from helioflow.physics.effects.base import FIT, Build, Effect, Parameter, TensorRole
from helioflow.physics.heliostat import Heliostat, without_planes

PARAMETERS = (Parameter("control_heights_mm", None, -20.0, 20.0, role="tensor", array=True,
                        doc="(F, C, C) B-spline control-point heights"),)


def absent(build: Build) -> None:
    build.heliostat = replace(build.heliostat, control_heights=torch.zeros_like(build.heliostat.control_heights))


def initial(params: dict, heliostat: Heliostat):
    """(F, C, C) mm zeros, all free."""
    if params.get("control_heights_mm") != FIT:
        return None
    device = heliostat.facet_size.device
    return (torch.zeros(heliostat.control_heights.shape, device=device),
            torch.ones(heliostat.control_heights.shape, dtype=torch.bool, device=device))


EFFECT = Effect(
    "surface", 50, "mirror normals", PARAMETERS, True,
    "smooth deformation (B-spline control-point heights); unset: the heliostat's own",
    apply=lambda build, params: None, absent=absent,
    tensor=TensorRole("control_heights_mm", "control_heights", 0.002, initial, without_planes),
    tried_as={"control_heights_mm": FIT}, neutral={"control_heights_mm": FIT},
    missing_text="a surface deformation (smooth mirror shape errors)",
    signature_text="the measured spot shapes differ from the model's in ways that change with the sun position",
    plausible={"control_heights_mm_rms": (0.0, 3.0, "surface deformations of more than 3 mm RMS")},
    separated_from={"slope_error": "images at another target distance", "camera": "images at another target distance",
                    "sunshape": "a sun-shape measurement"},
)
