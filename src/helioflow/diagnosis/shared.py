"""What a plant's heliostats share: the sun and the camera, fitted once across heliostats.

One heliostat on one target cannot tell a wider sun, a camera blur and a slope error apart: each
widens its spot. But every heliostat photographed in one calibration campaign sees the same sun and
is photographed by the same camera on the same target (the registry's `shared_by` effects), while
a slope error, a canting or a tracking error is each heliostat's own. The plant fit uses that:

1. It takes up to `heliostats` of a plant's heliostats, evenly across the plant's list (a plant of
   thousands shares one sun and one camera: a few dozen heliostats determine them as well as all).
2. Each heliostat keeps its kinematics free (`OWN`: tracking), fitted on its training images with
   the diagnosis' shape loss. Not its slope error: on one target a slope error and a camera blur (or
   a wider sun) widen the spot alike, and a slope error free on every heliostat could take up any
   share of a shared widening. Not its canting either: freed, it takes a share of the blur on every
   heliostat (each one's sigma of the blur doubles to quadruples) and the level rises, as measured
   on both 30-heliostat plants (docs/journal/2026-11-28-seed-22-misses.md). Widening common to the
   heliostats is the shared effects'; what one heliostat has beyond it is its own, for its own diagnosis.
3. Every change to a shared effect the diagnosis would try (the camera added, the sun's width
   freed, the sun switched to another profile: diagnosis/candidates.py) is fitted on each
   heliostat alone (its own effects and the change's values), and every heliostat is refitted with
   the shared values fixed. The camera's gain and background stay each heliostat's own (in closed
   form: exposure and daylight change from image to image).
4. The shared value of each of the change's widths (the camera's blur, the sun's width) is the
   level the heliostats agree on from below (`Level`). A heliostat's own effects (a slope
   error, a bump, canting) only widen its spot (variances add), so each heliostat's own value is
   the shared one plus a share of its own, never less, plus its noise: its marginal sigma in its
   fit with the value free (models/uncertainty.py). Small cantings and weak slope errors widen a
   spot by any amount down to zero, so the heliostats without a widening of their own do not stand
   apart from the least widened: the value is the values' lower envelope (`lower_envelope`), each
   heliostat's squared value the shared one plus its own widening (none, or exponentially
   distributed) plus its noise, fitted by maximum likelihood. A median sits inside the widened ones
   where most heliostats have an effect of their own (6-8 % high on the independent plants, 2.4-4.3
   sigma) and leaves the heliostats' own widening to the shared value (on a 6 x 30-image plant both
   slope errors went unnamed with it). Beside it, the one-sided clipping with which astronomers take
   the sky's level under stars that only add light (`clipped_level`): from the median, heliostats
   more than CLIP sigma above the inverse-variance mean of those kept are set aside (never those
   below), until the kept set stops changing. It says which heliostats carry a widening of their
   own, but keeps the least widened and lies above the truth where the widenings run down to zero
   (+0.07 and +0.11 px on the two 30-heliostat plants, where the envelope lay -0.01 and +0.03 px
   from it; at the clipped level true slope errors fit low and the plants' diagnoses named 27 and 26
   of 30 right, at the envelope 29 and 27: docs/results.md).
5. A change is shared when it cuts the plant's held-out error (the mean over the heliostats of the
   misplaced flux fraction on their held-out images) meaningfully (criteria.is_meaningful); the
   best one, then the best with one more change of another shared effect, as long as each step
   counts.
6. Each shared value carries its sigma, from two sources added in quadrature. Statistical: the
   spread of the envelope over the heliostats resampled (a bootstrap: which heliostats carry a
   widening of their own moves it more than their noise), or, where larger, that of the kept
   heliostats' inverse-variance mean, times the square root of their chi^2 per degree of freedom
   where it exceeds 1 (they disagree beyond their own sigma). Systematic: the envelope rests on a
   model of the own widenings (none, or a continuum from zero), the clipping on another (apart from
   none); their difference is the level's systematic sigma. Beside it, what each heliostat alone
   makes of it (its own fit with the value free: the confounded answer one heliostat gets) and
   whether the clipping kept it. A heliostat whose own value lies well above the level and whose
   diagnosis named no widening of its own may hide one the level took (scoring/plant.py flags it).

7. The sun against the camera, over the slant ranges (`RangeTest`). Levelled heliostat by heliostat,
   a sun told too narrow shows as a wider camera blur: each heliostat alone cannot tell the two
   apart. Across heliostats it can: the blur is the same number of pixels for all of them, while
   the sun's angular width spreads a spot in proportion to the heliostat's slant range r. Variances
   add, so each heliostat's own blur with the camera fitted (b_i, px) is b_i^2 = b^2 + delta (r_i / p)^2,
   with p the target's pixel (m) and delta the sun's angular variance the model lacks (mrad^2; < 0:
   told too wide). A straight line of b_i^2 against (r_i / p)^2, weighted by their sigma and clipped
   from above as the level, gives delta and b. The test advises and changes nothing: a heliostat's
   own slope error, cantings and surface widen its spot by an angle too, so in pixels they grow with
   slant range as a wider sun does, and where most heliostats carry them (as real heliostats do) the
   line is lifted and tilted by them. On a plant with cantings of 1-2 mrad on a third of it and slope
   errors on another the line read the sun 40 % wide, 3.7 sigma, while the two heliostats with
   tracking errors alone sat at the true blur (docs/journal/2026-12-03-plant-with-larger-cantings.md);
   on drawn plants whose sun is told right it reads a wider sun beyond 3 sigma on up to 20 % of them,
   and it finds a sun told 2.0 instead of 2.51 mrad on 11-21 % (scripts/experiments/range_test_rates.py,
   docs/diagnosis.md). Renaming the sun on it would widen every heliostat's model and hide their
   slope errors; so the verdict says what the line gives, and that a wider sun and the heliostats'
   own angular widenings look alike on these images. Done for a Gaussian sun (sigma_mrad) beside a
   shared camera; otherwise the verdict says the sun was not tested.

Every heliostat's physics model and diagnosis then take the shared effects at these values
(`shared_effects`) and try no change to a shared effect themselves (workflow: plant.shared).
"""

