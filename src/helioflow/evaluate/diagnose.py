"""The diagnosis: where the physics model fails against the measurements, and which effect is missing.

1. The model (config `model.effects`, its "fit" parameters fitted on the train split) predicts
   every measured image; residual signatures against sun position are measured (`signatures`).
2. Attribution: every registry effect the model lacks is added with its parameters marked
   "fit", fitted on the train split, and scored on the held-out splits (interpolation and
   extrapolation together). With one effect missing, the one that cuts the held-out error most
   is it; with several, an effect that mimics them all in part (the flexible surface) can win
   alone. So the identifiable candidates are chosen by stepwise selection (`stepwise`): forward,
   add the candidate that cuts the held-out error of the model plus the effects chosen so far
   most, while that cut is meaningful; backward, after each addition, drop a chosen effect that
   the others have made unnecessary. The chosen effects lead the ranking; pure scale effects
   (unidentifiable on images compared by shape) are listed after the others.
3. A plain-language verdict names the top effect with its signature.

The error measure is the misplaced flux fraction: half the L1 distance between the predicted and
measured images, each divided by its own sum (0 = same shape, 1 = no overlap); a pure scale
changes nothing. A candidate claims a meaningful reduction when it cuts the held-out error by at
least `THRESHOLD` (relative) and by at least `ABSOLUTE_FLOOR` (absolute): below those, a
better fit is the noise of fitting more parameters.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from ..data.hdf5 import read_dataset
from ..data.surfaces import read_heliostat
from ..device import resolve_device
from ..errors import DataError
from ..io import write_text_atomic
from ..models.physics_fit import (
    FitResult,
    FitSettings,
    Measurements,
    Scene,
    dataset_scene,
    fit_effects,
    normalised,
)
from ..physics.effects import FIT, REGISTRY
from ..physics.target import centroid

log = logging.getLogger(__name__)

ERROR_MEASURE = {"name": "misplaced_flux_fraction",
                 "description": "half the L1 distance of predicted and measured images, each divided by its own "
                                "sum: the fraction of the spot's flux in the wrong place (0 = same shape)"}
THRESHOLD = 0.25  # relative held-out error reduction a candidate needs to count
ABSOLUTE_FLOOR = 0.002  # ... and absolute reduction of the misplaced flux fraction
CORE_FRACTION = 0.05  # the sun-limited core: pixels where the model's spot exceeds this fraction of its peak

# how each absent effect is tried: its parameters, "fit" where fitted
CANDIDATES = {
    "sunshape": {"kind": "gaussian", "sigma_mrad": FIT},
    "slope_error": {"sigma_mrad": FIT},
    "tracking": {p.name: FIT for p in REGISTRY["tracking"].parameters},
    "canting": {"facet_tilts_mrad": FIT},
    "surface": {"control_heights_mm": FIT},
    "attenuation": {"model": "constant", "transmittance": FIT},
    "reflectivity": {"value": FIT},
    "camera": {"gain": FIT, "background_w_m2": FIT, "blur_px": FIT},
}
NOT_APPLICABLE = {"blocking_shading": "a calibration dataset images one heliostat: it has no neighbours to block or shade it"}
MISSING_TEXT = {
    "sunshape": "a wider sun shape", "slope_error": "slope error (small-scale mirror roughness)",
    "tracking": "a tracking error (kinematic offsets of the heliostat's axes)",
    "canting": "facet canting errors", "surface": "a surface deformation (smooth mirror shape errors)",
    "camera": "the camera's response (background and blur)", "attenuation": "atmospheric attenuation",
    "reflectivity": "a lower mirror reflectivity",
}
SIGNATURE_TEXT = {
    "sunshape": "the measured spots are {width} than the model's, in every direction",
    "slope_error": "the measured spots are {width} than the model's, in every direction",
    "tracking": "the spot centroids are off by {centroid:.2f} mrad RMS, varying with sun position",
    "canting": "the measured spots have a different structure (facets' images do not overlap as the model's do)",
    "surface": "the measured spot shapes differ from the model's in ways that change with the sun position",
    "camera": "{outside:.1%} of the measured flux lies outside the model's spot (background or blur)",
    "attenuation": "the measured flux is {ratio:.3f} times the model's (a scale)",
    "reflectivity": "the measured flux is {ratio:.3f} times the model's (a scale)",
}


def misplaced_flux(pred: Tensor, meas: Tensor, lost: Tensor | None = None) -> Tensor:
    """(N, H, W) predicted and measured images -> (N,) misplaced flux fraction (see module doc);
    `lost` (N,): predicted flux that missed the image (Scene.simulate), misplaced too."""
    p = normalised(pred.double(), "shape", 1.0, None if lost is None else lost.double())
    m = normalised(meas.double(), "shape", 1.0)
    return 0.5 * (p - m).abs().mean((-2, -1))


def model_hash(effects: dict) -> str:
    """Short hash of a model effect list's content: the ledger's key for a model revision."""
    return hashlib.sha256(json.dumps(effects, sort_keys=True).encode()).hexdigest()[:10]


def signatures(scene: Scene, pred: Tensor, meas: Tensor, slant_m: float) -> dict[str, np.ndarray]:
    """Residual signatures per image (N,): centroid offset (mrad, target right/up, as seen from
    the heliostat), spot ellipse of measured and predicted (semi-axes m, orientation deg), width
    ratio, energy ratio (measured / predicted), fraction of measured energy outside the model's core."""
    out: dict[str, np.ndarray] = {}
    c_pred, c_meas = centroid(pred, scene.target), centroid(meas, scene.target)
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


