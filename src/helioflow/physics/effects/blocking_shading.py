"""Shading and blocking between neighbouring heliostats, from the field geometry (field traces)."""

from __future__ import annotations

from helioflow.physics.effects.base import Build, Effect


def apply(build: Build, params: dict) -> None:
    """Rays lost to blocking and shading on the way in or out."""
    build.blocking_shading = True


EFFECT = Effect(
    name="blocking_shading", order=80, acts_on="rays lost on the way in or out", parameters=(), identifiable=True,
    doc="shading and blocking between neighbouring heliostats, from the field geometry (field traces only)",
    apply=apply,
    not_applicable="a calibration dataset images one heliostat, and its neighbours' positions are not known here",
    missing_text="shading and blocking by neighbouring heliostats",
    signature_text="the measured spots lose flux at low sun",
)