from __future__ import annotations

import functools
import json
import logging
import math
import os
from dataclasses import dataclass, field

import numpy as np
import torch
from scipy import optimize, stats

from helioflow.data.hdf5 import read_dataset
from helioflow.data.splits import evenly
from helioflow.data.surfaces import read_heliostat
from helioflow.device import resolve_device
from helioflow.diagnosis.candidates import Candidate, candidates
from helioflow.diagnosis.criteria import is_meaningful
from helioflow.diagnosis.diagnose import _measurements, cross_validation_folds, heldout_error, scoring_split
from helioflow.errors import DataError
from helioflow.io import write_text_atomic
from helioflow.models.physical import drt_effects
from helioflow.models.physics_fit import (
    FitResult,
    FitSettings,
    Measurements,
    fit_effects,
    with_uncertainty,
)
from helioflow.physics.effects import REGISTRY, fitted_parameters
from helioflow.physics.scene import Scene, dataset_scene

log = logging.getLogger(__name__)

BOOTSTRAP = 100  # resamplings of the heliostats for the shared level's statistical sigma
RESAMPLED_STEPS = 400  # Nelder-Mead iterations of the envelope's fit to resampled values (it starts at the optimum)
CLIP = 2.5  # a heliostat whose own value lies this many of its sigma above the clipped level has a widening of its own
OWN = "tracking"  # each heliostat's own effects during the plant fit (drt_effects, kinematics only)
RANGE_SIGNIFICANCE = 3.0  # the sun's variance deficit this many of its sigma from 0: the line stands out
RANGE_HINT = 2.0  # ... this many: the verdict says the sun may be off, and what would tell
BLUR = "camera.blur_px"


def is_shared(effect: str) -> bool:
    """Whether a registry effect is the same for every heliostat of a calibration campaign."""
    return bool(REGISTRY[effect].shared_by)


@dataclass
class Member:
    """One heliostat of the plant fit: its scene and its train / held-out measurements."""

    heliostat: str
    scene: Scene
    train: Measurements
    heldout: Measurements


@dataclass
class Joint:
    """A joint fit of the plant: the shared values, each heliostat's fit, its held-out error."""

    shared: dict[str, float]  # "effect.parameter" -> value
    fits: list[FitResult]
    errors: list[float]

    @property
    def error(self) -> float:
        """The plant's held-out error: the mean of the heliostats' misplaced flux fractions."""
        return float(np.mean(self.errors))


