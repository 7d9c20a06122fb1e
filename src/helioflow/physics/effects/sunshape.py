"""The sun's angular radiance profile: the spread of the incoming rays."""

from __future__ import annotations

from helioflow.physics.effects.base import FIT, Build, Effect, Parameter, Variant
from helioflow.physics.sun import SUN_KINDS, SunShape

WIDTH = {"pillbox": "half_angle_mrad", "gaussian": "sigma_mrad", "buie": "csr"}  # the width of each profile
SWITCHED = ("gaussian", "buie")  # the profiles the diagnosis switches a sun to
PARAMETERS = (
    Parameter("kind", "pillbox", role="choice", choices=SUN_KINDS),
    Parameter("half_angle_mrad", 4.65, 0.1, 50.0, doc="pillbox half-angle"),
    Parameter("sigma_mrad", 2.51, 0.01, 50.0, doc="gaussian per-axis std"),
    Parameter("csr", 0.1, 0.005, 0.4, doc="Buie circumsolar ratio"),
)


def apply(build: Build, params: dict) -> None:
    """The sun shape (the parameter `kind`'s default, pillbox, unless `kind` says otherwise)."""
    build.sun = SunShape.from_config({"kind": params.get("kind", PARAMETERS[0].default),
                                      **{k: v for k, v in params.items() if k != "kind"}})


def variants(params: dict) -> list[Variant]:
    """The sun's width freed ("your sun is not as wide as you assumed") and the other profiles with
    their width fitted ("your sun is not the Gaussian you assumed")."""
    kind = params.get("kind", PARAMETERS[0].default)
    width = WIDTH.get(kind)
    out = []
    if width and params.get(width) != FIT:
        default = next(p.default for p in PARAMETERS if p.name == width)
        out.append(Variant(f"sunshape: fit {width}", {**params, width: FIT}, "free",
                           {**params, width: params.get(width, default)}))
    out += [Variant(f"sunshape: {other}", {"kind": other, WIDTH[other]: FIT}, "switch", None)
            for other in SWITCHED if other != kind]
    return out


EFFECT = Effect(
    name="sunshape", order=10, acts_on="sun profile", parameters=PARAMETERS, identifiable=True,
    doc="the sun's angular radiance profile", apply=apply,
    tried_as={"kind": "gaussian", "sigma_mrad": FIT}, variants=variants,
    missing_text="a wider sun shape",
    signature_text="the measured spots are {width} than the model's, in every direction",
    plausible={"sigma_mrad": (0.0, 4.5, "a Gaussian sun wider than any measured sun (per-axis std up to ~4 mrad)"),
               "csr": (0.0, 0.35, "a circumsolar ratio beyond that of the haziest measured skies (~0.35)"),
               "half_angle_mrad": (0.0, 7.0, "a sun disc far wider than the real one (4.65 mrad)")},
    separated_from={"slope_error": "a measurement of the sun shape (a sun camera, or the circumsolar ratio of the "
                                   "calibration days)",
                    "camera": "a sun-shape measurement, or images at another target distance"},
    shared_by="the sun of the campaign",
)
