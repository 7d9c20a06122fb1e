"""The registry of physical effects, and how an effect list becomes the physics of one trace.

An effect is a named, parameterised mechanism. `world.effects` (what produced the measurements)
and `model.effects` (what the user believes) are dicts {effect name: {parameter: value}} in config.
A parameter's value is a number (in the unit its name ends with), a choice for `kind`/`model`,
or "fit" (model only: fitted from the training images by gradient descent through the tracer).

The heliostat-specific effects (tracking, canting, surface) take their values from the
heliostat's geometry file (`surfaces/{heliostat}.h5`, the true geometry) unless the effect sets
them; an effect absent from the list means the mechanism is absent (ideal heliostat).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import torch
from torch import Tensor

from helioflow.errors import ConfigError
from helioflow.physics.heliostat import TRACKING_PARAMETERS, Heliostat
from helioflow.physics.raytrace import Optics
from helioflow.physics.sun import KIND_KEYS, SUN_KINDS, SunShape
from helioflow.physics.target import Camera

FIT = "fit"


@dataclass(frozen=True)
class Parameter:
    """One effect parameter: name (with unit suffix), default, bounds, whether it can be fitted."""

    name: str
    default: float | str | None
    lower: float | None = None
    upper: float | None = None
    fittable: bool = True
    choices: tuple[str, ...] = ()
    doc: str = ""
    array: bool = False  # a tensor of the heliostat (per-facet values): "fit" is its only config value


@dataclass(frozen=True)
class Effect:
    """A physical mechanism: where it acts and what it needs.

    identifiable: False for a pure scale on the flux, which images normalised by their own
    maximum cannot reveal (reflectivity, attenuation, camera gain).
    """

    name: str
    acts_on: str
    parameters: tuple[Parameter, ...]
    identifiable: bool
    doc: str

    def parameter(self, name: str) -> Parameter:
        return next(p for p in self.parameters if p.name == name)


_TRACKING = tuple(Parameter(f"{n}_mrad", None, -50.0, 50.0, doc=f"{n.replace('_', ' ')} (mrad)") for n in TRACKING_PARAMETERS)

REGISTRY: dict[str, Effect] = {
    e.name: e
    for e in (
        Effect("sunshape", "incoming ray spread", (
            Parameter("kind", "pillbox", fittable=False, choices=SUN_KINDS),
            Parameter("half_angle_mrad", 4.65, 0.1, 50.0, doc="pillbox half-angle"),
            Parameter("sigma_mrad", 2.51, 0.01, 50.0, doc="gaussian per-axis std"),
            Parameter("csr", 0.1, 0.005, 0.4, doc="Buie circumsolar ratio"),
        ), True, "the sun's angular radiance profile"),
        Effect("slope_error", "surface normals", (
            Parameter("sigma_mrad", 1.0, 0.0, 20.0, doc="per-axis std of random normal tilts"),
        ), True, "small-scale random mirror slope errors"),
        Effect("tracking", "heliostat orientation per sun position", _TRACKING, True,
               "kinematic errors; unset parameters take the heliostat's true values"),
        Effect("canting", "facet normals", (
            Parameter("facet_tilts_mrad", None, -20.0, 20.0, array=True, doc="(F, 2) tilts about each facet's right/up axes"),
        ), True, "per-facet tilt errors; unset: the heliostat's own"),
        Effect("surface", "surface normals", (
            Parameter("control_heights_mm", None, -20.0, 20.0, array=True, doc="(F, C, C) B-spline control-point heights"),
        ), True, "smooth deformation (B-spline control-point heights); unset: the heliostat's own"),
        Effect("attenuation", "ray power", (
            Parameter("model", "vittitoe_biggs_clear", fittable=False,
                      choices=("vittitoe_biggs_clear", "vittitoe_biggs_hazy", "constant")),
            Parameter("transmittance", 1.0, 0.0, 1.0, doc="for model: constant"),
        ), False, "atmospheric extinction over the slant range from mirror to target"),
        Effect("reflectivity", "ray power", (Parameter("value", 0.95, 0.0, 1.0, doc="mirror reflectivity (soiling)"),),
               False, "mirror reflectivity"),
        Effect("blocking_shading", "rays lost on the way in or out", (), True,
               "shading and blocking between neighbouring heliostats, from the field geometry (field traces only)"),
        Effect("camera", "the measured image", (
            Parameter("gain", 1.0, 0.0, None, doc="multiplies the flux"),
            Parameter("background_w_m2", 0.0, 0.0, None, doc="constant added to every pixel"),
            Parameter("blur_px", 0.0, 0.0, 10.0, doc="std of the Gaussian blur of the optics (pixels)"),
            Parameter("noise", 0.0, 0.0, 1.0, fittable=False, doc="std of additive noise, fraction of the image peak"),
            Parameter("seed", 0, fittable=False, doc="seed of the noise"),
        ), True, "the calibration camera: gain, background, blur, noise"),
    )
}


def check_effects(effects: dict, where: str, allow_fit: bool) -> None:
    """Raise ConfigError naming `where` (e.g. 'world.effects') for an unknown effect, parameter or value."""
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


def vittitoe_biggs(slant_range_m: Tensor, hazy: bool) -> Tensor:
    """Atmospheric transmittance over a slant range (m), Vittitoe & Biggs (1978) polynomial fits.

    Clear day (23 km visibility): 0.99326 - 0.1046 R + 0.017 R^2 - 0.002845 R^3;
    hazy day (5 km visibility): 0.98707 - 0.2748 R + 0.03394 R^2; R in km (fits for R <= ~2 km).
    """
    r = slant_range_m / 1000.0
    if hazy:
        return 0.98707 - 0.2748 * r + 0.03394 * r**2
    return 0.99326 - 0.1046 * r + 0.017 * r**2 - 0.002845 * r**3


@dataclass(frozen=True)
class Physics:
    """Everything a trace needs, resolved from one effect list for one heliostat.

    blocking_shading: whether a field trace (field.field_flux) applies shading and blocking.
    """

    optics: Optics
    heliostat: Heliostat
    camera: Camera | None
    blocking_shading: bool = False


def resolve(effects: dict, heliostat: Heliostat, dni: float) -> Physics:
    """Turn an effect list (no 'fit' values) into optics, the effective heliostat and the camera.

    Args:
        effects: {effect name: {parameter: value}} as in config.
        heliostat: the heliostat's geometry (true values for tracking, canting, surface).
        dni: direct normal irradiance (W/m^2).
    """
    check_effects(effects, "effects", allow_fit=False)
    effects = {k: dict(v or {}) for k, v in (effects or {}).items()}
    sun_cfg = effects.get("sunshape", {"kind": "point"})
    sun = SunShape.from_config({"kind": sun_cfg.get("kind", "pillbox"), **{k: v for k, v in sun_cfg.items() if k != "kind"}})
    slope = effects["slope_error"].get("sigma_mrad", 1.0) * 1e-3 if "slope_error" in effects else 0.0
    reflectivity = effects["reflectivity"].get("value", 0.95) if "reflectivity" in effects else 1.0
    transmittance = None
    if "attenuation" in effects:
        att = effects["attenuation"]
        kind = att.get("model", "vittitoe_biggs_clear")
        if kind == "constant":
            value = float(att.get("transmittance", 1.0))
            transmittance = lambda r: torch.full_like(r, value)
        else:
            transmittance = lambda r: vittitoe_biggs(r, hazy=kind.endswith("hazy"))
    h = heliostat
    if "tracking" in effects:
        error = h.tracking_error.clone()
        for i, name in enumerate(TRACKING_PARAMETERS):
            if f"{name}_mrad" in effects["tracking"]:
                error[i] = effects["tracking"][f"{name}_mrad"] * 1e-3
        h = replace(h, tracking_error=error)
    else:
        h = replace(h, tracking_error=torch.zeros_like(h.tracking_error))
    if "canting" not in effects:
        h = replace(h, canting_error=torch.zeros_like(h.canting_error))
    if "surface" not in effects:
        h = replace(h, control_heights=torch.zeros_like(h.control_heights))
    camera = None
    if "camera" in effects:
        c = effects["camera"]
        camera = Camera(gain=c.get("gain", 1.0), background=c.get("background_w_m2", 0.0), blur_px=c.get("blur_px", 0.0),
                        noise=c.get("noise", 0.0), seed=int(c.get("seed", 0)))
    return Physics(Optics(sun, slope, dni, reflectivity, transmittance), h, camera, "blocking_shading" in effects)
