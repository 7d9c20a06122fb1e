"""Shading and blocking between neighbouring heliostats, from the field geometry (field traces)."""

from __future__ import annotations

from helioflow.physics.effects.base import Build, Effect


def apply(build: Build, params: dict) -> None:
    """Rays lost to blocking and shading on the way in or out."""
    build.blocking_shading = True


EFFECT = Effect(
    "blocking_shading", 80, "rays lost on the way in or out", (), True,
    "shading and blocking between neighbouring heliostats, from the field geometry (field traces only)", apply,
    not_applicable="a calibration dataset images one heliostat, and its neighbours' positions are not known here",
    missing_text="shading and blocking by neighbouring heliostats",
    signature_text="the measured spots lose flux at low sun",
)