class Diagnosis:
    """One dataset against one model effect list: fits, scores and ranks (see module doc)."""

    def __init__(self, scene: Scene, effects: dict, train: Measurements, heldout: Measurements,
                 settings: FitSettings, max_effects: int = 2):
        self.scene, self.effects, self.train, self.heldout = scene, effects, train, heldout
        self.max_effects = max_effects
        self.settings = FitSettings(**{**vars(settings), "loss": "shape"})

    def heldout_error(self, effects: dict) -> tuple[float, FitResult]:
        """(mean held-out misplaced flux, the fit) of an effect list fitted on the train split."""
        result = fit_effects(self.scene, effects, self.train, self.settings)
        with torch.no_grad():
            pred, lost = self.scene.simulate(result.effects, result.tensors, self.heldout.azimuth_deg,
                                             self.heldout.elevation_deg, with_lost=True)
        return float(misplaced_flux(pred, self.heldout.images, lost).mean()), result

    def candidates(self) -> tuple[list[str], list[dict]]:
        """(effects to try, not tested with reasons) for this model and heliostat."""
        tried, skipped = [], []
        for name in REGISTRY:
            if name in self.effects:
                continue
            if name in NOT_APPLICABLE:
                skipped.append({"effect": name, "reason": NOT_APPLICABLE[name]})
            elif name == "canting" and self.scene.heliostat.n_facets == 1:
                skipped.append({"effect": name, "reason": "one facet: its tilt is a tracking error"})
            else:
                tried.append(name)
        return tried, skipped

    def rank(self) -> tuple[float, FitResult, list[dict], list[dict]]:
        """(held-out error of the model, the model's fit, ranking best first, effects not tested).

        The ranking comes from stepwise selection over the identifiable candidates (module doc):
        the selected effects first, in the order of a forward path (each entry's before/after is
        the held-out error without and with it, the effects above it included), then the rest,
        each added alone, by that cut, the unidentifiable scales last. Every entry also carries
        `reduction_alone`: the cut when it is the only effect added."""
        tried, skipped = self.candidates()
        scores: dict[frozenset, tuple[float, FitResult]] = {}

        def score(names) -> float:
            key = frozenset(names)
            if key not in scores:
                scores[key] = self.heldout_error({**self.effects, **{n: dict(CANDIDATES[n]) for n in names}})
                log.info("model + %s: held-out error %.4f", "+".join(sorted(key)) or "nothing", scores[key][0])
            return scores[key][0]

        before = score(())
        alone = {n: 1.0 - score([n]) / max(before, 1e-30) for n in tried}
        identifiable = [n for n in tried if REGISTRY[n].identifiable]
        selected = sorted(stepwise(identifiable, score, self.max_effects), key=lambda n: -alone[n])
        ranking = []
        for k, name in enumerate(selected):
            ranking.append(self._entry(name, selected[:k], score, scores, meaningful=True))
        rest = [self._entry(n, [], score, scores, meaningful=False) for n in tried if n not in selected]
        rest.sort(key=lambda r: (not r["identifiable"], -r["relative_reduction"]))
        ranking += rest
        for r in ranking:
            r["reduction_alone"] = alone[r["effect"]]
        return before, scores[frozenset()][1], ranking, skipped

    def _entry(self, name: str, base: list[str], score, scores: dict, meaningful: bool) -> dict:
        """One ranking entry: `name` added to the model plus the effects `base`, fitted and scored."""
        before, after = score(base), score([*base, name])
        fit = scores[frozenset([*base, name])][1]
        own = {k.split(".", 1)[1]: v for k, v in fit.fitted_values().items() if k.startswith(name + ".")}
        return {"effect": name, "fitted": _summarised(own), "added_to": list(base), "heldout_error_before": before,
                "heldout_error_after": after, "relative_reduction": 1.0 - after / max(before, 1e-30),
                "identifiable": REGISTRY[name].identifiable, "meaningful": meaningful}


