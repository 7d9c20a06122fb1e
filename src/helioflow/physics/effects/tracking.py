"""Kinematic errors of the heliostat's axes: where the mirror points for each sun position."""

from __future__ import annotations

from dataclasses import replace

import torch

from helioflow.physics.effects.base import FIT, Build, Effect, Parameter, TensorRole, zeroed
from helioflow.physics.heliostat import TRACKING_PARAMETERS, Heliostat

PARAMETERS = tuple(Parameter(f"{n}_mrad", None, -50.0, 50.0, role="tensor", doc=f"{n.replace('_', ' ')} (mrad)")
                   for n in TRACKING_PARAMETERS)


def apply(build: Build, params: dict) -> None:
    """Set parameters replace the heliostat's own errors; unset ones keep them."""
    error = build.heliostat.tracking_error.clone()
    for i, p in enumerate(PARAMETERS):
        if p.name in params:
            error[i] = params[p.name] * 1e-3
    build.heliostat = replace(build.heliostat, tracking_error=error)


def initial(params: dict, heliostat: Heliostat):
    """(5,) mrad: given values, zeros where fitted; the fitted entries free."""
    if not any(params.get(p.name) == FIT for p in PARAMETERS):
        return None
    values = [params.get(p.name, 0.0) for p in PARAMETERS]
    device = heliostat.facet_size.device
    return (torch.tensor([0.0 if v == FIT else float(v) for v in values], device=device),
            torch.tensor([params.get(p.name) == FIT for p in PARAMETERS], device=device))


EFFECT = Effect(
    name="tracking", order=30, acts_on="kinematics", parameters=PARAMETERS, identifiable=True,
    doc="kinematic errors; unset parameters take the heliostat's true values", apply=apply,
    absent=zeroed("tracking_error"),
    tensor=TensorRole("tracking", "tracking_error", 0.01, initial),
    tried_as={p.name: FIT for p in PARAMETERS}, neutral={p.name: 0.0 for p in PARAMETERS},
    missing_text="a tracking error (kinematic offsets of the heliostat's axes)",
    signature_text="the spot centroids are off by {centroid:.2f} mrad RMS, varying with sun position",
    plausible={"*": (0.0, 10.0, "tracking offsets of more than 10 mrad")},
    separated_from={"canting": "images of single facets: a common tilt of all facets is tracking",
                    "surface": "images over a wider range of sun positions"},
)
