"""The diagnosis: where the physics model fails against the measurements, and which effect is missing.

1. The model (config `model.effects`, its "fit" parameters fitted on the train split) predicts
   every measured image; residual signatures against sun position are measured (`signatures`).
2. Attribution: every candidate change (diagnosis/candidates.py: an effect the model lacks, a
   present effect's fixed values freed, the sun switched to another profile) is fitted on the
   train split and scored on the held-out splits (interpolation and extrapolation together; a
   dataset that holds none out by cross-validation over its images, `CrossValidated`). Fits
   are nested: a model with one change more starts from the fit without its most flexible change
   (and from the others only when that start ends above one of them) and never ends with a higher
   training loss. With one effect missing, the change that cuts the held-out error most is it;
   with several, a flexible effect (the surface) that mimics them all in part can win alone. So
   the identifiable candidates are chosen as the best subset (`Diagnosis.select`): the best single
   change, then the best pair whose both members are needed, kept when it beats the single
   (meaningfully, or as its superset with the added member needed), and so on up to
   `max_effects`; a subset holding a surface gives way to the best rigid one that ends within half
   a noise floor of it (`Diagnosis.rigid_alike`). A member is needed when dropping it costs a
   meaningful error, or when the images determine its parameters away from the values that do
   nothing (`Diagnosis.significant`: a Wald test at the joint fit, with the fit's misfit-inflated
   covariance) and it lowers the held-out error: a change of the spot's width by a few per cent (a
   slope error under a blurred camera) hardly moves the misplaced flux, which averages it into the
   noise, but its fitted value can stand many sigma from zero.
   A subset holds at least one change that cuts the held-out error meaningfully alone (a forward
   step from it); subsets of changes that each help too little alone are left to the next
   revision's diagnosis (the loop). The cost: n single fits, and the pairs that hold one of the m
   meaningful singles, m (n - 1) - m (m - 1) / 2 (none when nothing is missing). Changes
   that explain the same residual are reported as confounded: alike held-out errors, or their
   parameters correlated beyond CORRELATED_EFFECTS at their joint fit (the covariance of
   models/uncertainty.py, for fits of at most COVARIANCE_PARAMETERS parameters). Each pair comes
   with the measurement that would separate them: from the joint fit's covariance where it has one
   (the sun positions that lower the pair's correlation most, models/planning.py), else the
   effects' own words. Fitted values outside their physical range are flagged. Pure scale effects
   (unidentifiable on images compared by shape) are listed after the others.
3. A plain-language verdict names the top effect with its signature. The final model's fitted
   numbers carry their sigma (JSON `uncertainty`), and every image its predicted centroid with its
   sigma (`signatures.per_image.model_centroid_*`).

The error measure is the misplaced flux fraction: half the L1 distance between the predicted and
measured images, each divided by its own sum (0 = same shape, 1 = no overlap); a pure scale
changes nothing. A candidate claims a meaningful reduction when it cuts the held-out error by at
least `THRESHOLD` (relative) and by at least `ABSOLUTE_FLOOR` (absolute): below those, a
better fit is the noise of fitting more parameters.
"""

from __future__ import annotations

import itertools
import json
import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from scipy.stats import chi2
from torch import Tensor

from helioflow.data.hdf5 import read_dataset
from helioflow.data.noise import NoiseModel
from helioflow.data.surfaces import read_heliostat
from helioflow.device import resolve_device
from helioflow.diagnosis.candidates import Candidate, candidates, separating
from helioflow.diagnosis.criteria import (
    ABSOLUTE_FLOOR,
    EXPLAINED,
    MODEL_RESOLUTION,
    NUMERICAL_FLOOR,
    PARTLY,
    SIGNIFICANCE,
    THRESHOLD,
    compared_floor,
    is_meaningful,
)
from helioflow.diagnosis.ledger import model_hash, read_ledger, revised, write_ledger
from helioflow.diagnosis.noise import measured_noise, noise_floor
from helioflow.diagnosis.residuals import by_sun_position, in_image, on_mirror
from helioflow.diagnosis.verdict import model_flags, verdict
from helioflow.errors import ConfigError
from helioflow.io import write_text_atomic
from helioflow.models.physics_fit import (
    FitResult,
    FitSettings,
    Measurements,
    fit_effects,
    initial_tensors,
    spot_spread,
    with_uncertainty,
)
from helioflow.models.planning import canonical_correlation, image_information, plan
from helioflow.models.uncertainty import FitUncertainty, end_state
from helioflow.physics.effects import FIT, REGISTRY, fitted_parameters
from helioflow.physics.scene import Scene, dataset_scene, misplaced_flux

log = logging.getLogger(__name__)

ERROR_MEASURE = {"name": "misplaced_flux_fraction",
                 "description": "half the L1 distance of predicted and measured images, each divided by its own "
                                "sum: the fraction of the spot's flux in the wrong place (0 = same shape)"}
ROUNDING = 1e-3  # relative: a nested fit that ends no worse than its start up to this (float32 rounding of
#                   a loss that is a small difference of large numbers) keeps its own values
NOISE_METHOD = ("parametric bootstrap: the final model's held-out images re-noised with the noise measured in "
                "the measurements (its level per signal level and its spatial correlation, read in the model's "
                "residual at the frequencies the spot lacks; diagnosis/noise.py) and scored like the measurements")
CONFOUNDED_RATIO = 1.5  # two changes whose held-out errors are within this factor explain the same residual alike
CORRELATED_EFFECTS = 0.95  # two effects whose parameters correlate beyond this at their joint fit are confounded
COVARIANCE_PARAMETERS = 64  # joint fits with at most this many parameters get a covariance (the surface has hundreds)
CORRELATED_BLOCK = 5  # effects of at most this many parameters are compared by correlation (a block of dozens, a
#                       surface, reaches a canonical correlation near 1 with any single width: it can bend to mimic it)
SEPARATING_IMAGES = 3  # sun positions named as the measurement that separates a confounded pair ...
SEPARATED = 0.8  # ... when they bring the pair's correlation below this; else the effects' own words
SUN_GRID = [(az, el) for az in range(-120, 121, 40) for el in range(10, 81, 20)]  # where they are sought (deg)
CORE_FRACTION = 0.05  # the sun-limited core: pixels where the model's spot exceeds this fraction of its peak
MIRROR_IMAGES = 48  # images (evenly picked) the mirror localisation traces, region by region
FACET_SWAPS = 1  # passes of facet swaps in every fit with canting on 2-8 facets (models/physics_fit.py): a fit
# from untilted facets can end with two facets' tilts exchanged, and the surface then stands in for the canting
SWAP_NOISE = 0.5  # swapping a chosen change for another that ends within this fraction of the noise floor: alike


