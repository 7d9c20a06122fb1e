"""What an effect is: the facts one effect module declares (its parameters, where it acts, its role
in a fit, how the diagnosis tries it and words it), and the physics under construction that its
hooks change (`Build`). See physics/effects/__init__.py for the registry and docs/adding_an_effect.md.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any

import torch
from torch import Tensor

from helioflow.physics.heliostat import Heliostat
from helioflow.physics.raytrace import MirrorPoints, Optics
from helioflow.physics.sun import SunShape
from helioflow.physics.target import Camera

FIT = "fit"
ACTS_ON = ("sun profile", "mirror normals", "kinematics", "mirror mask", "ray power", "image",
           "rays lost on the way in or out")
ROLES = ("spread", "scale", "offset", "tensor", "choice", "fixed")


@dataclass(frozen=True)
class Parameter:
    """One effect parameter.

    Attributes:
        name: with its unit as suffix (`sigma_mrad`).
        default: the value when an effect sets none (None: the heliostat's own, for its tensors).
        lower, upper: the allowed range (None: unbounded).
        role: how a fit treats it: "spread" (a width: bounded scalar search), "scale" (multiplies
            the flux: closed form), "offset" (added to every pixel: closed form), "tensor" (a
            heliostat tensor entry: descent through the tracer), "choice" (a name from `choices`),
            "fixed" (a number never fitted).
        choices: the allowed names of a "choice".
        doc: what it is.
        array: a tensor of the heliostat (per-facet values): "fit" is its only config value.
    """

    name: str
    default: float | str | None
    lower: float | None = None
    upper: float | None = None
    role: str = "spread"
    choices: tuple[str, ...] = ()
    doc: str = ""
    array: bool = False

    @property
    def fittable(self) -> bool:
        """Whether a fit may free the parameter (not a choice, not fixed)."""
        return self.role not in ("choice", "fixed")


@dataclass
class Build:
    """The physics of one trace under construction: each effect's hook sets its part."""

    heliostat: Heliostat
    dni: float
    neighbours: Tensor | None = None  # (K, 3) ENU pivots of the neighbouring heliostats, where known
    sun: SunShape = field(default_factory=lambda: SunShape("point"))
    slope_error: float = 0.0  # rad
    reflectivity: float = 1.0
    transmittance: Callable[[Tensor], Tensor] | None = None
    camera: Camera | None = None
    blocking_shading: bool = False
    masks: list[Callable[[MirrorPoints], Tensor]] = field(default_factory=list)  # masks on the mirror: they multiply

    def optics(self) -> Optics:
        """The optics the build sets up, its masks on the mirror multiplied into one."""
        mask = _multiplied(tuple(self.masks)) if self.masks else None
        return Optics(self.sun, self.slope_error, self.dni, self.reflectivity, self.transmittance, mask)


def _multiplied(masks: tuple[Callable[[MirrorPoints], Tensor], ...]) -> Callable[[MirrorPoints], Tensor]:
    return lambda points: _product([m(points) for m in masks])


def _product(weights: list[Tensor]) -> Tensor:
    out = weights[0]
    for w in weights[1:]:
        out = out * w
    return out


@dataclass(frozen=True)
class TensorRole:
    """How a fit moves an effect that is a tensor of the heliostat.

    Attributes:
        key: its name among a fit's tensors and in fitted values ("tracking", "facet_tilts_mrad", ...).
        field: the Heliostat attribute it sets (in rad or m: the tensor's mrad or mm times 1e-3).
        fd_step: central-difference step of Gauss-Newton (the tensor's unit).
        initial: (params, heliostat) -> (start tensor, free-entries mask), or None when nothing of
            it is fitted.
        effective: the tensor as the heliostat takes it (e.g. canting without its mean).
    """

    key: str
    field: str
    fd_step: float
    initial: Callable[[dict, Heliostat], tuple[Tensor, Tensor] | None]
    effective: Callable[[Tensor], Tensor] = lambda t: t


@dataclass(frozen=True)
class Variant:
    """One way the diagnosis changes an effect the model has (a "free" or a "switch")."""

    label: str
    params: dict
    change: str
    neutral: dict | None


@dataclass(frozen=True, kw_only=True)
class Effect:
    """A physical mechanism and every fact about it (one module of physics/effects/).

    Attributes:
        name: its config key.
        order: its place in the registry (fitted parameters, candidates and tables follow it).
        acts_on: where it acts, one of ACTS_ON.
        parameters: its parameters.
        identifiable: False for a pure scale on the flux, which images compared by shape cannot
            reveal (reflectivity, attenuation).
        doc: one line.
        apply: (build, params) -> None: the effect present, with these parameters (numbers; a
            missing one at its default, see `value`).
        absent: (build) -> None: the effect absent (e.g. the heliostat's own tracking error zeroed).
        tensor: its role as a heliostat tensor in a fit (None for scalar effects).
        tried_as: the parameters with which the diagnosis adds it to a model that lacks it ("fit"
            where fitted); None: never added (`not_applicable` says why).
        neutral: its parameters at which it does nothing (the start of a nested fit; None: none).
        not_applicable: why the diagnosis cannot try it (empty: it can).
        needs: (a fact of the dataset, why the diagnosis cannot try it without): e.g. ("neighbours",
            "the neighbours' positions are not known"); the diagnosis tries it where the fact is known.
        min_facets: (fewest facets, why) for an effect a heliostat with fewer facets cannot show.
        variants: (params) -> [Variant]: how the diagnosis changes it when the model has it;
            default: its fixed fittable scalars freed.
        missing_text: "the model lacks ..." in the verdict.
        signature_text: the residual's evidence in the verdict; may quote {width}, {centroid},
            {outside}, {ratio} (diagnosis.diagnose.summarise).
        plausible: {fitted-value key: (low, high, why)}: beyond the range, a fitted value stands
            in for another effect (keys as the diagnosis' fitted values: "<parameter>", or
            "<tensor key>_rms"; "*" for every parameter).
        separated_from: {other effect: the measurement that tells the two apart}.
        shared_by: what makes it the same for every heliostat photographed in one calibration
            campaign ("the sun of the campaign"); empty for a heliostat's own effect. A plant's
            shared effects are fitted once across its heliostats (diagnosis/shared.py).
    """

    name: str
    order: int
    acts_on: str
    parameters: tuple[Parameter, ...]
    identifiable: bool
    doc: str
    apply: Callable[[Build, dict], None]
    absent: Callable[[Build], None] = lambda build: None
    tensor: TensorRole | None = None
    tried_as: dict | None = None
    neutral: dict | None = None
    not_applicable: str = ""
    needs: tuple[str, str] | None = None
    min_facets: tuple[int, str] = (1, "")
    variants: Callable[[dict], list[Variant]] | None = None
    missing_text: str = ""
    signature_text: str = ""
    plausible: dict = field(default_factory=dict)
    separated_from: dict = field(default_factory=dict)
    shared_by: str = ""

    def parameter(self, name: str) -> Parameter:
        """The parameter `name`."""
        return next(p for p in self.parameters if p.name == name)

    def value(self, params: dict, name: str):
        """The parameter `name` as set in `params`, else its default."""
        return params.get(name, self.parameter(name).default)

    def changed(self, params: dict) -> list[Variant]:
        """How the diagnosis changes this effect when a model has it with `params`."""
        if self.variants is not None:
            return self.variants(params)
        fixed = [p.name for p in self.parameters
                 if p.fittable and not p.array and p.name in params and params[p.name] != FIT]
        if not fixed:
            return []
        return [Variant(f"{self.name}: fit {', '.join(fixed)}", {**params, **dict.fromkeys(fixed, FIT)}, "free",
                        dict(params))]


def zeroed(name: str) -> Callable[[Build], None]:
    """An `absent` hook: the heliostat's own tensor `name` (a Heliostat field) set to zeros."""

    def absent(build: Build) -> None:
        zeros: dict[str, Any] = {name: torch.zeros_like(getattr(build.heliostat, name))}
        build.heliostat = replace(build.heliostat, **zeros)

    return absent


def all_free(parameter: str, name: str) -> Callable[[dict, Heliostat], tuple[Tensor, Tensor] | None]:
    """A TensorRole's `initial` for a tensor parameter that is "fit" or absent: zeros shaped like the
    heliostat's field `name`, every entry free."""

    def initial(params: dict, heliostat: Heliostat) -> tuple[Tensor, Tensor] | None:
        if params.get(parameter) != FIT:
            return None
        like = getattr(heliostat, name)
        return (torch.zeros(like.shape, device=like.device),
                torch.ones(like.shape, dtype=torch.bool, device=like.device))

    return initial
