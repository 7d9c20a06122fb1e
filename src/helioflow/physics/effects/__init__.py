"""The registry of physical effects, and how an effect list becomes the physics of one trace.

An effect is a named, parameterised mechanism. `world.effects` (what produced the measurements)
and `model.effects` (what the user believes) are dicts {effect name: {parameter: value}} in config.
A parameter's value is a number (in the unit its name ends with), a choice for `kind`/`model`,
or "fit" (model only: fitted from the training images).

**One effect, one module**: every module in this folder (but base.py) declares one `EFFECT`
(physics/effects/base.py: its parameters, where it acts and the hooks that do it, its role in a
fit, how the diagnosis tries it, the verdict's words, the measurements that separate it from
others). The registry is what the folder holds, in the effects' `order`; the tables the tracer,
the fit and the diagnosis use are derived from it (tests/physics/test_registry.py checks that
they cover every entry). Adding an effect: docs/adding_an_effect.md.

The heliostat-specific effects (tracking, canting, surface) take their values from the
heliostat's geometry file (`surfaces/{heliostat}.h5`, the true geometry) unless the effect sets
them; an effect absent from the list means the mechanism is absent (ideal heliostat).
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from pathlib import Path

from torch import Tensor

from helioflow.errors import ConfigError
from helioflow.physics.effects.attenuation import vittitoe_biggs
from helioflow.physics.effects.base import FIT, Build, Effect, Parameter
from helioflow.physics.heliostat import Heliostat
from helioflow.physics.raytrace import Optics
from helioflow.physics.sun import KIND_KEYS, SUN_KINDS
from helioflow.physics.target import Camera

__all__ = ["FIT", "REGISTRY", "Effect", "Parameter", "Physics", "check_effects", "discover", "fitted_parameters",
           "resolve", "vittitoe_biggs"]


def discover(folder: Path, package: str) -> dict[str, Effect]:
    """{name: effect} of every module in `folder` (importable as `package`.<module>) that declares
    an EFFECT, in the effects' order."""
    effects = []
    for path in sorted(Path(folder).glob("*.py")):
        if path.stem in ("__init__", "base"):
            continue
        effect = getattr(importlib.import_module(f"{package}.{path.stem}"), "EFFECT", None)
        if isinstance(effect, Effect):
            effects.append(effect)
    names = [e.name for e in effects]
    if len(set(names)) != len(names):
        raise ValueError(f"{folder}: two modules declare the same effect: {sorted(names)}")
    return {e.name: e for e in sorted(effects, key=lambda e: e.order)}


REGISTRY: dict[str, Effect] = discover(Path(__file__).parent, __name__)
TENSOR_EFFECTS = {name: e.tensor for name, e in REGISTRY.items() if e.tensor is not None}


def check_effects(effects: dict | None, where: str, allow_fit: bool) -> None:
    """Raise ConfigError naming `where` (e.g. 'world.effects') for an unknown effect, parameter or value
    (None: no effects)."""
    for name, params in (effects or {}).items():
        if name not in REGISTRY:
            raise ConfigError(f"{where}: unknown effect {name!r}; allowed: {', '.join(REGISTRY)}")
        effect = REGISTRY[name]
        if name == "sunshape":
            _check_sun_kind(params or {}, f"{where}.{name}")
        for key, value in (params or {}).items():
            known = [p.name for p in effect.parameters]
            if key not in known:
                allowed = ", ".join(known) or f"none ({effect.doc})"
                raise ConfigError(f"{where}.{name}: unknown parameter {key!r}; allowed: {allowed}")
            p = effect.parameter(key)
            if p.array and value != FIT:
                raise ConfigError(f"{where}.{name}.{key} = {value!r}; a per-facet tensor: 'fit' or leave it out")
            if value == FIT:
                if not (allow_fit and p.fittable):
                    raise ConfigError(f"{where}.{name}.{key}: 'fit' is only allowed for fittable model parameters")
                continue
            if p.choices:
                if value not in p.choices:
                    raise ConfigError(f"{where}.{name}.{key} = {value!r}; allowed: {', '.join(p.choices)}")
                continue
            if not isinstance(value, (int, float)) or isinstance(value, bool):
                raise ConfigError(f"{where}.{name}.{key} = {value!r}; expected a number")
            if (p.lower is not None and value < p.lower) or (p.upper is not None and value > p.upper):
                raise ConfigError(f"{where}.{name}.{key} = {value!r}; expected {p.lower} <= value <= {p.upper}")


def _check_sun_kind(params: dict, where: str) -> None:
    """A sun shape's parameters are those of its kind (e.g. no csr for a gaussian sun)."""
    kind = params.get("kind", REGISTRY["sunshape"].parameter("kind").default)
    if kind not in SUN_KINDS:
        return  # the parameter check names the unknown kind
    other = [k for k in params if k != "kind" and k not in KIND_KEYS[kind]]
    if other:
        takes = ", ".join(KIND_KEYS[kind]) or "no parameter"
        raise ConfigError(f"{where}.{other[0]} = {params[other[0]]!r}: a {kind} sun takes {takes}; remove "
                          f"{other[0]} (in a --configfile variant: {other[0]}: null)")


def fitted_parameters(effects: dict) -> list[tuple[str, str]]:
    """(effect, parameter) pairs marked "fit" in an effect list, in registry order."""
    return [(e, p.name) for e in REGISTRY for p in REGISTRY[e].parameters
            if e in (effects or {}) and (effects[e] or {}).get(p.name) == FIT]


def with_role(role: str) -> set[tuple[str, str]]:
    """(effect, parameter) pairs whose fit role is `role` (base.ROLES)."""
    return {(e.name, p.name) for e in REGISTRY.values() for p in e.parameters if p.role == role}


@dataclass(frozen=True)
class Physics:
    """Everything a trace needs, resolved from one effect list for one heliostat.

    blocking_shading: whether a field trace (field.field_flux) applies shading and blocking.
    """

    optics: Optics
    heliostat: Heliostat
    camera: Camera | None
    blocking_shading: bool = False


def resolve(effects: dict, heliostat: Heliostat, dni: float, neighbours: Tensor | None = None) -> Physics:
    """Turn an effect list (no 'fit' values) into optics, the effective heliostat and the camera:
    every registry effect's `apply` hook when the list has it, its `absent` hook otherwise.

    Args:
        effects: {effect name: {parameter: value}} as in config.
        heliostat: the heliostat's geometry (true values for tracking, canting, surface).
        dni: direct normal irradiance (W/m^2).
        neighbours: (K, 3) ENU pivots of the neighbouring heliostats where known (None: unknown).
    """
    check_effects(effects, "effects", allow_fit=False)
    build = Build(heliostat, dni, neighbours)
    for name, effect in REGISTRY.items():
        if name in (effects or {}):
            effect.apply(build, dict(effects[name] or {}))
        else:
            effect.absent(build)
    return Physics(build.optics(), build.heliostat, build.camera, build.blocking_shading)