def signatures(scene: Scene, pred: Tensor, meas: Tensor, slant_m: float) -> dict[str, np.ndarray]:
    """Residual signatures per image (N,): centroid offset (mrad, target right/up, as seen from
    the heliostat), spot ellipse of measured and predicted (semi-axes m, orientation deg), width
    ratio, energy ratio (measured / predicted), fraction of measured energy outside the model's core."""
    out: dict[str, np.ndarray] = {}
    c_pred, c_meas = scene.target.centroid(pred), scene.target.centroid(meas)
    offset = (c_meas - c_pred) / slant_m * 1e3
    out["centroid_right_mrad"], out["centroid_up_mrad"] = offset[:, 0].numpy(), offset[:, 1].numpy()
    for name, images, c in (("measured", meas, c_meas), ("model", pred, c_pred)):
        major, minor, angle = _ellipse(images, scene, c)
        out[f"{name}_major_m"], out[f"{name}_minor_m"], out[f"{name}_angle_deg"] = major, minor, angle
    out["width_ratio"] = np.sqrt(out["measured_major_m"] * out["measured_minor_m"]
                                 / np.maximum(out["model_major_m"] * out["model_minor_m"], 1e-30))
    out["energy_ratio"] = (meas.sum((-2, -1)) / pred.sum((-2, -1)).clamp_min(1e-30)).numpy()
    core = pred >= CORE_FRACTION * pred.amax((-2, -1), keepdim=True)
    out["energy_outside_core"] = ((meas * ~core).sum((-2, -1)) / meas.sum((-2, -1)).clamp_min(1e-30)).numpy()
    return out


