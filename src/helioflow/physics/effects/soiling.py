"""Soiling that grows down the mirror: a mask on the mirror.

Why it is a real calibration effect: dust settles on a tilted mirror and the film that dew and rain
leave runs down and dries at its lower part, so a heliostat between cleanings reflects less at the
bottom than at the top (soiling rates of 0.1-1 % of reflectance per day, several times faster near
the lower edge). A uniform loss is a scale that images compared by shape cannot see (reflectivity);
a gradient dims one side of every facet's image, which moves the spot's flux within it, at every
sun position alike. Modelled as a reflectance falling linearly from the mirror's top edge (clean)
to `gradient` less at its bottom edge, in the heliostat frame's up direction.
"""

from __future__ import annotations

from torch import Tensor

from helioflow.physics.effects.base import FIT, Build, Effect, Parameter
from helioflow.physics.raytrace import MirrorPoints

PARAMETERS = (Parameter("gradient", 0.2, 0.0, 1.0,
                        doc="reflectance lost at the mirror's bottom edge, relative to its clean top edge"),)


def apply(build: Build, params: dict) -> None:
    """A mask on the mirror: the reflectance falling from the mirror's top edge to its bottom edge."""
    gradient = float(EFFECT.value(params, "gradient"))
    h = build.heliostat
    half = h.facet_size[:, 1] / 2.0
    top, bottom = float((h.facet_translation[:, 1] + half).max()), float((h.facet_translation[:, 1] - half).min())

    def reflectance(points: MirrorPoints) -> Tensor:
        return (1.0 - gradient * (top - points.local[..., 1]) / (top - bottom)).clamp(0.0, 1.0)

    build.masks.append(reflectance)


EFFECT = Effect(
    name="soiling", order=75, acts_on="mirror mask", parameters=PARAMETERS, identifiable=True,
    doc="soiling that grows from the mirror's top edge to its bottom edge",
    apply=apply, tried_as={"gradient": FIT}, neutral={"gradient": 0.0},
    missing_text="soiling that grows down the mirror (its lower part reflects less)",
    signature_text="the measured spots hold less flux on one side than the model's, at every sun position",
    plausible={"gradient": (0.0, 0.6, "more than 60 % of the reflectance lost at the mirror's bottom edge")},
    separated_from={"surface": "a reflectometer reading at the mirror's top and bottom, or images after a cleaning",
                    "canting": "a reflectometer reading at the mirror's top and bottom, or images after a cleaning"},
)
