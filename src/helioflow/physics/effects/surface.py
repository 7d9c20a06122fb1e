"""Smooth deformations of the mirror: B-spline control-point heights on every facet."""

from __future__ import annotations

from helioflow.physics.effects.base import FIT, Effect, Parameter, TensorRole, all_free, zeroed
from helioflow.physics.heliostat import without_planes

PARAMETERS = (Parameter("control_heights_mm", None, -20.0, 20.0, role="tensor", array=True,
                        doc="(F, C, C) B-spline control-point heights"),)


EFFECT = Effect(
    name="surface", order=50, acts_on="mirror normals", parameters=PARAMETERS, identifiable=True,
    doc="smooth deformation (B-spline control-point heights); unset: the heliostat's own",
    apply=lambda build, params: None, absent=zeroed("control_heights"),
    tensor=TensorRole("control_heights_mm", "control_heights", 0.002,
                      all_free("control_heights_mm", "control_heights"), without_planes),
    tried_as={"control_heights_mm": FIT}, neutral={"control_heights_mm": FIT},
    missing_text="a surface deformation (smooth mirror shape errors)",
    signature_text="the measured spot shapes differ from the model's in ways that change with the sun position",
    plausible={"control_heights_mm_rms": (0.0, 3.0, "surface deformations of more than 3 mm RMS")},
    separated_from={"slope_error": "images at another target distance", "camera": "images at another target distance",
                    "sunshape": "a sun-shape measurement"},
)