def _ellipse(images: Tensor, scene: Scene, c: Tensor) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Semi-axes (2 sigma, m) and orientation (deg from the target's right axis) of each spot's
    second moments about its centroid c (N, 2)."""
    u, v = scene.target.pixel_centres(images.dtype)
    w = images / images.sum((-2, -1), keepdim=True).clamp_min(1e-30)
    du = u[None, None, :] - c[:, 0, None, None]
    dv = v[None, :, None] - c[:, 1, None, None]
    suu, svv, suv = (w * du * du).sum((-2, -1)), (w * dv * dv).sum((-2, -1)), (w * du * dv).sum((-2, -1))
    cov = torch.stack((torch.stack((suu, suv), -1), torch.stack((suv, svv), -1)), -2).double()
    values, vectors = torch.linalg.eigh(cov)
    angle = torch.rad2deg(torch.atan2(vectors[:, 1, 1], vectors[:, 0, 1])) % 180.0
    return (2 * values[:, 1].clamp_min(0).sqrt()).numpy(), (2 * values[:, 0].clamp_min(0).sqrt()).numpy(), angle.numpy()


@dataclass
class Ranking:
    """The candidates ranked (`Diagnosis.rank`)."""

    before: float  # the model's held-out error (misplaced flux)
    model: FitResult  # the model's own fit
    entries: list[dict]  # the ranking, best first: the selected candidates, then the rest
    skipped: list[dict]  # effects not tested, and why
    selected: list[str]  # the selected candidates' labels


class Diagnosis:
    """One dataset against one model effect list: fits, scores and ranks (see module doc)."""

    def __init__(self, scene: Scene, effects: dict, train: Measurements, heldout: Measurements,
                 settings: FitSettings, max_effects: int = 2, plant: str = "", measured: bool = True):
        """`plant`: the shared effects (the registry's `shared_by`) were fitted across this plant's
        heliostats (diagnosis/shared.py): no change to them is tried here. `measured`: images that
        helioflow's tracer did not make (a camera's, an independent Monte Carlo's): the model's own
        resolution counts in what remains (`compared_floor`)."""
        self.scene, self.effects, self.train, self.heldout = scene, effects, train, heldout
        self.measured = measured
        self.max_effects = max_effects
        self.settings = FitSettings(**{**vars(settings), "loss": "shape"})
        known = frozenset({"neighbours"} if scene.neighbours is not None and len(scene.neighbours) else ())
        self.tried, self.skipped = candidates(effects, scene.heliostat.n_facets, known)
        if plant:
            shared = sorted({c.effect for c in self.tried if REGISTRY[c.effect].shared_by})
            self.tried = [c for c in self.tried if not REGISTRY[c.effect].shared_by]
            self.skipped += [{"effect": e, "reason": f"shared by every heliostat of plant {plant} "
                                                     f"({REGISTRY[e].shared_by}): fitted once across them "
                                                     "(plant/shared.json)"} for e in shared]
        self.candidate = {c.label: c for c in self.tried}
        self.results: dict[frozenset, FitResult] = {}  # the fits (`fit`)
        self.scores: dict[frozenset, float] = {}  # their held-out errors (`error`)
        self.predictions: dict[frozenset, Tensor] = {}
        self.noises: dict[frozenset, NoiseModel] = {}
        self.floors: dict[frozenset, tuple[float, float]] = {}
        self.covariances: dict[frozenset, FitResult | None] = {}

    def effects_with(self, labels) -> dict:
        """The model's effect list with the candidates `labels` applied."""
        out = {e: dict(p or {}) for e, p in self.effects.items()}
        for label in labels:
            c = self.candidate[label]
            out[c.effect] = dict(c.params)
        return out

    def compatible(self, labels) -> bool:
        """Whether the candidates change different effects (two changes of one effect exclude each other)."""
        effects = [self.candidate[label].effect for label in labels]
        return len(set(effects)) == len(effects)

    def fit(self, labels) -> FitResult:
        """The model with the candidates `labels` fitted on the train split. Nested: the fit starts
        from a fit of one candidate fewer, and keeps that start (the added candidate at its neutral
        values) when it ends with a higher training loss (beyond ROUNDING). The most flexible candidate
        (most free parameters, `free_parameters`) is added last: a surface fitted alone takes up a
        tracking error, and the pair started from it stays in that minimum (on the 30-heliostat plant
        the pair started from the tracking's fit ends at 0.35-0.5 of its training loss and at 0.4-0.5
        of its held-out error, near the noise floor). When that start ends above another fit of one
        candidate fewer, the next start is tried, and the lowest training loss wins: adding a
        candidate never raises the training loss."""
        key = frozenset(labels)
        if key in self.results:
            return self.results[key]
        effects = self.effects_with(key)
        if not key:
            result = fit_effects(self.scene, effects, self.train, self.settings)
        else:
            fewer = {added: self.fit(key - {added}) for added in key}
            bound = min(base.history[-1] for base in fewer.values()) * (1.0 + ROUNDING)
            ends = []
            for added in sorted(key, key=lambda label: (-self.free_parameters([label]), label)):
                base = fewer[added]
                end = fit_effects(self.scene, effects, self.train, self.settings, start=base)
                kept = self._embedded(base, key, added)
                ends.append(kept if kept is not None and end.history[-1] > base.history[-1] * (1.0 + ROUNDING) else end)
                if ends[-1].history[-1] <= bound:
                    break
            result = min(ends, key=lambda fit: fit.history[-1])
        self.results[key] = result
        return result

    def free_parameters(self, labels, with_model: bool = False) -> int:
        """The free parameters the candidates `labels` add (with the model's own "fit" ones too when
        `with_model`): tensors' free entries (a surface's control heights: hundreds; canting: 2 per
        facet; a tracking error: 5) and the "fit" scalars of effects without a tensor."""
        effects = self.effects_with(labels) if with_model else {
            self.candidate[n].effect: dict(self.candidate[n].params) for n in labels}
        _, masks = initial_tensors(effects, self.scene.heliostat)
        return sum(int(m.sum()) for m in masks.values()) + sum(e not in masks for e, _ in fitted_parameters(effects))

    def _embedded(self, base: FitResult, key: frozenset, added: str) -> FitResult | None:
        """The fit `base` as a fit of the model with the candidates `key`: the `added` candidate at
        its neutral values (None when it has none: a switched sun shape)."""
        c = self.candidate[added]
        if c.neutral is None:
            return None
        effects = {e: dict(p) for e, p in base.effects.items()}
        effects[c.effect] = dict(c.params) if REGISTRY[c.effect].tensor is not None else dict(c.neutral)
        zeros, _ = initial_tensors(self.effects_with(key), self.scene.heliostat)
        tensors = {**zeros, **base.tensors}
        return FitResult(effects, tensors, list(base.history), fitted_parameters(self.effects_with(key)))

    def error(self, labels) -> float:
        """The held-out misplaced flux of the model with the candidates `labels` (`fit`, `_scored`)."""
        key = frozenset(labels)
        if key not in self.scores:
            self.scores[key] = self._scored(key)
            log.info("model + %s: held-out error %.4f", " + ".join(sorted(key)) or "nothing", self.scores[key])
        return self.scores[key]

    def _scored(self, key: frozenset) -> float:
        """The held-out misplaced flux of the fit of the candidates `key` on the held-out split."""
        return heldout_error(self.scene, self.fit(key), self.heldout)

    def predicted(self, labels) -> Tensor:
        """(N_train + N_heldout, H, W) the images of the model with the candidates `labels`, fitted on
        the train split, at every sun position: the train split's, then the held-out ones (traced once)."""
        key = frozenset(labels)
        if key not in self.predictions:
            result = self.fit(key)
            az, el = (torch.cat((getattr(self.train, a), getattr(self.heldout, a)))
                      for a in ("azimuth_deg", "elevation_deg"))
            with torch.no_grad():
                self.predictions[key] = self.scene.simulate(result.effects, result.tensors, az, el)
        return self.predictions[key]

    def noise(self, labels) -> NoiseModel:
        """The measurements' noise read in the residual of the model with the candidates `labels` on
        every image (diagnosis/noise.py: `measured_noise`)."""
        key = frozenset(labels)
        if key not in self.noises:
            self.noises[key] = measured_noise(self.predicted(key), torch.cat((self.train.images, self.heldout.images)))
        return self.noises[key]

    def floor(self, labels) -> float:
        """The held-out error that noise alone would leave if the model with the candidates `labels`
        were the truth (diagnosis/noise.py: its held-out images re-noised like the measurements)."""
        return self._floor(labels)[0]

    def _floor(self, labels) -> tuple[float, float]:
        """(that floor, the standard error of its bootstrap)."""
        key = frozenset(labels)
        if key not in self.floors:
            pred = self.predicted(key)[len(self.train.images):]
            per_image, standard_error = noise_floor(pred, self.heldout.images, self.noise(key))
            self.floors[key] = (float(per_image.mean()), standard_error)
        return self.floors[key]

    def remaining(self, labels) -> dict:
        """What remains after the candidates `labels`: held-out error, the noise floor, their ratio,
        and whether it is explained down to the noise: within EXPLAINED times `compared_floor`, the
        noise's floor with the model's own resolution (`model_resolution`, 0 on helioflow's own traces)."""
        error, (floor, standard_error) = self.error(labels), self._floor(labels)
        ratio = error / float(compared_floor(floor, self.measured))
        return {"changes": list(labels), "error": error, "noise_floor": floor,
                "noise_floor_standard_error": standard_error,
                "model_resolution": MODEL_RESOLUTION if self.measured else 0.0,
                "over_noise": ratio, "explained": bool(ratio <= EXPLAINED)}

    def select(self) -> list[str]:
        """The candidates the measurements need (best subset, module doc), in the order a forward
        path adds them."""
        names = [c.label for c in self.tried if REGISTRY[c.effect].identifiable]
        helps = {n for n in names if is_meaningful(self.error(()), self.error([n]))}  # each fitted alone
        chosen: tuple = ()
        for k in range(1, self.max_effects + 1):
            subsets = [s for s in itertools.combinations(names, k) if self.compatible(s) and helps & set(s)]
            needed = [s for s in subsets if k == 1 or all(self.needed(m, set(s) - {m}) for m in s)]
            if not needed:
                break
            best = self.rigid_alike(min(needed, key=self.error), needed)
            if not (is_meaningful(self.error(chosen), self.error(best))
                    or (set(chosen) < set(best) and self.error(best) < self.error(chosen))):
                break
            chosen = best
        order: list[str] = []
        while len(order) < len(chosen):
            order.append(min((n for n in chosen if n not in order), key=lambda n: self.error([*order, n])))
        return order

    def rigid_alike(self, best: tuple, subsets: list[tuple]) -> tuple:
        """`best`, or, when its joint fit is too flexible for a covariance (beyond
        COVARIANCE_PARAMETERS free parameters: a surface's heights, which bend to mimic a tilt or a
        widening), the best subset of rigid changes whose fit has one when that ends within SWAP_NOISE
        of the noise floor of `best`: the images do not tell them apart, and the rigid changes' values
        are tested and carry their sigma (the flexible one stays listed as a stand-in). The rigid
        subsets are those of `subsets` and the subsets, all members needed, of the up to `max_effects`
        compatible rigid changes that cut most alone: a surface that stands in for two rigid changes
        may leave neither a meaningful cut alone (on the 30-heliostat plant a tracking error cut
        24.6 % alone and a canting 20 %, together they ended below the surface). Every compatible
        subset of the changes that cut at all would cost a fit each (journal 2026-12-06). On the
        30-heliostat plant a slope error and a canting were named surface + tracking at held-out
        errors within 1 % of the true pair's; the surface of a bump cuts 1.3-2.7 noise floors below
        the best rigid pair."""
        def rigid(subset) -> bool:
            return self.free_parameters(subset, with_model=True) <= COVARIANCE_PARAMETERS

        if rigid(best):
            return best
        bound = self.error(best) + SWAP_NOISE * max(self.floor(best), NUMERICAL_FLOOR)
        helping = sorted((c.label for c in self.tried if REGISTRY[c.effect].identifiable and rigid([c.label])
                          and self.error([c.label]) < self.error(())), key=lambda label: self.error([label]))
        top: list[str] = []
        for label in helping:
            if len(top) < self.max_effects and self.compatible([*top, label]):
                top.append(label)
        more = [s for k in range(1, len(top) + 1) for s in itertools.combinations(top, k) if rigid(s)]
        alike = sorted({tuple(sorted(s)) for s in [*subsets, *more] if rigid(s) and self.error(s) <= bound},
                       key=self.error)
        return next((s for s in alike if len(s) == 1 or all(self.needed(m, set(s) - {m}) for m in s)), best)

    def needed(self, label: str, rest) -> bool:
        """Whether candidate `label` is needed beside the candidates `rest`: dropping it costs a
        meaningful held-out error, or its parameters are significant there (`significant`)."""
        return is_meaningful(self.error(rest), self.error({*rest, label})) or self.significant(label, rest) is not None

    def significant(self, label: str, rest) -> dict | None:
        """The Wald test of candidate `label` beside the candidates `rest`, when it passes: at their
        joint fit, the departure d of its fitted parameters from the values that do nothing (its
        `neutral`; 0 for a tensor's entries) against their statistical covariance C
        (models/uncertainty.py: scaled by the fit's misfit and widened by how far it stopped short, but
        without the variance of facets the fit has not found, which is the tensor's own typical entry
        and made canting's W equal its degrees of freedom on every heliostat of the independent
        plants, canting or not: docs/journal/2026-11-28-seed-22-misses.md), W = d^T C+ d beyond the
        1 - SIGNIFICANCE quantile of chi^2 with rank(C) degrees of freedom, and the held-out error
        lower with it than without. {"wald", "dof", "p", "determined"}: `determined` false when the
        covariance reports any of its parameters not determined (a structured residual: the value may
        stand in for what the model lacks, and the verdict says so). A change of several parameters
        not determined must also cut the held-out error by PARTLY: against a structured residual a
        pattern of several entries stands out from white noise whether the heliostat has it or not
        (canting beside a tracking error on helioflow's own images without canting: W = 127 on 6
        degrees of freedom, a 0.3 % cut; the independent plants' cantings named so cut 15-23 %),
        while a single width moves the misplaced flux too little to be asked for a cut (a slope
        error's 0.7 %, tested). None when it fails or cannot be
        tested (a switched sun has no do-nothing values; a fit beyond COVARIANCE_PARAMETERS has no
        covariance)."""
        c, key = self.candidate[label], frozenset({*rest, label})
        if c.neutral is None or self.error(key) >= self.error(rest):
            return None
        fit = self.with_covariance(key)
        if fit is None:
            return None
        u = _uncertainty(fit)
        # the change's own parameters: a tensor's entries (do nothing: 0) and the scalars it moves from a
        # number; one the model fits as well ("fit" in `neutral`: the camera's gain beside its blur) is no part of it
        neutral = {k: 0.0 if "[" in u.names[k] else c.neutral.get(u.names[k].split(".", 1)[1], 0.0)
                   for k in self._indices(fit, label)}
        at = [k for k, v in neutral.items() if isinstance(v, (int, float)) and not isinstance(v, bool)]
        if not at:
            return None
        d = u.values[at] - np.array([float(neutral[k]) for k in at])
        if u.statistical is None:
            raise ValueError("this fit's uncertainty has no statistical covariance (a fresh fit's has one)")
        covariance = u.statistical[np.ix_(at, at)]  # not what unfound facets may do: that scales with the value
        dof = int(np.linalg.matrix_rank(covariance))
        if dof == 0:
            return None
        wald = float(d @ np.linalg.pinv(covariance) @ d)
        p = float(chi2.sf(wald, dof))
        determined = not any(u.names[k] in u.undetermined for k in at)
        if p >= SIGNIFICANCE or (not determined and dof > 1 and self.error(key) > (1.0 - PARTLY) * self.error(rest)):
            return None
        return {"wald": round(wald, 2), "dof": dof, "p": float(f"{p:.3g}"), "determined": determined}

    def rank(self) -> Ranking:
        """The candidates ranked (`Ranking`).

        The selected candidates first, in forward order (each entry's before/after is the held-out
        error without and with it, the candidates above it included), then the rest, each added
        alone, by that cut, the unidentifiable scales last. Every entry also carries
        `reduction_alone` (the cut when it is the only change) and `confounded_with`."""
        before = self.error(())
        selected = self.select()
        ranking = [self._entry(n, selected[:k], meaningful=True, joint=selected) for k, n in enumerate(selected)]
        rest = [self._entry(c.label, [], meaningful=False) for c in self.tried if c.label not in selected]
        rest.sort(key=lambda r: (not r["identifiable"], -r["relative_reduction"]))
        ranking += rest
        for r in ranking:
            r["reduction_alone"] = 1.0 - self.error([r["effect"]]) / max(before, 1e-30)
            alike = self.confounded(r["effect"])
            if r["effect"] in selected:
                seen = {c["effect"] for c in alike}
                alike += [c for c in self.swapped(r["effect"], selected) if c["effect"] not in seen]
                seen = {c["effect"] for c in alike}
                alike += [c for c in self.correlated(r["effect"], selected) if c["effect"] not in seen]
            for c in alike:  # where a joint fit has a covariance: the pair's correlation, and what separates them
                found = self.correlation(r["effect"], c["effect"], selected) if "correlation" not in c else None
                if found is not None:
                    c["correlation"] = round(found[0], 4)
                    c["separated_by"] = self.separating_images(found[1], r["effect"], c["effect"])
            r["confounded_with"] = alike
        return Ranking(before, self.fit(()), ranking, self.skipped, selected)

    def swapped(self, label: str, chosen: list[str]) -> list[dict]:
        """Candidates that can stand in for `label` among the chosen ones: the chosen set with
        `label` swapped for them ends within SWAP_NOISE of the noise floor of the chosen set's
        held-out error (or lower), given the other chosen changes, and is needed there itself (a
        change named for its significance cuts the error little, and a candidate that does nothing
        would end as close). With the measurement that separates them."""
        rest = [n for n in chosen if n != label]
        error, tolerance = self.error(chosen), SWAP_NOISE * max(self.floor(chosen), NUMERICAL_FLOOR)
        out = []
        for c in self.tried:
            other = c.label
            if (other in chosen or not REGISTRY[c.effect].identifiable or not self.compatible([*rest, other])
                    or c.effect == self.candidate[label].effect):
                continue
            swapped = self.error([*rest, other])
            if swapped <= error + tolerance and self.needed(other, rest):
                out.append({"effect": other, "relative_reduction": 1.0 - swapped / max(self.error(rest), 1e-30),
                            "given": rest, "heldout_error": swapped,
                            "separated_by": separating(self.candidate[label].effect, c.effect)})
        return out

    def with_covariance(self, key: frozenset) -> FitResult | None:
        """The fit of the candidates `key` with its uncertainty (models/uncertainty.py), or None when
        they were neither fitted nor scored (`fit`, `error`) or have more than COVARIANCE_PARAMETERS
        parameters."""
        if key not in self.covariances:
            tried = key in self.results or key in self.scores
            self.covariances[key] = (with_uncertainty(self.scene, self.fit(key), self.train, "shape")
                                     if tried and self.free_parameters(key, with_model=True) <= COVARIANCE_PARAMETERS
                                     else None)
        return self.covariances[key]

    def correlated(self, label: str, chosen: list[str]) -> list[dict]:
        """Candidates the images cannot tell from `label`: each cuts the held-out error meaningfully
        alone, and at the joint fit of the chosen changes with the candidate (or of the two alone; the
        fits the selection made) the first canonical correlation of the two effects' parameters (at
        most CORRELATED_BLOCK each) is beyond CORRELATED_EFFECTS. Each with that
        correlation and the sun positions that would separate them (`separated_by`)."""
        out, before = [], self.error(())
        for c in self.tried:
            other = c.label
            if (other in chosen or not self.compatible([label, other]) or not REGISTRY[c.effect].identifiable
                    or not is_meaningful(before, self.error([other]))):  # a confounder explains some of it alone
                continue
            found = self.correlation(label, other, chosen)
            if found is None or found[0] < CORRELATED_EFFECTS:
                continue
            r, key = found
            rest = sorted(key - {label, other})
            cut = 1.0 - self.error([*rest, other]) / max(self.error(rest), 1e-30)
            out.append({"effect": other, "relative_reduction": cut,
                        "given": rest, "heldout_error": self.error([*rest, other]), "correlation": round(r, 4),
                        "separated_by": self.separating_images(key, label, other)})
        return out

    def correlation(self, label: str, other: str, chosen: list[str]) -> tuple[float, frozenset] | None:
        """(first canonical correlation of the two candidates' parameters, the fit it comes from): the
        joint fit of the chosen changes with `other`, else of the two alone; None where neither was
        fitted or has a covariance."""
        for key in (frozenset({*chosen, other}), frozenset({label, other})):
            fit = self.with_covariance(key) if label in key else None
            if fit is None:
                continue
            a, b = (self._indices(fit, n) for n in (label, other))
            if 0 < len(a) <= CORRELATED_BLOCK and 0 < len(b) <= CORRELATED_BLOCK:
                return canonical_correlation(_uncertainty(fit).covariance, a, b), key
        return None

    def _indices(self, fit: FitResult, label: str) -> list[int]:
        prefix = self.candidate[label].effect + "."
        return [k for k, n in enumerate(_uncertainty(fit).names) if n.startswith(prefix)]

    def separating_images(self, key: frozenset, label: str, other: str) -> str:
        """The measurement that separates two confounded candidates, from the joint fit's covariance:
        the SEPARATING_IMAGES sun positions of SUN_GRID that lower their correlation most
        (models/planning.py, criterion "pair"), in words; where they leave it above SEPARATED, no
        calibration image does, and the effects' own words (`separating`) say what would."""
        fit = self.with_covariance(key)
        if fit is None:
            raise ValueError(f"the candidates {sorted(key)} have no fit with a covariance to separate them by")
        effects = (self.candidate[label].effect, self.candidate[other].effect)
        az, el = (torch.tensor([s[i] for s in SUN_GRID], dtype=torch.float32, device=self.train.images.device)
                  for i in (0, 1))
        _, masks = initial_tensors(fit.effects, self.scene.heliostat)
        state = end_state(self.scene, fit, az, el, self.train.scale, "shape", masks)
        picks = plan(image_information(state, fit.fitted, masks, _uncertainty(fit)), _uncertainty(fit),
                     SEPARATING_IMAGES, "pair", pair=effects)
        where = ", ".join(f"(azimuth {SUN_GRID[p.index][0]}, elevation {SUN_GRID[p.index][1]} deg)" for p in picks)
        after = -picks[-1].gain
        if after > SEPARATED:
            return (f"no calibration image separates them (the best {SEPARATING_IMAGES}, at {where}, leave their "
                    f"correlation at {after:.2f}); {separating(*effects)}")
        return (f"images at the sun positions {where}, where the two predict the most different spots (their "
                f"correlation falls to {after:.2f})")

    def confounded(self, label: str) -> list[dict]:
        """Candidates that explain the same residual as `label`: each alone cuts the held-out error
        meaningfully, to much the same error (within CONFOUNDED_RATIO of each other), and fitted
        together they do no meaningfully better than the better one alone (the pair is fitted when
        the selection fits pairs, max_effects >= 2). With the measurement that separates them."""
        before, mine = self.error(()), self.error([label])
        if not is_meaningful(before, mine):
            return []
        out = []
        for c in self.tried:
            other = c.label
            if other == label or not self.compatible([label, other]) or not REGISTRY[c.effect].identifiable:
                continue
            theirs = self.error([other])
            if not is_meaningful(before, theirs) or max(theirs, mine) > CONFOUNDED_RATIO * min(theirs, mine):
                continue
            if self.max_effects >= 2 and is_meaningful(min(mine, theirs), self.error([label, other])):
                continue
            out.append({"effect": other, "relative_reduction": 1.0 - theirs / max(before, 1e-30), "given": [],
                        "heldout_error": theirs, "separated_by": separating(self.candidate[label].effect, c.effect)})
        return out

    def _entry(self, name: str, base: list[str], meaningful: bool, joint: list[str] | None = None) -> dict:
        """One ranking entry: candidate `name` added to the model plus the candidates `base`; its config
        line with the values of the fit of `joint` (the selected changes together, the model the lines
        make), else of its own fit; `fitted` always its own fit's."""
        before, after = self.error(base), self.error([*base, name])
        c = self.candidate[name]
        fit = self.fit([*base, name])
        test = self.significant(name, base) if meaningful and base else None
        own = {k.split(".", 1)[1]: v for k, v in fit.fitted_values().items() if k.startswith(c.effect + ".")}
        return {"effect": name, "changes": c.effect, "change": c.change, "fitted": _summarised(own),
                "added_to": list(base), "heldout_error_before": before, "heldout_error_after": after,
                "relative_reduction": 1.0 - after / max(before, 1e-30),
                "identifiable": REGISTRY[c.effect].identifiable, "meaningful": meaningful,
                "significance": test,
                "named_for": ("" if not meaningful else "cut" if test is None
                              or 1.0 - after / max(before, 1e-30) >= THRESHOLD else "significance"),
                "config": config_line(c, self.fit(joint) if joint else fit)}


class CrossValidated(Diagnosis):
    """A dataset that holds no images out, diagnosed on all of them by k-fold cross-validation.

    Every candidate is fitted on all the images (its values, their sigma, the significance tests,
    the final model, the noise) and, once per fold, on the images outside the fold, scored on the
    fold's (`folds`): the held-out error is the mean misplaced flux over every image, each held out
    once, and the noise floor the mean of what noise leaves on each image under the fit on all. On
    a real heliostat's few images one or two held-out images would decide the verdict alone."""

    def __init__(self, scene: Scene, effects: dict, images: Measurements, folds: list[np.ndarray],
                 settings: FitSettings, max_effects: int = 2, plant: str = "", measured: bool = True):
        """`images`: every image; `folds`: (k,) the indices into them that each fold holds out
        (`cross_validation_folds`); the rest as `Diagnosis`'."""
        super().__init__(scene, effects, images, _subset(images, np.arange(0)), settings, max_effects, plant,
                         measured)
        everything = np.arange(len(images.images))
        self.folds = [Diagnosis(scene, effects, _subset(images, np.setdiff1d(everything, held)),
                                _subset(images, held), settings, max_effects, plant, measured) for held in folds]

    def _scored(self, key: frozenset) -> float:
        """The misplaced flux of each fold's fit on the fold's images, averaged over every image."""
        return sum(len(f.heldout.images) * f.error(key) for f in self.folds) / len(self.train.images)

    def _floor(self, labels) -> tuple[float, float]:
        """(what noise alone leaves on every image under the fit on all, the standard error of its bootstrap)."""
        key = frozenset(labels)
        if key not in self.floors:
            per_image, standard_error = noise_floor(self.predicted(key), self.train.images, self.noise(key))
            self.floors[key] = (float(per_image.mean()), standard_error)
        return self.floors[key]


def _subset(m: Measurements, index: np.ndarray) -> Measurements:
    """The measurements `index` of `m`."""
    at = torch.as_tensor(index, dtype=torch.long, device=m.images.device)
    return Measurements(m.images[at], m.azimuth_deg[at], m.elevation_deg[at], m.scale)


def heldout_error(scene: Scene, result: FitResult, heldout: Measurements) -> float:
    """The mean misplaced flux fraction of a fit's prediction against held-out measurements."""
    with torch.no_grad():
        pred, lost = scene.simulate(result.effects, result.tensors, heldout.azimuth_deg, heldout.elevation_deg,
                                    with_lost=True)
    return float(misplaced_flux(pred, heldout.images, lost).mean())


def is_measured(attrs: dict) -> bool:
    """Whether a dataset's images are measurements (PAINT, own camera images), not helioflow's own trace."""
    return not str(attrs.get("source", "")).startswith("synthetic")


def config_line(candidate: Candidate, fit: FitResult) -> str:
    """The line to paste under `model.effects` in config.yaml: the candidate's fitted scalars at
    their values, "fit" for the heliostat's canting and surface (the physics models fit those)."""
    values, params = fit.fitted_values(), {}
    for k, v in candidate.params.items():
        value = values.get(f"{candidate.effect}.{k}", v) if v == FIT else v
        params[k] = v if isinstance(value, list) else (round(value, 4) if isinstance(value, float) else value)
    return f"{candidate.effect}: {{{', '.join(f'{k}: {v}' for k, v in params.items())}}}"


def _predicted_centroids(spots: dict[str, np.ndarray]) -> dict[str, list]:
    """The final model's predicted spot centroid per image (mrad from the target centre, right / up,
    as seen from the heliostat) and its sigma from the fit's covariance (physics_fit.spot_spread)."""
    (right, up), (s_right, s_up) = spots["centroid_mrad"].T, spots["centroid_sigma_mrad"].T
    return {"model_centroid_right_mrad": np.round(right, 4).tolist(),
            "model_centroid_up_mrad": np.round(up, 4).tolist(),
            "model_centroid_sigma_right_mrad": np.round(s_right, 5).tolist(),
            "model_centroid_sigma_up_mrad": np.round(s_up, 5).tolist()}


def _summarised(values: dict) -> dict:
    """Fitted values for the JSON: tensors (lists) as their RMS and size."""
    out = {}
    for k, v in values.items():
        if isinstance(v, list):
            a = np.asarray(v, dtype=float)
            out[f"{k}_rms"] = round(float(np.sqrt((a**2).mean())), 4)
            out[f"{k}_count"] = int(a.size)
        else:
            out[k] = round(float(v), 4) if isinstance(v, (int, float)) else v
    return out


def _uncertainty(fit: FitResult) -> FitUncertainty:
    """The uncertainty of a fit that has one (physics_fit.with_uncertainty: `with_covariance`'s)."""
    if fit.uncertainty is None:
        raise ValueError("this fit has no uncertainty (physics_fit.with_uncertainty)")
    return fit.uncertainty


def summarise(sig: dict[str, np.ndarray]) -> dict:
    """Numbers the verdict and the JSON quote, over all images."""
    ratio = float(np.median(sig["width_ratio"]))
    return {"centroid": float(np.sqrt(np.mean(sig["centroid_right_mrad"] ** 2 + sig["centroid_up_mrad"] ** 2))),
            "width": f"{abs(ratio - 1):.1%} " + ("wider" if ratio >= 1 else "narrower"),
            "width_ratio": ratio, "outside": float(np.median(sig["energy_outside_core"])),
            "ratio": float(np.median(sig["energy_ratio"]))}


OWN_FOLDS = 4  # a dataset that holds no images out: the diagnosis cross-validates over this many folds (at most n)


def scoring_split(ds) -> tuple[np.ndarray, np.ndarray, dict]:
    """(indices the fits use, indices they are scored on, what the JSON says of the latter).

    The held-out splits (interpolation and extrapolation) when the dataset has them. A dataset that
    holds none out (own images without splits or holdout, a PAINT dataset without holdout: every
    image trains the networks): (its images, none), scored by cross-validation over them
    (`CrossValidated`, `cross_validation_folds`; the JSON's count and note are `cross_validated`'s);
    with a single image, on that image itself (a training error: no test of a candidate against
    images it was not fitted to)."""
    train = ds.indices("train")
    heldout = np.concatenate((ds.indices("interpolation"), ds.indices("extrapolation")))
    if len(heldout):
        return train, heldout, {"source": "held-out splits", "images": len(heldout), "note": ""}
    if len(train) < 2:
        return train, train, {"source": "the training image", "images": len(train),
                              "note": ("The dataset has one image and holds none out: every error below is a "
                                       "training error, and no candidate is tested on an image it was not fitted to.")}
    return train, heldout, cross_validated(len(train), len(train))


def cross_validation_folds(n: int) -> list[np.ndarray]:
    """The folds of n images: min(OWN_FOLDS, n) of them, fold j holding out the images j, j + k, ...
    (images ordered in time spread each fold over the days)."""
    k = min(OWN_FOLDS, n)
    return [np.arange(j, n, k) for j in range(k)]


def cross_validated(used: int, images: int) -> dict:
    """What the JSON says of a dataset of `images` images that holds none out, `used` of them cross-validated."""
    k = len(cross_validation_folds(used))
    of = f"all {images}" if used == images else f"{used} of its {images}"
    return {"source": f"{k}-fold cross-validation", "images": used,
            "note": (f"The dataset holds no images out (every image trains the networks), so the diagnosis "
                     f"cross-validates over {of} images: each candidate is fitted {k} times, each time without "
                     f"one in {k} of them, and scored on those.")}


def _measurements(ds, index: np.ndarray, scale: float, device: str | torch.device = "cpu") -> Measurements:
    return Measurements((torch.as_tensor(ds.images[index]) / scale).to(device),
                        torch.as_tensor(ds.azimuth_deg[index]).float().to(device),
                        torch.as_tensor(ds.elevation_deg[index]).float().to(device), scale)


@dataclass
class DiagnosisResult:
    """What `diagnose` finds: the record diagnosis/{dataset}.json holds, the ledger with this
    revision recorded (every entry, for `write_diagnosis`), and the images the figures show."""

    record: dict
    ledger: list[dict]
    predicted: np.ndarray  # (N, H, W) the model's images of every measurement, in the measurements' scale
    measured: np.ndarray  # (N, H, W) the measurements over the training images' peak
    error: np.ndarray  # (N,) the model's misplaced flux per image


def diagnose_dataset(dataset_path, heliostat_path, effects: dict, settings: dict, output_json, figures: dict | None,
                     ledger_path, device: str | torch.device = "cpu", plant: str = "") -> dict:
    """The `diagnose` rule: diagnosis/{dataset}.json (its record returned), its figures (keys of
    `figures`: signatures, ranking, residuals, location, ledger; None: none drawn) and the ledger at
    `ledger_path`; the arguments as `diagnose`'s. A broken ledger stops the rule before the fits."""
    ds = read_dataset(dataset_path)
    result = diagnose(ds, heliostat_path, effects, settings, read_ledger(ledger_path), device, plant,
                      name=Path(dataset_path).stem)
    write_diagnosis(result, ds, output_json, figures, ledger_path)
    return result.record


def write_diagnosis(result: DiagnosisResult, ds, output_json, figures: dict | None, ledger_path) -> None:
    """Write `diagnose`'s result: the figures (`figures`' paths; None: none), the ledger, then the JSON."""
    if figures is not None:
        from helioflow.diagnosis.figures import plot_diagnosis

        plot_diagnosis(result.record, ds, result.predicted, result.measured, result.error, figures)
    write_ledger(ledger_path, result.ledger)
    write_text_atomic(output_json, json.dumps(result.record, indent=1))
    log.info("verdict: %s", result.record["verdict"])


def diagnose(ds, heliostat_path, effects: dict, settings: dict, ledger: list[dict], device: str | torch.device = "cpu",
             plant: str = "", name: str = "dataset") -> DiagnosisResult:
    """Diagnose the dataset `ds` (data.hdf5.CalibrationDataset) against the model `effects` of the
    heliostat at `heliostat_path` (the module doc); nothing is written.

    Args:
        effects: the model's effect list for this dataset.
        settings: fit_images, heldout_images, fit_steps, rounds, cells_per_side, fit_rays, max_effects.
        ledger: the ledger's entries so far (ledger.read_ledger); this revision is recorded in them.
        device: where the fits run (cpu | cuda | auto).
        plant: a plant's heliostat: its plant entry, whose shared effects `effects` holds at the
            plant fit's values (diagnosis.shared.with_plant); no change to them is tried.
        name: the dataset's name where its attributes hold none (its file's stem).
    """
    train_index, heldout_index, heldout = scoring_split(ds)
    scale = float(ds.images[train_index].max())
    def pick(index, n):
        return index[np.linspace(0, len(index) - 1, min(n, len(index))).round().astype(int)]

    device = resolve_device(device)
    heliostat = read_heliostat(heliostat_path).ideal().to(device)
    shape = tuple(ds.images.shape[1:])
    fit_scene = dataset_scene(heliostat, ds.attrs, shape, settings["cells_per_side"], settings["fit_rays"], True)
    fit = FitSettings(steps=settings["fit_steps"], rounds=settings["rounds"], facet_swaps=FACET_SWAPS)
    used = _measurements(ds, pick(train_index, settings["fit_images"]), scale, device)
    measured = is_measured(ds.attrs)
    diagnosis: Diagnosis
    if len(heldout_index):
        diagnosis = Diagnosis(fit_scene, effects, used,
                              _measurements(ds, pick(heldout_index, settings["heldout_images"]), scale, device), fit,
                              settings["max_effects"], plant=plant, measured=measured)
    else:
        n = len(used.images)
        if n < 2:
            raise ConfigError(f"diagnosis.fit_images is {settings['fit_images']}, but dataset {name} holds no images "
                              "out and is cross-validated over the images the fits use: expected at least 2")
        diagnosis = CrossValidated(fit_scene, effects, used, cross_validation_folds(n), fit, settings["max_effects"],
                                   plant=plant, measured=measured)
        heldout = cross_validated(n, len(train_index))
    ranked = diagnosis.rank()
    before, model, ranking, chosen = ranked.before, ranked.model, ranked.entries, ranked.selected
    remaining = diagnosis.remaining(chosen)
    final = with_uncertainty(fit_scene, diagnosis.fit(chosen), diagnosis.train, "shape")
    everything = _measurements(ds, np.arange(len(ds.images)), scale)
    sun = everything.azimuth_deg.to(device), everything.elevation_deg.to(device)
    spots = {k: v.cpu().numpy() for k, v in spot_spread(fit_scene, final, *sun, scale, "shape").items()}
    with torch.no_grad():
        pred, lost = fit_scene.simulate(model.effects, model.tensors, *sun, with_lost=True)
        pred, lost = pred.cpu() / scale, lost.cpu() / scale
        last, last_lost = pred, lost  # the final model is the model when nothing is chosen
        if chosen:
            last, last_lost = fit_scene.simulate(final.effects, final.tensors, *sun, with_lost=True)
            last, last_lost = last.cpu() / scale, last_lost.cpu() / scale
    slant = float(np.linalg.norm(np.subtract(ds.attrs["target_center_m"], heliostat.position.cpu().numpy())))
    sig = signatures(fit_scene, pred, everything.images, slant)
    summary = summarise(sig)
    if ds.attrs.get("per_image_normalised"):  # each image divided by its own peak: no absolute energy
        sig.pop("energy_ratio")
        summary["ratio"] = None
    floor_each = noise_floor(last, everything.images, diagnosis.noise(chosen))[0]
    error_each = misplaced_flux(last, everything.images, last_lost).numpy()
    over_noise = error_each / compared_floor(floor_each, diagnosis.measured)
    few = pick(np.arange(len(ds.images)), MIRROR_IMAGES)  # the mirror's images (traced once per region)
    at = torch.as_tensor(few)
    location = {"changes": chosen, "sun_position": by_sun_position(ds.azimuth_deg, ds.elevation_deg, over_noise),
                "image": in_image(fit_scene, last, everything.images),
                "mirror": on_mirror(fit_scene, final.effects, final.tensors, sun[0][at.to(sun[0].device)],
                                    sun[1][at.to(sun[1].device)], everything.images[at].to(device),
                                    over_noise[few] > EXPLAINED)}
    changed = {diagnosis.candidate[label].effect for label in chosen}
    final_fitted = _summarised(final.fitted_values())  # the named changes' values flagged in the verdict, the
    #                                                   model's own after it
    ledger, revisions = revised(ledger, str(ds.attrs.get("config_hash", name)), effects, before)
    result = {
        "dataset": ds.attrs.get("dataset", name),
        "model_effects": effects,
        "plant": plant or None,
        "model_hash": model_hash(effects),
        "error_measure": ERROR_MEASURE,
        "threshold": {"relative_reduction": THRESHOLD, "absolute_reduction": ABSOLUTE_FLOOR,
                      "significance": SIGNIFICANCE,
                      "explained_over_noise": EXPLAINED, "numerical_floor": NUMERICAL_FLOOR},
        "heldout_error": before,
        "heldout": heldout,
        "noise_floor": remaining["noise_floor"],
        "noise_floor_standard_error": remaining["noise_floor_standard_error"],
        "noise": {"method": NOISE_METHOD, "model": diagnosis.noise(chosen).as_json()},
        "remaining": {k: remaining[k] for k in ("changes", "error", "model_resolution", "over_noise", "explained")},
        "remaining_note": ("The images hold almost no noise: what remains is compared with the diagnosis' "
                           f"numerical floor ({NUMERICAL_FLOOR})"
                           if remaining["noise_floor"] < NUMERICAL_FLOOR and not diagnosis.measured else ""),
        "model_fitted": _summarised(model.fitted_values()),
        "final_fitted": final_fitted,
        "ranking": ranking,
        "not_tested": ranked.skipped,
        "signatures": {"rms_centroid_offset_mrad": summary["centroid"], "median_width_ratio": summary["width_ratio"],
                       "median_energy_ratio": summary["ratio"], "median_energy_outside_core": summary["outside"],
                       "note": ("images each normalised to their own peak: no energy ratio between measured and "
                                "predicted flux" if summary["ratio"] is None else ""),
                       "per_image": {"azimuth_deg": ds.azimuth_deg.tolist(), "elevation_deg": ds.elevation_deg.tolist(),
                                     "split": ds.split.tolist(),
                                     **{k: np.round(v, 5).tolist() for k, v in sig.items()},
                                     "remaining_error": np.round(error_each, 5).tolist(),
                                     "noise_floor": np.round(floor_each, 5).tolist(),
                                     **_predicted_centroids(spots)}},
        "uncertainty": {"changes": chosen, **_uncertainty(final).as_json()},
        "location": location,
        "verdict": ((heldout["note"] + " " if heldout["note"] else "")
                    + verdict(ranking, summary, remaining, location,
                              {k: v for k, v in final_fitted.items() if k.split(".", 1)[0] in changed})
                    + model_flags({k: v for k, v in final_fitted.items() if k.split(".", 1)[0] not in changed})),
        "ledger": revisions,
    }
    return DiagnosisResult(result, ledger, pred.numpy(), everything.images.numpy(),
                           misplaced_flux(pred, everything.images, lost).numpy())