def is_meaningful(before: float, after: float) -> bool:
    """Does going from held-out error `before` to `after` count as a finding (module doc)?"""
    return after <= (1.0 - THRESHOLD) * before and before - after >= ABSOLUTE_FLOOR


def stepwise(names: list[str], score, max_effects: int = 2) -> list[str]:
    """Stepwise selection of the effects that the measurements need, in the order added.

    Forward: add the candidate whose joint fit with the effects selected so far has the lowest
    held-out error, while that cut is meaningful. Backward, after each addition: drop an earlier
    effect whose removal no longer costs a meaningful error (the newcomer explains what it
    explained: a flexible surface that absorbed part of a tracking error is dropped once tracking
    is in). Fitting one candidate at a time cannot do this: with two effects missing, the one that
    mimics both partly wins alone. `score(names)` is the held-out error of the model plus `names`.
    At most `max_effects` are selected (each stage fits every remaining candidate jointly with
    the selected ones: the cost grows with it); the loop names the rest in the next revision.
    """
    selected: list[str] = []
    for _ in range(2 * len(names)):  # each effect can enter and leave; bounds a (rare) cycle
        if len(selected) >= max_effects:
            break
        trials = {n: score([*selected, n]) for n in names if n not in selected}
        best = min(trials, key=trials.get, default=None)
        if best is None or not is_meaningful(score(selected), trials[best]):
            break
        selected.append(best)
        while len(selected) >= 2:
            full = score(selected)
            without = {n: score([m for m in selected if m != n]) for n in selected[:-1]}
            weakest = min(without, key=without.get)
            if is_meaningful(without[weakest], full):
                break
            selected.remove(weakest)
    return selected


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


def verdict(ranking: list[dict], summary: dict) -> str:
    """One plain-language paragraph: what is missing, the evidence, and how much fitting it helps."""
    if not ranking:
        return "No effect could be tested: the model contains every registry effect that applies here."
    meaningful = [r for r in ranking if r["meaningful"]]
    if not meaningful:
        best = ranking[0]
        return (f"No missing effect found: no effect absent from the model cuts the held-out error (misplaced flux "
                f"{best['heldout_error_before']:.3f}) by {THRESHOLD:.0%} or more; the best, "
                f"{best['effect'].replace('_', ' ')}, cuts it by {best['relative_reduction']:.0%}. The model explains "
                f"the measurements as far as the registry's effects can tell.")
    top = meaningful[0]
    evidence = SIGNATURE_TEXT[top["effect"]].format(**summary)
    text = (f"The model lacks {MISSING_TEXT[top['effect']]}: {evidence}; "
            f"fitting {top['effect'].replace('_', ' ')} cuts the held-out error by {top['relative_reduction']:.0%} "
            f"(misplaced flux {top['heldout_error_before']:.3f} -> {top['heldout_error_after']:.3f}).")
    if len(meaningful) > 1:
        others = ", ".join(f"{r['effect'].replace('_', ' ')} ({r['relative_reduction']:.0%})" for r in meaningful[1:])
        text += (f" Also missing, each added to the effects before it: {others}. Add the first, rerun, "
                 "and look again.")
    return text


def summarise(sig: dict[str, np.ndarray]) -> dict:
    """Numbers the verdict and the JSON quote, over all images."""
    ratio = float(np.median(sig["width_ratio"]))
    return {"centroid": float(np.sqrt(np.mean(sig["centroid_right_mrad"] ** 2 + sig["centroid_up_mrad"] ** 2))),
            "width": f"{abs(ratio - 1):.1%} " + ("wider" if ratio >= 1 else "narrower"),
            "width_ratio": ratio, "outside": float(np.median(sig["energy_outside_core"])),
            "ratio": float(np.median(sig["energy_ratio"]))}


def read_ledger(path: str | os.PathLike) -> list[dict]:
    """The revisions in the ledger at `path` (none when it does not exist yet); DataError names the
    file when it is not a ledger. Read before the fits, so that a broken ledger costs no run."""
    path = Path(path)
    if not path.exists():
        return []
    try:
        entries = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise DataError(f"{path}: not a readable ledger (JSON list of model revisions): {exc}; "
                        "repair it or delete it to start a new ledger") from None
    keys = ("revision", "model_hash", "dataset_hash", "model_effects", "heldout_error")
    if not isinstance(entries, list) or not all(isinstance(e, dict) and all(k in e for k in keys) for e in entries):
        raise DataError(f"{path}: expected a JSON list of model revisions, each with {', '.join(keys)}; "
                        "repair it or delete it to start a new ledger")
    return entries


