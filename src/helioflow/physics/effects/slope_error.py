"""Small-scale random mirror slope errors: each surface normal tilted at random."""

from __future__ import annotations

from helioflow.physics.effects.base import FIT, Build, Effect, Parameter

PARAMETERS = (Parameter("sigma_mrad", 1.0, 0.0, 20.0, doc="per-axis std of random normal tilts"),)


def apply(build: Build, params: dict) -> None:
    """The per-axis std of the mirror's random slope errors (mrad -> rad)."""
    build.slope_error = EFFECT.value(params, "sigma_mrad") * 1e-3


EFFECT = Effect(
    name="slope_error", order=20, acts_on="mirror normals", parameters=PARAMETERS, identifiable=True,
    doc="small-scale random mirror slope errors", apply=apply,
    tried_as={"sigma_mrad": FIT}, neutral={"sigma_mrad": 0.0},
    missing_text="slope error (small-scale mirror roughness)",
    signature_text="the measured spots are {width} than the model's, in every direction",
    plausible={"sigma_mrad": (0.0, 3.0, "a slope error of several mrad (heliostat mirrors: ~1-2.5 mrad)")},
    separated_from={"camera": "images at another target distance (a slope error widens the spot in proportion to "
                              "the distance, a camera blur does not)"},
)