@dataclass
class Level:
    """The level a shared width's per-heliostat values agree on from below (module docstring, 4 and 6)."""

    value: float  # the values' lower envelope (`lower_envelope`)
    clipped: float  # the one-sided clipping's level (`clipped_level`): |value - clipped| is the systematic sigma
    kept_sigma: float  # the kept heliostats' inverse-variance sigma, times the root of their chi^2 per dof above 1
    chi2_per_dof: float  # of the kept heliostats' values about the clipped level
    values: list[float]  # each heliostat's own value ...
    sigmas: list[float]  # ... its marginal sigma (nan or 0: not determined, given the median sigma) ...
    kept: list[bool]  # ... and whether the clipping kept it (False: a widening of its own)
    optimum: np.ndarray = field(repr=False)  # (3,) the envelope's fit (`lower_envelope`): where resamplings start

    @classmethod
    def of(cls, values: list[float], sigmas: list[float]) -> Level:
        """The level of `values` (each heliostat's own, with its marginal `sigmas`): their lower
        envelope, beside the one-sided clipping's level and the heliostats it kept."""
        v, s = np.asarray(values, float), weighting_sigmas(sigmas)
        clipped, kept = clipped_level(v, s)
        chi2 = float((((v[kept] - clipped) / s[kept]) ** 2).sum() / max(kept.sum() - 1, 1))
        kept_sigma = float((1.0 / s[kept] ** 2).sum() ** -0.5 * math.sqrt(max(chi2, 1.0)))
        envelope, optimum = lower_envelope(v, s)
        return cls(envelope, clipped, kept_sigma, chi2, v.tolist(), np.asarray(sigmas, float).tolist(), kept.tolist(),
                   optimum)

    @functools.cached_property
    def statistical(self) -> float:
        """The larger of the kept heliostats' sigma and the spread of the envelope over the heliostats
        resampled (BOOTSTRAP draws: which heliostats happen to carry a widening of their own moves it
        more than their noise does). A few seconds: computed for the values the plant fit reports."""
        v, s = np.asarray(self.values), weighting_sigmas(self.sigmas)
        draws = np.random.default_rng(0).integers(0, len(v), (BOOTSTRAP, len(v)))
        resampled = [lower_envelope(v[d], s[d], start=self.optimum)[0] for d in draws]
        return max(self.kept_sigma, float(np.std(resampled)))

    @property
    def systematic(self) -> float:
        """The envelope's distance to the clipping's level (module docstring, 6)."""
        return abs(self.value - self.clipped)

    @property
    def sigma(self) -> float:
        """Statistical and systematic, in quadrature."""
        return math.hypot(self.statistical, self.systematic)


def weighting_sigmas(sigmas: list[float]) -> np.ndarray:
    """Heliostats' marginal sigmas (n,) for weighting: a value not determined (sigma nan or 0) gets
    their median, not infinite weight (nor none: it still counts as one heliostat)."""
    s = np.asarray(sigmas, float)
    usable = np.isfinite(s) & (s > 0)
    return np.where(usable, s, np.median(s[usable]) if usable.any() else 1.0)


