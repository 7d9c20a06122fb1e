"""What the diagnosis tries: changes to the model's effect list, their physical ranges, and the
measurements that tell apart two changes that explain the same residual.

A candidate is one change to one registry effect:

- "add": an effect the model lacks, its parameters fitted (tracking, slope error, camera, ...);
- "free": an effect the model has with fixed values, those values fitted ("your slope error is
  not the 0.5 mrad you assumed");
- "switch": the sun shape replaced by another profile, its width fitted ("your sun is not the
  Gaussian you assumed").

An "add" or "free" candidate can reproduce the model it extends (`neutral`): the added effect at
values that do nothing, the freed values at the model's. A fit of it starts there and keeps that
start when it finds nothing better, so adding a candidate never raises the training loss.
"""

from __future__ import annotations

from dataclasses import dataclass

from helioflow.physics.effects import FIT, REGISTRY

# how each absent effect is tried: its parameters, "fit" where fitted
ADDED = {
    "sunshape": {"kind": "gaussian", "sigma_mrad": FIT},
    "slope_error": {"sigma_mrad": FIT},
    "tracking": {p.name: FIT for p in REGISTRY["tracking"].parameters},
    "canting": {"facet_tilts_mrad": FIT},
    "surface": {"control_heights_mm": FIT},
    "attenuation": {"model": "constant", "transmittance": FIT},
    "reflectivity": {"value": FIT},
    "camera": {"gain": FIT, "background_w_m2": FIT, "blur_px": FIT},
}
# the values at which an added effect does nothing (tensor effects: zero tensors)
NEUTRAL = {
    "slope_error": {"sigma_mrad": 0.0},
    "tracking": {p.name: 0.0 for p in REGISTRY["tracking"].parameters},
    "camera": {"gain": 1.0, "background_w_m2": 0.0, "blur_px": 0.0},
    "attenuation": {"model": "constant", "transmittance": 1.0},
    "reflectivity": {"value": 1.0},
    "canting": {"facet_tilts_mrad": FIT},
    "surface": {"control_heights_mm": FIT},
}
NOT_APPLICABLE = {"blocking_shading": "a calibration dataset images one heliostat: it has no neighbours to block or shade it"}
SUN_WIDTH = {"pillbox": "half_angle_mrad", "gaussian": "sigma_mrad", "buie": "csr"}  # the width of each profile
SWITCHED_SUNS = ("gaussian", "buie")  # the profiles a sun is switched to

# physical ranges of fitted values: beyond them a value absorbs another effect (names as fitted_values)
PLAUSIBLE = {
    "sunshape.sigma_mrad": (0.0, 4.5, "a Gaussian sun wider than any measured sun (per-axis std up to ~4 mrad)"),
    "sunshape.csr": (0.0, 0.35, "a circumsolar ratio beyond that of the haziest measured skies (~0.35)"),
    "sunshape.half_angle_mrad": (0.0, 7.0, "a sun disc far wider than the real one (4.65 mrad)"),
    "slope_error.sigma_mrad": (0.0, 3.0, "a slope error of several mrad (heliostat mirrors: ~1-2.5 mrad)"),
    "camera.blur_px": (0.0, 3.0, "a camera blur of many pixels"),
    "tracking": (0.0, 10.0, "tracking offsets of more than 10 mrad"),
    "canting.facet_tilts_mrad_rms": (0.0, 6.0, "facet tilts of more than 6 mrad RMS"),
    "surface.control_heights_mm_rms": (0.0, 3.0, "surface deformations of more than 3 mm RMS"),
}

