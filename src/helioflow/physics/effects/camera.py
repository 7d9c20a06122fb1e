"""The calibration camera: gain, background, blur and noise between the flux and the image."""

from __future__ import annotations

from helioflow.physics.effects.base import FIT, Build, Effect, Parameter
from helioflow.physics.target import Camera

PARAMETERS = (
    Parameter("gain", 1.0, 0.0, None, role="scale", doc="multiplies the flux"),
    Parameter("background_w_m2", 0.0, 0.0, None, role="offset", doc="constant added to every pixel"),
    Parameter("blur_px", 0.0, 0.0, 10.0, doc="std of the Gaussian blur of the optics (pixels)"),
    Parameter("noise", 0.0, 0.0, 1.0, role="fixed", doc="std of additive noise, fraction of the image peak"),
    Parameter("seed", 0, role="fixed", doc="seed of the noise"),
)


def apply(build: Build, params: dict) -> None:
    """The camera's gain, background, blur, noise and noise seed."""

    def value(name: str):
        return EFFECT.value(params, name)

    build.camera = Camera(gain=value("gain"), background=value("background_w_m2"), blur_px=value("blur_px"),
                          noise=value("noise"), seed=int(value("seed")))


EFFECT = Effect(
    name="camera", order=90, acts_on="image", parameters=PARAMETERS, identifiable=True,
    doc="the calibration camera: gain, background, blur, noise", apply=apply,
    tried_as={"gain": FIT, "background_w_m2": FIT, "blur_px": FIT},
    neutral={"gain": 1.0, "background_w_m2": 0.0, "blur_px": 0.0},
    missing_text="the camera's response (background and blur)",
    signature_text="{outside:.1%} of the measured flux lies outside the model's spot (background or blur)",
    plausible={"blur_px": (0.0, 3.0, "a camera blur of many pixels")},
    shared_by="the camera and the target",
)