def lower_envelope(v: np.ndarray, s: np.ndarray, start: np.ndarray | None = None) -> tuple[float, np.ndarray]:
    """The shared width under own widenings that run down to zero in a continuum (module docstring,
    4), from each heliostat's value `v` (n,) and sigma `s` (n,), widths in px or mrad: the
    maximum-likelihood b of v_i^2 = b^2 + w_i + e_i, variances adding, with e_i ~ N(0, (2 v_i s_i)^2)
    the heliostat's noise and w_i >= 0 its own widening, 0 with probability pi, else exponential of
    mean tau (so that v_i^2 is a Gaussian or an exponentially modified Gaussian about b^2,
    scipy.stats.exponnorm). (b^2, logit pi, log tau) by Nelder-Mead from `start` (3,), or else from three
    starts of b^2 (the mean of the lowest fifth of the v_i^2, their least, their median)
    -> (b, the optimum (3,), a start for resampled values)."""
    y, sy = v ** 2, np.maximum(2.0 * np.abs(v) * s, 1e-9)

    def nll(p: np.ndarray) -> float:
        b2, clean, tau = p[0], 1.0 / (1.0 + math.exp(-p[1])), math.exp(p[2])
        density = clean * stats.norm.pdf(y, b2, sy) + (1.0 - clean) * stats.exponnorm.pdf(y, tau / sy, b2, sy)
        return float(-np.log(np.maximum(density, 1e-300)).sum())

    if start is None:
        low = float(np.sort(y)[:max(3, len(y) // 5)].mean())
        starts = [np.array([b2, 0.0, math.log(max(float(np.median(y)) - b2, 1e-3))])
                  for b2 in (low, float(y.min()), float(np.median(y)))]
        steps = 4000
    else:  # a resampling: values repeated make pi and tau flat directions, which Nelder-Mead would walk for long
        starts, steps = [start], RESAMPLED_STEPS
    options = {"xatol": 1e-6, "fatol": 1e-8, "maxiter": steps}
    best = min((optimize.minimize(nll, p, method="Nelder-Mead", options=options) for p in starts), key=lambda f: f.fun)
    return math.sqrt(max(float(best.x[0]), 0.0)), best.x


def clipped_level(v: np.ndarray, s: np.ndarray) -> tuple[float, np.ndarray]:
    """One-sided clipping of values `v` (n,) with sigmas `s` (n,): from the median, the inverse-variance
    mean of the values at most CLIP sigma above it, until the kept set repeats -> (level, kept (n,) bool)."""
    level, kept = float(np.median(v)), np.ones(len(v), bool)
    for _ in range(len(v)):
        now = v - level <= CLIP * s
        w = 1.0 / s[now] ** 2
        level = float((w * v[now]).sum() / w.sum())
        if (now == kept).all():
            break
        kept = now
    return level, kept


@dataclass
class RangeTest:
    """The sun's width against the camera's blur over the heliostats' slant ranges (module docstring, 7)."""

    deficit_mrad2: float  # delta: the sun's angular variance the model lacks (< 0: told too wide)
    sigma_mrad2: float  # its sigma (inverse-variance, inflated by the kept heliostats' chi^2 per dof above 1)
    blur_px: float  # the camera's blur with it: the line's intercept, square-rooted
    blur_sigma_px: float
    ranges_m: list[float]  # each heliostat's slant range to the target's centre
    kept: list[bool]  # whether the line kept it (False: a widening of its own, above the line)

    @classmethod
    def of(cls, blur: Level, ranges_m: list[float], pixel_m: float) -> RangeTest:
        """The line b_i^2 = b^2 + delta (r_i / p)^2 through the heliostats' own blurs (`blur`, the
        camera's level), from the level's kept set, clipped from above until the kept set repeats."""
        b, s = np.asarray(blur.values, float), weighting_sigmas(blur.sigmas)
        y, sy = b ** 2, 2.0 * np.abs(b) * s
        x = (np.asarray(ranges_m, float) * 1e-3 / pixel_m) ** 2  # px^2 per mrad^2
        design = np.stack([np.ones_like(x), x], 1) / sy[:, None]
        kept = np.asarray(blur.kept, bool)

        def line(kept: np.ndarray) -> np.ndarray:
            return np.linalg.lstsq(design[kept], y[kept] / sy[kept], rcond=None)[0]

        for _ in range(len(b)):
            now = y - design @ line(kept) * sy <= CLIP * sy
            if (now == kept).all() or now.sum() < 3:
                break
            kept = now
        coef = line(kept)  # the line of the kept set (also when the clipping ran out of rounds)
        cov = np.linalg.inv(design[kept].T @ design[kept])
        chi2 = float((((y[kept] - design[kept] @ coef * sy[kept]) / sy[kept]) ** 2).sum() / max(kept.sum() - 2, 1))
        cov *= max(chi2, 1.0)
        intercept = max(float(coef[0]), 0.0)
        blur_px = math.sqrt(intercept)
        return cls(float(coef[1]), float(math.sqrt(cov[1, 1])), blur_px,
                   float(math.sqrt(cov[0, 0]) / (2.0 * max(blur_px, 1e-6))), [float(r) for r in ranges_m],
                   kept.tolist())

    @property
    def significant(self) -> bool:
        """The deficit beyond RANGE_SIGNIFICANCE of its sigma: the line stands out (the sun is kept all the same)."""
        return abs(self.deficit_mrad2) > RANGE_SIGNIFICANCE * self.sigma_mrad2

    def sun_width(self, told_mrad: float) -> tuple[float, float]:
        """(sigma_mrad, its sigma) of the sun with the deficit added to the told width's variance."""
        width = math.sqrt(max(told_mrad ** 2 + self.deficit_mrad2, 1e-6))
        return width, self.sigma_mrad2 / (2.0 * width)


def slant_range_m(scene: Scene) -> float:
    """A heliostat's distance to its target's centre (m)."""
    return float(torch.linalg.norm(scene.heliostat.position - scene.target.center))


class PlantFit:
    """The plant's heliostats against one model effect list: the shared changes, fitted jointly."""

    def __init__(self, members: list[Member], effects: dict, settings: FitSettings):
        self.members, self.effects = members, effects
        self.settings = FitSettings(**{**vars(settings), "loss": "shape"})
        n_facets = members[0].scene.heliostat.n_facets
        self.tried: list[Candidate] = [c for c in candidates(effects, n_facets)[0] if is_shared(c.effect)]
        self.candidate = {c.label: c for c in self.tried}
        self.joints: dict[frozenset, Joint] = {}
        self.alone: dict[frozenset, list[FitResult]] = {}
        self.levels: dict[frozenset, dict[str, Level]] = {}

    def effects_with(self, labels) -> dict:
        """The plant fit's effect list (the model's, each heliostat's kinematics "fit") with the
        changes `labels` applied."""
        out = {e: dict(p or {}) for e, p in self.effects.items()}
        for label in labels:
            c = self.candidate[label]
            out[c.effect] = dict(c.params)
        return drt_effects(out, self.members[0].scene.heliostat.n_facets, freedom="tracking")

    def shared_spreads(self, effects: dict) -> list[tuple[str, str]]:
        """The fitted spread scalars of shared effects in an effect list: what the heliostats share."""
        return [(e, k) for e, k in fitted_parameters(effects)
                if is_shared(e) and REGISTRY[e].parameter(k).role == "spread"]

    def joint(self, labels) -> Joint:
        """The joint fit of the model with the changes `labels` (module docstring, step 3); nested:
        each heliostat starts from its fit with one change fewer."""
        key = frozenset(labels)
        if key in self.joints:
            return self.joints[key]
        effects = self.effects_with(key)
        starts: list[FitResult | None] = [None] * len(self.members)
        if key:
            starts = list(min((self.joint(key - {label}) for label in key), key=lambda j: j.error).fits)
        fits = [fit_effects(m.scene, effects, m.train, self.settings, start=s) for m, s in zip(self.members, starts)]
        self.alone[key] = fits
        spreads = self.shared_spreads(effects)
        self.levels[key] = {f"{e}.{k}": Level.of([float(f.effects[e][k]) for f in fits],
                                                  [self._sigma(m, f, f"{e}.{k}") for m, f in zip(self.members, fits)])
                            for e, k in spreads}
        shared = {name: round(level.value, 4) for name, level in self.levels[key].items()}
        if shared:
            fixed = with_values(effects, shared)
            fits = [fit_effects(m.scene, fixed, m.train, self.settings, start=f) for m, f in zip(self.members, fits)]
        errors = [heldout_error(m.scene, f, m.heldout) for m, f in zip(self.members, fits)]
        self.joints[key] = Joint(shared, fits, errors)
        log.info("plant + %s: held-out error %.4f %s", " + ".join(sorted(key)) or "nothing", self.joints[key].error,
                 shared)
        return self.joints[key]

    def select(self, max_changes: int) -> list[str]:
        """The shared changes the plant needs: the best that counts alone, then the best with one
        more change of another shared effect while it counts (criteria.is_meaningful)."""
        chosen: list[str] = []
        for _ in range(max_changes):
            effects = {self.candidate[c].effect for c in chosen}
            options = [c.label for c in self.tried if c.effect not in effects]
            if not options:
                break
            best = min(options, key=lambda label: self.joint([*chosen, label]).error)
            if not is_meaningful(self.joint(chosen).error, self.joint([*chosen, best]).error):
                break
            chosen.append(best)
        return chosen

    def range_test(self, chosen: list[str]) -> tuple[RangeTest | None, str]:
        """The sun against the camera (module docstring, 7) on the chosen changes' fit, or None and why
        it was not done."""
        sun = self.effects.get("sunshape") or {}
        if BLUR not in self.levels.get(frozenset(chosen), {}):
            return None, "the camera's blur is not among the shared changes"
        if sun.get("kind") != "gaussian" or any(self.candidate[c].effect == "sunshape" for c in chosen):
            return None, "the sun's model is not a Gaussian of configured width"
        ranges = [slant_range_m(m.scene) for m in self.members]
        target = self.members[0].scene.target
        return RangeTest.of(self.levels[frozenset(chosen)][BLUR], ranges, target.width / target.resolution[1]), ""

    def sigma(self, key: frozenset) -> dict[str, dict]:
        """Per shared value: its sigma over the plant and each heliostat's own answer (module docstring, 6)."""
        out = {}
        for name, level in self.levels[key].items():
            out[name] = {"value": self.joints[key].shared[name], "sigma": round(level.sigma, 5),
                         "sigma_statistical": round(level.statistical, 5),
                         "sigma_systematic": round(level.systematic, 5), "clipped": round(level.clipped, 4),
                         "alone": {m.heliostat: {"value": round(v, 4), "sigma": round(s, 5), "kept": kept}
                                   for m, v, s, kept in zip(self.members, level.values, level.sigmas, level.kept)},
                         "kept_chi2_per_dof": round(level.chi2_per_dof, 3)}
        return out

    def _sigma(self, member: Member, fit: FitResult, name: str) -> float:
        """The marginal sigma of the fitted value `name` in one heliostat's fit."""
        u = with_uncertainty(member.scene, fit, member.train, "shape").uncertainty
        assert u is not None, "with_uncertainty gives every fit its uncertainty"
        return float(u.sigma[u.index(name)])


def with_values(effects: dict, values: dict[str, float]) -> dict:
    """A copy of an effect list with the values {"effect.parameter": value} set."""
    out = {e: dict(p) for e, p in effects.items()}
    for name, value in values.items():
        e, k = name.split(".")
        out[e][k] = value
    return out


def shared_effects(effects: dict, chosen: list[Candidate], shared: dict[str, float]) -> dict:
    """The shared effects every heliostat's model takes: the model's shared effects as configured,
    the chosen changes applied with their shared values (linear scalars stay "fit": each heliostat's
    own exposure)."""
    out = {e: dict(p or {}) for e, p in effects.items() if is_shared(e)}
    for c in chosen:
        out[c.effect] = dict(c.params)
    return with_values(out, shared)


def plant_shared(spec: dict, output_json: str | os.PathLike) -> dict:
    """Rule `plant_shared`: plant/shared.json, per plant entry what its heliostats share.

    spec: {"settings": heliostats, fit_images, heldout_images, fit_steps, cells_per_side, fit_rays
    (config plant.shared, its defaults the schema's), "device": ..., "plants": {plant: [{"heliostat", "dataset_path",
    "heliostat_path", "effects"}]}, "sizes": {plant: its number of heliostats}} (workflow.plant_shared_spec,
    which lists only the heliostats the fit takes; of a longer list it takes `settings["heliostats"]`
    evenly, data.splits.evenly)."""
    settings = spec["settings"]
    device = resolve_device(spec.get("device", "cpu"))
    out = {}
    for plant, heliostats in spec["plants"].items():
        picked = evenly(heliostats, settings["heliostats"])
        out[plant] = fit_plant(plant, [member(h, settings, device) for h in picked], picked[0]["effects"], settings,
                               spec.get("sizes", {}).get(plant, len(heliostats)))
    write_text_atomic(output_json, json.dumps(out, indent=1))
    return out


def member(entry: dict, settings: dict, device) -> Member:
    """A heliostat of the plant fit from its dataset and geometry files (the diagnosis' split and scale;
    a dataset that holds no images out is scored on the first of its cross-validation folds)."""
    ds = read_dataset(entry["dataset_path"])
    train_index, heldout_index, _ = scoring_split(ds)
    if not len(heldout_index):
        heldout_index = train_index[cross_validation_folds(len(train_index))[0]]
        train_index = np.setdiff1d(train_index, heldout_index)

    def pick(index: np.ndarray, n: int) -> np.ndarray:
        return index[np.linspace(0, len(index) - 1, min(n, len(index))).round().astype(int)]

    scale = float(ds.images[train_index].max())
    heliostat = read_heliostat(entry["heliostat_path"]).ideal().to(device)
    scene = dataset_scene(heliostat, ds.attrs, tuple(ds.images.shape[1:]), settings["cells_per_side"],
                          settings["fit_rays"], True)
    train = _measurements(ds, pick(train_index, settings["fit_images"]), scale, device)
    return Member(entry["heliostat"], scene, train,
                  _measurements(ds, pick(heldout_index, settings["heldout_images"]), scale, device))


def fit_plant(plant: str, members: list[Member], effects: dict, settings: dict, n_heliostats: int) -> dict:
    """One plant entry's shared effects (module docstring) as shared.json holds them."""
    fit = PlantFit(members, effects, FitSettings(steps=settings["fit_steps"], rounds=1))
    n_shared = len({c.effect for c in fit.tried})
    chosen = fit.select(n_shared)
    key = frozenset(chosen)
    final = fit.joint(chosen)
    before = fit.joint(()).error
    values = fit.sigma(key)
    tried = []
    for c in fit.tried:
        j = fit.joint([c.label])
        tried.append({"change": c.label, "effect": c.effect, "heldout_error": round(j.error, 5),
                      "relative_reduction": round(1.0 - j.error / max(before, 1e-30), 4),
                      "meaningful": is_meaningful(before, j.error), "shared_values": j.shared})
    test, why_not = fit.range_test(chosen)
    sun = range_verdict(test, why_not, effects)
    changed = {fit.candidate[c].effect for c in chosen}
    kept = shared_effects(effects, [fit.candidate[c] for c in chosen], final.shared)
    return {
        "heliostats": n_heliostats,
        "heliostats_fitted": [m.heliostat for m in members],
        "own_effects": OWN,
        "heldout_error": {"model": round(before, 5), "shared": round(final.error, 5)},
        "per_heliostat_heldout_error": {m.heliostat: round(e, 5) for m, e in zip(members, final.errors)},
        "changes": chosen,
        "shared": [{"effect": e, "shared_by": REGISTRY[e].shared_by, "params": p,
                    "changed": e in changed,
                    "values": {n: v for n, v in values.items() if n.startswith(e + ".")}}
                   for e, p in kept.items()],
        "effects": kept,
        "tried": tried,
        "range_test": None if test is None else {
            "deficit_mrad2": round(test.deficit_mrad2, 4), "sigma_mrad2": round(test.sigma_mrad2, 4),
            "significant": test.significant, "blur_px": round(test.blur_px, 4),
            "blur_sigma_px": round(test.blur_sigma_px, 5), "kept": int(sum(test.kept)),
            "ranges_m": {m.heliostat: round(r, 2) for m, r in zip(members, test.ranges_m)}},
        "verdict": plant_verdict(len(members), before, final.error, chosen, changed, kept, values) + " " + sun,
    }


def range_verdict(test: RangeTest | None, why_not: str, effects: dict) -> str:
    """What the range test (module docstring, 7) says of the sun against the camera, in words: the
    told sun agrees (within RANGE_HINT sigma), or the blur grows or shrinks with slant range (short of
    or beyond RANGE_SIGNIFICANCE sigma), with what the line gives and what else does the same; the
    sun is kept as configured either way."""
    if test is None:
        return (f"The sun was not tested against the camera ({why_not}): a sun told too narrow or too wide would show "
                "here as a wider or narrower blur.")
    span = f"{min(test.ranges_m):.0f}-{max(test.ranges_m):.0f} m"
    z = abs(test.deficit_mrad2) / max(test.sigma_mrad2, 1e-12)
    numbers = (f"the sun's variance deficit {test.deficit_mrad2:+.2f} +- {test.sigma_mrad2:.2f} mrad^2, {z:.1f} sigma, "
               f"over slant ranges of {span}, {sum(test.kept)} of {len(test.kept)} heliostats on the line")
    told = float(effects["sunshape"]["sigma_mrad"])
    if z < RANGE_HINT:
        return (f"The sun as configured ({told:g} mrad) agrees with the camera: the blur the heliostats need does not "
                f"grow or shrink with their slant range ({numbers}).")
    width, width_sigma = test.sun_width(told)
    grows = test.deficit_mrad2 > 0
    line = (f"sunshape.sigma_mrad = {width:.3f} +- {width_sigma:.2g} with camera.blur_px = {test.blur_px:.3f} +- "
            f"{test.blur_sigma_px:.2g}")
    words = [f"The blur the heliostats need {'grows' if grows else 'shrinks'} with their slant range ({numbers}"
             f"{'' if test.significant else f'; short of {RANGE_SIGNIFICANCE:g} sigma'}): the line gives {line}."]
    if grows:
        words.append(f"A sun wider than configured ({told:g} mrad) would do this, and so do the heliostats' own slope "
                     "errors, cantings and surfaces, which widen a spot by an angle as the sun does: on these images "
                     "the two look alike (on drawn plants whose sun is told right, such a line stands out beyond "
                     f"{RANGE_SIGNIFICANCE:g} sigma on up to 20 % of them: docs/diagnosis.md).")
    else:
        words.append(f"A sun narrower than configured ({told:g} mrad) would do this (the heliostats' own effects only "
                     "widen a spot), or a few heliostats at long range that the line rests on.")
    words.append("The sun is kept as configured; a measured sunshape would tell.")
    return " ".join(words)


def plant_verdict(n: int, before: float, after: float, chosen: list[str], changed: set[str], kept: dict,
                  values: dict) -> str:
    """One paragraph: what the plant's heliostats share (the `chosen` changes; `changed`: the effects
    they change), with the shared values and their sigma."""
    if not chosen:
        words = [(f"No change to the shared effects ({', '.join(sorted(kept)) or 'none in the model'}) cuts the "
                  f"held-out error of the {n} heliostats meaningfully: they are kept as configured.")]
    else:
        numbers = "; ".join(f"{name} = {v['value']:.4g} +- {v['sigma']:.2g}{sources(v)}" for name, v in values.items())
        words = [f"Shared by the {n} heliostats fitted: {', '.join(chosen)}"
                 + (f" ({numbers})" if numbers else "")
                 + f": the plant's held-out error falls from {before:.4f} to {after:.4f}."]
    rest = sorted(set(kept) - changed)
    if chosen and rest:
        words.append(f"Kept as configured: {', '.join(rest)}.")
    words.append(f"Each heliostat's own effects ({OWN}, canting, slope error, surface) are left to its own fit and "
                 "diagnosis, which take the shared effects at these values.")
    return " ".join(words)


def sources(value: dict) -> str:
    """What a shared value (`PlantFit.sigma`'s entry) is and where its sigma comes from, in words
    (module docstring, 4 and 6): the fewer heliostats the clipping kept, the more the clipped level
    rests on a few heliostats' luck of carrying no widening of their own."""
    kept = sum(a["kept"] for a in value["alone"].values())
    return (f" (the lower envelope of the {len(value['alone'])} heliostats' values; {value['sigma_statistical']:.2g} "
            f"from their scatter, {value['sigma_systematic']:.2g} from their own widenings: the level where the "
            f"{kept} least widened agree is {value['clipped']:.4g})")


def with_plant(effects: dict, shared: dict | None) -> dict:
    """A heliostat's model effects with its plant's shared effects (`shared`: {"path": plant/shared.json,
    "plant": its entry}, workflow.shared_of; None: unchanged) at the plant fit's values."""
    if shared is None:
        return effects
    try:
        with open(shared["path"]) as f:
            plants = json.load(f)
        kept = plants[shared["plant"]]["effects"]
    except (OSError, ValueError) as exc:
        raise DataError(f"{shared['path']}: cannot read the plant fit: {exc}") from None
    except (KeyError, TypeError):
        raise DataError(f"{shared['path']}: no shared effects of plant {shared['plant']!r}; rerun rule "
                        "plant_shared") from None
    return {**{e: p for e, p in effects.items() if not is_shared(e)}, **kept}