# the measurement that separates two candidates explaining the same residual (by their effects)
SEPARATING = {
    frozenset({"camera", "slope_error"}): "images at another target distance (a slope error widens the spot in "
                                          "proportion to the distance, a camera blur does not)",
    frozenset({"sunshape", "slope_error"}): "a measurement of the sun shape (a sun camera, or the circumsolar "
                                            "ratio of the calibration days)",
    frozenset({"sunshape", "camera"}): "a sun-shape measurement, or images at another target distance",
    frozenset({"canting", "surface"}): "images of single facets (the others covered), or at another distance",
    frozenset({"canting", "tracking"}): "images of single facets: a common tilt of all facets is tracking",
    frozenset({"surface", "tracking"}): "images over a wider range of sun positions",
    frozenset({"surface", "slope_error"}): "images at another target distance",
    frozenset({"surface", "camera"}): "images at another target distance",
    frozenset({"surface", "sunshape"}): "a sun-shape measurement",
}
ANY_OTHER = "images at sun positions where the two predict different spots"


@dataclass(frozen=True)
class Candidate:
    """One change to the model's effect list (module docstring).

    Attributes:
        label: its name in the ranking: the effect ("tracking") for an added effect, else what
            changes ("sunshape: buie", "slope_error: fit sigma_mrad").
        effect: the registry effect it changes.
        params: that effect's parameters in the changed model ("fit" where fitted).
        change: "add", "free" or "switch".
        neutral: the effect's parameters that reproduce the model (None for a switch).
    """

    label: str
    effect: str
    params: dict
    change: str
    neutral: dict | None


def candidates(effects: dict, n_facets: int) -> tuple[list[Candidate], list[dict]]:
    """(candidates to try, {effect, reason} not tried) for a model effect list and heliostat."""
    tried, skipped = [], []
    for name in REGISTRY:
        present = name in effects
        if name in NOT_APPLICABLE:
            if not present:
                skipped.append({"effect": name, "reason": NOT_APPLICABLE[name]})
        elif name == "canting" and n_facets == 1:
            if not present:
                skipped.append({"effect": name, "reason": "one facet: its tilt is a tracking error"})
        elif not present:
            tried.append(Candidate(name, name, dict(ADDED[name]), "add", NEUTRAL.get(name)))
        else:
            tried += _changed(name, dict(effects[name] or {}))
    return tried, skipped


def _changed(name: str, params: dict) -> list[Candidate]:
    """Candidates that change an effect the model has: its fixed fittable values fitted and, for
    the sun, the other profiles with their width fitted."""
    out = []
    if name == "sunshape":
        kind = params.get("kind", REGISTRY["sunshape"].parameter("kind").default)
        width = SUN_WIDTH.get(kind)
        if width and params.get(width) != FIT:
            out.append(Candidate(f"sunshape: fit {width}", name, {**params, width: FIT}, "free",
                                 {**params, width: params.get(width, REGISTRY[name].parameter(width).default)}))
        for other in SWITCHED_SUNS:
            if other != kind:
                out.append(Candidate(f"sunshape: {other}", name, {"kind": other, SUN_WIDTH[other]: FIT}, "switch", None))
        return out
    fixed = [p.name for p in REGISTRY[name].parameters
             if p.fittable and not p.array and p.name in params and params[p.name] != FIT]
    if fixed:
        out.append(Candidate(f"{name}: fit {', '.join(fixed)}", name, {**params, **dict.fromkeys(fixed, FIT)},
                             "free", dict(params)))
    return out


def implausible(fitted: dict) -> list[str]:
    """Descriptions of fitted values (keys as `FitResult.fitted_values` summarised: "effect.param",
    tensors as "<name>_rms") outside their physical range."""
    out = []
    for key, value in fitted.items():
        rule = PLAUSIBLE.get(key) or (PLAUSIBLE["tracking"] if key.startswith("tracking.") else None)
        if rule is not None and isinstance(value, (int, float)) and not rule[0] <= abs(value) <= rule[1]:
            out.append(f"{key} = {value:g} ({rule[2]})")
    return out


def separating(a: str, b: str) -> str:
    """The measurement that tells effect `a` from effect `b`."""
    return SEPARATING.get(frozenset({a, b}), ANY_OTHER)