def update_ledger(path: str | os.PathLike, dataset_hash: str, effects: dict, error: float) -> list[dict]:
    """Record the held-out error of this model revision in the ledger at `path` (JSON list, kept
    across runs: not a rule output) and return the revisions on the same measurements, oldest
    first. A revision is keyed by the hash of the model effect list; a rerun replaces its entry."""
    entries = read_ledger(path)
    key = model_hash(effects)
    same = [e for e in entries if e["dataset_hash"] == dataset_hash]
    entry = next((e for e in same if e["model_hash"] == key), None)
    if entry is None:
        entry = {"revision": len(same) + 1, "model_hash": key, "dataset_hash": dataset_hash, "model_effects": effects}
        entries.append(entry)
    entry["heldout_error"] = error
    write_text_atomic(path, json.dumps(entries, indent=1))
    return [e for e in entries if e["dataset_hash"] == dataset_hash]


def _measurements(ds, index: np.ndarray, scale: float, device: str | torch.device = "cpu") -> Measurements:
    return Measurements((torch.as_tensor(ds.images[index]) / scale).to(device),
                        torch.as_tensor(ds.azimuth_deg[index]).float().to(device),
                        torch.as_tensor(ds.elevation_deg[index]).float().to(device), scale)


def diagnose_dataset(dataset_path, heliostat_path, effects: dict, settings: dict, output_json, figures: dict,
                     ledger_path, device: str = "cpu") -> dict:
    """The `diagnose` rule: diagnosis/{dataset}.json and its figures (keys of `figures`:
    signatures, ranking, residuals, ledger).

    Args:
        effects: the model's effect list for this dataset.
        settings: fit_images, heldout_images, fit_steps, rounds, cells_per_side, fit_rays, max_effects.
        device: where the fits run (cpu | cuda | auto).
    """
    from .diagnosis_figures import plot_diagnosis

    ds = read_dataset(dataset_path)
    read_ledger(ledger_path)  # a broken ledger stops the rule before the fits, not after them
    train_index = ds.indices("train")
    heldout_index = np.concatenate((ds.indices("interpolation"), ds.indices("extrapolation")))
    scale = float(ds.images[train_index].max())
    pick = lambda index, n: index[np.linspace(0, len(index) - 1, min(n, len(index))).round().astype(int)]
    device = resolve_device(device)
    heliostat = read_heliostat(heliostat_path).ideal().to(device)
    shape = tuple(ds.images.shape[1:])
    fit_scene = dataset_scene(heliostat, ds.attrs, shape, settings["cells_per_side"], settings["fit_rays"], True)
    fit = FitSettings(steps=settings["fit_steps"], rounds=settings["rounds"])
    diagnosis = Diagnosis(fit_scene, effects, _measurements(ds, pick(train_index, settings["fit_images"]), scale, device),
                          _measurements(ds, pick(heldout_index, settings["heldout_images"]), scale, device), fit,
                          settings["max_effects"])
    before, model, ranking, skipped = diagnosis.rank()
    everything = _measurements(ds, np.arange(len(ds.images)), scale)
    with torch.no_grad():
        pred, lost = fit_scene.simulate(model.effects, model.tensors, everything.azimuth_deg.to(device),
                                        everything.elevation_deg.to(device), with_lost=True)
        pred, lost = pred.cpu() / scale, lost.cpu() / scale
    slant = float(np.linalg.norm(np.subtract(ds.attrs["target_center_m"], heliostat.position.cpu().numpy())))
    sig = signatures(fit_scene, pred, everything.images, slant)
    summary = summarise(sig)
    ledger = update_ledger(ledger_path, str(ds.attrs.get("config_hash", Path(dataset_path).stem)), effects, before)
    result = {
        "dataset": ds.attrs.get("dataset", Path(dataset_path).stem),
        "model_effects": effects,
        "model_hash": model_hash(effects),
        "error_measure": ERROR_MEASURE,
        "threshold": {"relative_reduction": THRESHOLD, "absolute_reduction": ABSOLUTE_FLOOR},
        "heldout_error": before,
        "ranking": ranking,
        "not_tested": skipped,
        "signatures": {"rms_centroid_offset_mrad": summary["centroid"], "median_width_ratio": summary["width_ratio"],
                       "median_energy_ratio": summary["ratio"], "median_energy_outside_core": summary["outside"],
                       "per_image": {"azimuth_deg": ds.azimuth_deg.tolist(), "elevation_deg": ds.elevation_deg.tolist(),
                                     "split": ds.split.tolist(),
                                     **{k: np.round(v, 5).tolist() for k, v in sig.items()}}},
        "verdict": verdict(ranking, summary),
        "ledger": ledger,
    }
    error = misplaced_flux(pred, everything.images, lost).numpy()
    plot_diagnosis(result, ds, pred.numpy(), everything.images.numpy(), error, figures)
    write_text_atomic(output_json, json.dumps(result, indent=1))
    log.info("verdict: %s", result["verdict"])
    return result
