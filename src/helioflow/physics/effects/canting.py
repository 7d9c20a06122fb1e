"""Facet canting errors: each facet tilted about its own right and up axes."""

from __future__ import annotations

from torch import Tensor

from helioflow.physics.effects.base import FIT, Effect, Parameter, TensorRole, all_free, zeroed

PARAMETERS = (Parameter("facet_tilts_mrad", None, -20.0, 20.0, role="tensor", array=True,
                        doc="(F, 2) tilts about each facet's right/up axes"),)


def zero_mean(tilts: Tensor) -> Tensor:
    """(F, 2) facet tilts without their mean: a common tilt is a tracking error, not canting."""
    return tilts - tilts.mean(dim=0)


EFFECT = Effect(
    name="canting", order=40, acts_on="mirror normals", parameters=PARAMETERS, identifiable=True,
    doc="per-facet tilt errors; unset: the heliostat's own",
    apply=lambda build, params: None, absent=zeroed("canting_error"),
    tensor=TensorRole("facet_tilts_mrad", "canting_error", 0.01, all_free("facet_tilts_mrad", "canting_error"),
                      zero_mean),
    tried_as={"facet_tilts_mrad": FIT}, neutral={"facet_tilts_mrad": FIT},
    min_facets=(2, "one facet: its tilt is a tracking error"),
    missing_text="facet canting errors",
    signature_text="the measured spots have a different structure (facets' images do not overlap as the model's do)",
    plausible={"facet_tilts_mrad_rms": (0.0, 6.0, "facet tilts of more than 6 mrad RMS")},
    separated_from={"surface": "images of single facets (the others covered), or at another distance"},
)
