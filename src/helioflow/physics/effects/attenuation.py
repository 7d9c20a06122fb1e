"""Atmospheric extinction over the slant range from mirror to target: a scale on the flux."""

from __future__ import annotations

import torch
from torch import Tensor

from helioflow.physics.effects.base import FIT, Build, Effect, Parameter

PARAMETERS = (
    Parameter("model", "vittitoe_biggs_clear", role="choice",
              choices=("vittitoe_biggs_clear", "vittitoe_biggs_hazy", "constant")),
    Parameter("transmittance", 1.0, 0.0, 1.0, role="scale", doc="for model: constant"),
)


def vittitoe_biggs(slant_range_m: Tensor, hazy: bool) -> Tensor:
    """Atmospheric transmittance over a slant range (m), Vittitoe & Biggs (1978) polynomial fits.

    Clear day (23 km visibility): 0.99326 - 0.1046 R + 0.017 R^2 - 0.002845 R^3;
    hazy day (5 km visibility): 0.98707 - 0.2748 R + 0.03394 R^2; R in km (fits for R <= ~2 km).
    """
    r = slant_range_m / 1000.0
    if hazy:
        return 0.98707 - 0.2748 * r + 0.03394 * r**2
    return 0.99326 - 0.1046 * r + 0.017 * r**2 - 0.002845 * r**3


def apply(build: Build, params: dict) -> None:
    """The transmittance over the slant range: the chosen Vittitoe-Biggs fit, or a constant."""
    kind = EFFECT.value(params, "model")
    if kind == "constant":
        value = float(EFFECT.value(params, "transmittance"))
        build.transmittance = lambda r: torch.full_like(r, value)
    else:
        build.transmittance = lambda r: vittitoe_biggs(r, hazy=kind.endswith("hazy"))


EFFECT = Effect(
    name="attenuation", order=60, acts_on="ray power", parameters=PARAMETERS, identifiable=False,
    doc="atmospheric extinction over the slant range from mirror to target", apply=apply,
    tried_as={"model": "constant", "transmittance": FIT}, neutral={"model": "constant", "transmittance": 1.0},
    missing_text="atmospheric attenuation",
    signature_text="the measured flux is {ratio:.3f} times the model's (a scale)",
)
