"""How much of the heliostat a handful of images determine: drt's freedom, chosen by leave-one-out
over its own training images.

On a few real images a fit of everything can run away: the kinematics and the surface take up what
the model lacks and predict a held-out image worse than the ideal heliostat does. The pixels do not
stop it (a real residual is smooth over the spot, so its independent pixels are far fewer than its
pixels, and a prior weighted by the pixel count is negligible), and a design prior applied after the
fit moved what it did not need to touch (docs/journal/2026-12-02-few-image-fits.md). What does decide
it is the question the user asks: does the freer fit predict an image it was not fitted to better?
So the freedom is chosen as a model is chosen by cross-validation:

- the nested levels: `design` (the configured model's own fit: sun, camera; the heliostat as
  designed), `tracking` (+ the five kinematic errors), `canting` (+ the facets' tilts, heliostats
  of several facets), `full` (+ surface and slope error: what drt fits);
- each level fitted on every training image but one and scored on that one (misplaced flux, the
  scale-free measure of the diagnosis and the leave-one-out table), each level's fit starting from
  the level below's on the same images (a nested fit);
- the simplest level whose mean held-out score is within one standard error of the best level's
  (the one-standard-error rule of cross-validation: a freer model must earn its freedom by more
  than the scatter of the scores);
- one training image leaves nothing to test on: the design is kept.

What is not fitted stays at the design: its value is the prior, and the written heliostat says so
(scoring/fitted_heliostat.py). What is fitted carries a sigma at least the scatter of the chosen level's
leave-one-out fits (the jackknife, models/uncertainty.py `widened_by_refits`): on a handful of real images
the residual is model mismatch more than noise, and the covariance at the fit's end point alone is too sure.

The levels cost one fit each per training image, so `auto` chooses only up to SELECT_MAX_IMAGES
training images; with more, everything is fitted (docs/results.md, "drt on real images": where the
images are that many, the full fit beats the ideal heliostat).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from torch import Tensor

from helioflow.models.physics_fit import FitResult, Measurements
from helioflow.physics.scene import misplaced_flux

FREEDOMS = ("design", "tracking", "canting", "full")  # nested: each frees more of the heliostat
CHOICES = ("auto", *FREEDOMS)
SELECT_MAX_IMAGES = 4  # auto chooses by leave-one-out up to this many training images; with more: full


@dataclass
class FreedomChoice:
    """The freedom a fit took and why.

    Attributes:
        chosen: one of FREEDOMS.
        reason: one sentence for a user.
        scores: {level: held-out misplaced flux per training image left out} (empty when no
            choice was made by leave-one-out).
        refits: {level: its fits, one per training image left out}: their scatter is the
            jackknife's variance of the fit on all images (models/uncertainty.py `widened_by_refits`);
            not written to the model file.
    """

    chosen: str
    reason: str
    scores: dict[str, list[float]] = field(default_factory=dict)
    refits: dict[str, list[FitResult]] = field(default_factory=dict, repr=False)

    def as_json(self) -> dict:
        """The choice, its reason and the held-out scores (each level's mean and standard error too)."""
        summary = {k: {"mean": round(float(np.mean(v)), 5), "standard_error": round(_standard_error(v), 5)}
                   for k, v in self.scores.items()}
        return {"chosen": self.chosen, "reason": self.reason,
                "held_out_misplaced_flux": {k: [round(x, 5) for x in v] for k, v in self.scores.items()},
                "summary": summary}

    @classmethod
    def from_json(cls, data: dict) -> FreedomChoice:
        """The choice `as_json` wrote."""
        return cls(data["chosen"], data["reason"], {k: list(v) for k, v in data["held_out_misplaced_flux"].items()})


def choose_freedom(levels: dict[str, dict], data: Measurements,
                   fit: Callable[[dict, Measurements, FitResult | None], FitResult],
                   predict: Callable[[FitResult, Tensor, Tensor], Tensor]) -> FreedomChoice:
    """The freedom of the module docstring.

    Args:
        levels: {level: effect list}, simplest first (FREEDOMS order).
        data: the N training images (N, H, W) and their sun positions (N,) deg.
        fit: (effects, measurements, start) -> the fit of those effects (start: the nested start).
        predict: (fit, azimuth (K,), elevation (K,)) -> (K, H, W) predicted images.
    """
    n = len(data.images)
    if n < 2:
        return FreedomChoice("design", "one training image: no other image to test a freer fit on, so the "
                                       "heliostat stays as designed")
    scores: dict[str, list[float]] = {k: [] for k in levels}
    refits: dict[str, list[FitResult]] = {k: [] for k in levels}
    for out in range(n):
        keep = [i for i in range(n) if i != out]
        subset = Measurements(data.images[keep], data.azimuth_deg[keep], data.elevation_deg[keep], data.scale)
        start = None
        for level, effects in levels.items():
            start = fit(effects, subset, start)
            refits[level].append(start)
            predicted = predict(start, data.azimuth_deg[out:out + 1], data.elevation_deg[out:out + 1])
            scores[level].append(float(misplaced_flux(predicted, data.images[out:out + 1])[0]))
    mean = {k: float(np.mean(v)) for k, v in scores.items()}
    best = min(mean, key=lambda k: mean[k])
    bar = mean[best] + _standard_error(scores[best])
    chosen = next(k for k in levels if mean[k] <= bar)
    reason = (f"chosen by leave-one-out over the {n} training images: held-out misplaced flux "
              + ", ".join(f"{k} {mean[k]:.3f}" for k in levels)
              + f"; the simplest within one standard error of the best ({best}, {mean[best]:.3f} + "
                f"{bar - mean[best]:.3f})")
    return FreedomChoice(chosen, reason, scores, refits)


def _standard_error(values: list[float]) -> float:
    return float(np.std(values, ddof=1) / np.sqrt(len(values))) if len(values) > 1 else 0.0
