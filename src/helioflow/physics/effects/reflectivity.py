"""The mirror's reflectivity (soiling, ageing): a scale on the flux."""

from __future__ import annotations

from helioflow.physics.effects.base import FIT, Build, Effect, Parameter

PARAMETERS = (Parameter("value", 0.95, 0.0, 1.0, role="scale", doc="mirror reflectivity (soiling)"),)


def apply(build: Build, params: dict) -> None:
    """The mirror's reflectivity."""
    build.reflectivity = EFFECT.value(params, "value")


EFFECT = Effect(
    name="reflectivity", order=70, acts_on="ray power", parameters=PARAMETERS, identifiable=False,
    doc="mirror reflectivity", apply=apply,
    tried_as={"value": FIT}, neutral={"value": 1.0},
    missing_text="a lower mirror reflectivity",
    signature_text="the measured flux is {ratio:.3f} times the model's (a scale)",
)
