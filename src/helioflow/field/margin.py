"""How sure a calibrated field's flux map is, and an aiming that keeps the limit with a stated probability.

A calibrated heliostat's pointing is known to its tracking parameters' covariance C (5 x 5, mrad^2:
the fit's, models/uncertainty.py). Where its beam meets the receiver moves, to first order, by
J d for tracking errors d, J (2 x 5, m per mrad) the derivative of that point (u right, v up on the
receiver plane) through the heliostat's kinematics (`receiver_jacobian`: the central ray from the
heliostat's reference point, reflected about the mirror normal the kinematics give, met with the
receiver plane). So its spot on the receiver sits at its aim point plus a displacement with
covariance J C J^T (m^2), independent between heliostats (`pointing_covariances`).

The map's spread follows by drawing those displacements (`jittered_peaks`): the spots precomputed
for the aim optimiser (field.aim.SpotPatches) are moved by aim offset + draw and summed, a render
per draw and no ray. The peak's `probability` quantile over the draws is the bound an operator can
hold the limit to; `optimise_with_margin` chooses aim points on the model's map under a lowered
limit, the largest fraction of the limit (found by bisection, with the same draws throughout) whose
aiming keeps the peak's quantile under the real limit. Only the pointing is drawn: it moves whole
spots, where the surface's and the canting's uncertainty reshape them by far less on the receiver
(the plant's fits: pointing sigma 0.3-0.5 mrad, canting and surface "not determined" in
place). A heliostat without a fitted tracking covariance (a network's model, an unmeasured
heliostat, a fit that kept the design) is taken as pointing where its model says.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import torch
from scipy.stats import binom, chi2
from torch import Tensor

from helioflow.field.aim import AimResult, Limit, SpotPatches, optimise, render
from helioflow.models.uncertainty import FitUncertainty
from helioflow.physics.effects import REGISTRY
from helioflow.physics.geometry import reflect
from helioflow.physics.heliostat import Heliostat, orientation
from helioflow.physics.target import Target

TRACKING_NAMES = [f"tracking.{p.name}" for p in REGISTRY["tracking"].parameters]  # FitUncertainty names, in order
BISECTIONS = 7  # halvings of the limit's fraction: the margin to 0.4 % of the limit
LOWEST_FRACTION = 0.5  # the smallest fraction of the limit the bisection hands the optimiser
QUANTILE_CONFIDENCE = 0.95  # the confidence with which the drawn peaks bound the peak's quantile (`peak_quantile`)


def tracking_covariance(uncertainty: FitUncertainty | None) -> Tensor | None:
    """(5, 5) mrad^2: the fit's covariance of its five tracking parameters (TRACKING_NAMES order);
    None when the fit has no uncertainty or did not fit the tracking."""
    if uncertainty is None or not all(n in uncertainty.names for n in TRACKING_NAMES):
        return None
    at = [uncertainty.index(n) for n in TRACKING_NAMES]
    return torch.as_tensor(uncertainty.covariance[np.ix_(at, at)], dtype=torch.float64)


def receiver_jacobian(heliostat: Heliostat, sun: Tensor, aim: Tensor, receiver: Target) -> Tensor:
    """(2, 5) m per mrad: how the point where `heliostat`'s central ray meets the receiver plane moves
    (u right, v up) per mrad of each tracking parameter (TRACKING_NAMES order), at the heliostat's own
    tracking, for the (3,) unit vector towards the sun `sun` and the (3,) ENU aim point `aim` (m)."""
    h = heliostat.to("cpu", torch.float64)
    sun, aim = sun.detach().cpu().double(), aim.detach().cpu().double()
    centre, normal = receiver.center.detach().cpu().double(), receiver.normal.detach().cpu().double()
    right, up = (a.detach().cpu().double() for a in receiver.axes())

    def hit(error_mrad: Tensor) -> Tensor:
        turned = orientation(replace(h, tracking_error=error_mrad * 1e-3), sun[None], aim)[0]
        ray = reflect(-sun, turned[:, 2])
        point = h.position + ((centre - h.position) @ normal) / (ray @ normal) * ray
        return torch.stack(((point - centre) @ right, (point - centre) @ up))

    jacobian = torch.autograd.functional.jacobian(hit, h.tracking_error.double() * 1e3)
    assert isinstance(jacobian, Tensor)
    return jacobian


def pointing_covariances(heliostats: list[Heliostat], covariances: list[Tensor | None], sun: Tensor,
                         aims: Tensor, receiver: Target) -> Tensor:
    """(N, 2, 2) m^2: each heliostat's spot displacement on the receiver, J C J^T (module docstring), for
    its (5, 5) tracking covariance (mrad^2; None: zero), the (3,) sun vector and its (N, 3) aim points."""
    out = torch.zeros(len(heliostats), 2, 2, dtype=torch.float64)
    for k, (h, c) in enumerate(zip(heliostats, covariances)):
        if c is not None:
            j = receiver_jacobian(h, sun, aims[k], receiver)
            out[k] = j @ c @ j.T
    return out


def covered(covariances: Tensor, offsets: Tensor, probability: float = 0.95) -> tuple[float, int]:
    """(the share of the heliostats with a covariance whose (N, 2) offsets (m; e.g. true spot centroid minus
    the model's) lie inside their `probability` ellipse of the (N, 2, 2) covariances (m^2), how many have
    one): a covariance that describes the pointing covers about `probability` of them."""
    known = covariances.diagonal(dim1=-2, dim2=-1).sum(-1) > 0
    if not bool(known.any()):
        return 1.0, 0
    c, d = covariances[known], offsets[known].to(covariances)
    distance = (d[:, None, :] @ torch.linalg.pinv(c) @ d[:, :, None]).reshape(-1)  # squared Mahalanobis
    return float((distance <= chi2.ppf(probability, 2)).double().mean()), int(known.sum())


def displacement_draws(covariances: Tensor, draws: int, seed: int) -> Tensor:
    """(draws, N, 2) m: displacements drawn from each heliostat's (N, 2, 2) covariance (seeded)."""
    n = covariances.shape[0]
    values, vectors = torch.linalg.eigh(covariances)  # a zero or degenerate covariance has no Cholesky factor
    root = vectors * values.clamp_min(0.0).sqrt()[:, None, :]
    z = torch.randn(draws, n, 2, generator=torch.Generator().manual_seed(seed), dtype=torch.float64)
    return torch.einsum("nij,dnj->dni", root, z)


def jittered_peaks(spots: SpotPatches, offsets: Tensor, displacements: Tensor, limit_w_m2: Limit) -> Tensor:
    """(D,) the peak over the limit (field.aim.peak_over_limit; the limit in W/m^2, one value or a map) of
    the map with every spot at its aim offset ((N, 2) m) plus each of the (D, N, 2) displacements (m)."""
    with torch.no_grad():
        return torch.stack([(render(spots, offsets + d.to(offsets)) / limit_w_m2).max() for d in displacements])


def peak_quantile(spots: SpotPatches, offsets: Tensor, displacements: Tensor, probability: float,
                  limit_w_m2: Limit) -> float:
    """An upper bound, at QUANTILE_CONFIDENCE, of the `probability` quantile of the peak over the limit
    over the displaced maps (`jittered_peaks`): the order statistic X_(k) of the D drawn peaks with the smallest k
    for which the binomial law puts the quantile below it with that confidence, whatever the peak's
    distribution. The plain sample quantile of 64 draws, which the bisection then leans on, kept the
    limit on 82 % of fresh draws for a stated 90 % (tests/field/test_margin.py)."""
    peaks = torch.sort(jittered_peaks(spots, offsets, displacements, limit_w_m2)).values
    k = int(binom.ppf(QUANTILE_CONFIDENCE, len(peaks), probability))  # P(Binom(D, p) <= k) >= confidence
    return float(peaks[min(k, len(peaks) - 1)])


def optimise_with_margin(spots: SpotPatches, start: Tensor, limit_w_m2: Limit, displacements: Tensor,
                         probability: float, *, region: float, steps: int, seed: int = 0,
                         target: Tensor | None = None) -> tuple[AimResult, float, float]:
    """(the aiming, its peak over the limit's `probability` quantile over the `displacements`, the fraction
    of the limit it was optimised under): the largest fraction f, to 2^-BISECTIONS, whose optimised aiming
    (field.aim.optimise under f x limit) keeps the quantile at most 1; the full limit when its own aiming
    already does, LOWEST_FRACTION's when none does. The aiming's peak_over_limit and feasible are over the
    real limit, not f x limit. The limit (W/m^2) is one value or a map (field.aim.limit_map); `target` as
    field.aim.optimise's."""
    def attempt(fraction: float) -> tuple[AimResult, float]:
        result = optimise(spots, start, fraction * limit_w_m2, region=region, steps=steps, seed=seed, target=target)
        peak = result.peak_over_limit * fraction  # over the real limit
        result = replace(result, peak_over_limit=peak, feasible=peak <= 1.0)
        return result, peak_quantile(spots, result.offsets, displacements, probability, limit_w_m2)

    result, bound = attempt(1.0)
    if bound <= 1.0:
        return result, bound, 1.0
    result, bound = attempt(LOWEST_FRACTION)
    kept = (result, bound, LOWEST_FRACTION)
    if bound > 1.0:
        return kept  # not even the lowest fraction keeps it: that one, reported as such
    low, high = LOWEST_FRACTION, 1.0
    for _ in range(BISECTIONS):
        middle = (low + high) / 2
        result, bound = attempt(middle)
        if bound <= 1.0:
            low, kept = middle, (result, bound, middle)
        else:
            high = middle
    return kept
