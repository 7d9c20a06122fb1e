"""The next calibration images to take: candidate sun positions ranked by how much each would shrink
the fitted model's uncertainty (models/uncertainty.py).

A new image j adds the information F_j = J_j^T diag(1 / s_j^2) J_j about the parameters (J_j: its
Jacobian as the fit compares it, s_j: its pixels' noise at the predicted level, from the noise
model measured in the calibration images). With the current covariance C = L L^T, the covariance
after it is

    C' = L (I + L^T F_j L)^-1 L^T

(only the directions the fit has: a direction with no variance stays so). Images are picked
greedily, one at a time, each by one of three criteria:

- "d_optimal": the largest log det(I + L^T F_j L), the expected information gain (the volume of
  the uncertainty ellipsoid shrinks most);
- targeted at named parameters ("targets"): the smallest sum of their variances after it;
- targeted at a confounded pair of effects ("pair"): the smallest canonical correlation between
  their parameters after it (what separates them);
- targeted at predictions ("predictions"; I-optimal): the smallest sum of the variances, after it,
  of predicted quantities q = G theta to first order (G: their Jacobian by the parameters), by
  default the spot centroids (right, up) at the sun positions to come: what a prediction there will
  be off by. "targets" is the case G = rows of the identity.

Candidates: a list of sun positions, or the site's sun path over the next days (`sun_path`), at
the times the sun stands at least `min_elevation_deg` high (the heliostat can then put its spot on
the target at any azimuth: helioflow's kinematics have no travel limits).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from datetime import datetime, timedelta
from typing import TYPE_CHECKING, cast

import numpy as np
import torch
from torch import Tensor

from helioflow.models.uncertainty import (
    FitUncertainty,
    _State,
    compared_jacobian,
    end_state,
    parameters,
    predicted_spread,
)

if TYPE_CHECKING:
    from helioflow.models.physical import RaytraceModel

CRITERIA = ("d_optimal", "targets", "pair", "predictions")
CHUNK = 16  # candidate images whose Jacobian is built at once (memory: CHUNK x pixels x parameters)


@dataclass(frozen=True)
class Pick:
    """One recommended image: its candidate index, the criterion's gain and the sigma of every
    parameter once it (and the picks before it) are taken."""

    index: int
    gain: float
    sigma_after: np.ndarray


def image_information(state: _State, fitted: list[tuple[str, str]], masks: dict[str, Tensor],
                      uncertainty: FitUncertainty) -> Tensor:
    """(M, P, P) the information each of the M images at `state`'s sun positions adds about the
    parameters of the fit's `uncertainty`, as the fit compares images, with the noise read in its
    residual (times the misfit where the residual is larger: the covariance's own scale), at least
    uncertainty.NOISE_FLOOR of the peak: no image is worth infinitely much."""
    names, noise = uncertainty.names, uncertainty.noise
    if noise is None:
        raise ValueError("the uncertainty holds no noise model (a model file written before it): nothing to weigh "
                         "new images with")
    scale = max(1.0, uncertainty.misfit)  # the covariance's own noise: the residual's, where it exceeds the noise
    out = []
    for start in range(0, len(state.azimuth_deg), CHUNK):
        at = slice(start, start + CHUNK)
        chunk = state.at(state.azimuth_deg[at], state.elevation_deg[at])
        params = parameters(chunk, fitted, masks)
        if [p.name for p in params] != names:
            raise ValueError("the uncertainty was computed for other parameters than this fit's")
        columns, std, _ = compared_jacobian(chunk, params, noise)
        weighted = (columns.double() / std.clamp_min(1e-30)[:, None]).reshape(len(chunk.azimuth_deg), -1, len(params))
        out.append(torch.einsum("npi,npj->nij", weighted, weighted) / scale)
    return torch.cat(out)


def plan(information: Tensor, uncertainty: FitUncertainty, count: int, criterion: str = "d_optimal",
         targets: list[str] | None = None, pair: tuple[str, str] | None = None,
         predictions: Tensor | None = None) -> list[Pick]:
    """The `count` best images among the candidates, picked greedily (module docstring).

    Args:
        information: (M, P, P) from `image_information`.
        uncertainty: the fit's covariance now.
        criterion: one of CRITERIA.
        targets: parameter names (or name prefixes, e.g. "tracking.") for "targets".
        pair: two effect names for "pair".
        predictions: (Q, P) for "predictions": the Jacobian of Q predicted quantities by the P
            parameters (e.g. centroids in mrad per parameter unit: uncertainty.predicted_spread).
    """
    if criterion not in CRITERIA:
        raise ValueError(f"criterion {criterion!r}: expected one of {', '.join(CRITERIA)}")
    values, vectors = np.linalg.eigh(uncertainty.covariance)
    keep = values > 1e-12 * max(values.max(), 1e-300)
    root = torch.as_tensor(vectors[:, keep] * np.sqrt(values[keep]))  # (P, r): C = root root^T
    chosen: list[Pick] = []
    for _ in range(min(count, len(information))):
        g = root.T @ information @ root  # (M, r, r)
        eye = torch.eye(g.shape[-1], dtype=g.dtype)
        shrink = torch.linalg.inv(eye + g)  # (M, r, r): C after = root shrink root^T
        score = _score(criterion, g, root, shrink, uncertainty.names, targets, pair, predictions)
        for pick in chosen:
            score[pick.index] = -np.inf
        best = int(torch.argmax(score))
        root = root @ torch.linalg.cholesky(shrink[best])
        chosen.append(Pick(best, float(score[best]), root.pow(2).sum(1).sqrt().numpy()))
    return chosen


def _score(criterion: str, g: Tensor, root: Tensor, shrink: Tensor, names: list[str], targets, pair,
           predictions) -> Tensor:
    """(M,) each candidate's worth under `criterion`, larger is better."""
    if criterion == "d_optimal":
        return torch.linalg.slogdet(torch.eye(g.shape[-1], dtype=g.dtype) + g)[1]
    if criterion in ("targets", "predictions"):  # the summed variance after it of q = G theta (targets: G's
        if criterion == "targets":                # rows those of the identity at the named parameters)
            at = [k for k, n in enumerate(names) if any(n == t or n.startswith(t) for t in targets or ())]
            if not at:
                raise ValueError(f"targets {targets}: none of the fit's parameters ({', '.join(names[:6])}, ...)")
            rows = root[at]  # (Q, r)
        elif predictions is None or predictions.shape[-1] != root.shape[0]:
            raise ValueError(f"predictions: a (Q, {root.shape[0]}) Jacobian of the predicted quantities is needed")
        else:
            rows = predictions.to(root) @ root  # (Q, r)
        return -torch.einsum("qi,mij,qj->m", rows, shrink, rows)
    a, b = ([k for k, n in enumerate(names) if n.startswith(e + ".")] for e in pair or ("", ""))
    if not a or not b:
        raise ValueError(f"pair {pair}: both effects must have fitted parameters")
    sub = root[a + b]
    after = (sub @ shrink @ sub.T).numpy()  # (M, |a| + |b|, |a| + |b|)
    first, second = list(range(len(a))), list(range(len(a), len(a) + len(b)))
    return -torch.tensor([canonical_correlation(c, first, second) for c in after], dtype=torch.float64)


def canonical_correlation(covariance: np.ndarray, a: list[int], b: list[int]) -> float:
    """The largest correlation between any combination of the parameters `a` and any of `b` (the
    first canonical correlation): near 1, the images cannot tell the two groups apart."""
    caa, cbb, cab = covariance[np.ix_(a, a)], covariance[np.ix_(b, b)], covariance[np.ix_(a, b)]
    m = np.linalg.pinv(caa) @ cab @ np.linalg.pinv(cbb) @ cab.T
    return float(np.sqrt(np.clip(np.linalg.eigvals(m).real.max(initial=0.0), 0.0, 1.0)))


def sun_path(site: dict, start: datetime, days: float, every_minutes: float,
             min_elevation_deg: float) -> tuple[list[datetime], np.ndarray, np.ndarray]:
    """(times, azimuth (deg, 0 = south, +90 = east), elevation (deg)) of the sun at `site`
    ({latitude_deg, longitude_deg, altitude_m}) every `every_minutes` from `start` (UTC) for
    `days`, where it stands at least `min_elevation_deg` high."""
    from helioflow.data.images import sun_position

    steps = int(days * 24 * 60 / every_minutes)
    times = [start + timedelta(minutes=every_minutes * i) for i in range(steps)]
    azimuth, elevation = sun_position(times, site)
    up = elevation >= min_elevation_deg
    return [t for t, u in zip(times, up) if u], azimuth[up], elevation[up]


def plan_measurements(model_path, dataset_path, settings: dict, output=None, device: str = "cpu") -> dict:
    """Rule `plan_measurements` / `helioflow plan-measurements`: the next `settings["images"]`
    calibration images for a fitted physics model (drt or raytrace) of a dataset, written to
    `output` as JSON (the dict is returned).

    settings: images, criterion (CRITERIA), targets (for "targets"), pair (for "pair"), predict_at
    [[azimuth_deg, elevation_deg], ...] (for "predictions"; default: the candidates), and the
    candidates: `sun` [[azimuth_deg, elevation_deg], ...], or the sun path: site {latitude_deg,
    longitude_deg, altitude_m} (default: the dataset's own), start (ISO 8601, UTC), days,
    every_minutes, min_elevation_deg: config `plan`'s keys, the schema's defaults where unset.
    """
    from helioflow.data.hdf5 import read_dataset
    from helioflow.errors import DataError
    from helioflow.io import write_text_atomic
    from helioflow.models.physics_fit import initial_tensors
    from helioflow.models.registry import load_model
    from helioflow.schema import with_defaults

    settings = with_defaults(settings, "plan")  # a spec written by hand may leave them out
    model, info = load_model(model_path, device)
    fit = getattr(model, "fitted", None)
    if fit is None or fit.uncertainty is None or not fit.uncertainty.names:
        raise DataError(f"{model_path}: a {info['network']} model without fitted parameters and their uncertainty "
                        "(a physics model - raytrace or drt - trained by this version of helioflow) has nothing to "
                        "plan for")
    model = cast("RaytraceModel", model)  # a physics model: it has a fit and its uncertainty
    ds = read_dataset(dataset_path)
    times, azimuth, elevation, source = _candidates(settings, ds.attrs, dataset_path)
    scene = model.scene()
    _, masks = initial_tensors(fit.effects, scene.heliostat)
    loss = "shape" if model.config.per_image_normalised else "absolute"
    az, el = (torch.as_tensor(a, dtype=torch.float32, device=model.device) for a in (azimuth, elevation))
    state = end_state(scene, fit, az, el, model.scale, loss, masks)
    information = image_information(state, fit.fitted, masks, fit.uncertainty)
    pair = tuple(settings["pair"]) if settings.get("pair") else None
    criterion = settings["criterion"]
    predictions = None
    if criterion == "predictions":  # the centroids at `predict_at`, or at the candidates themselves
        at = np.asarray(settings["predict_at"], dtype=float).reshape(-1, 2) if settings.get("predict_at") else \
            np.stack((azimuth, elevation), -1)
        where_az, where_el = (torch.as_tensor(at[:, i], dtype=torch.float32, device=model.device) for i in (0, 1))
        spread = predicted_spread(end_state(scene, fit, where_az, where_el, model.scale, loss, masks), fit.fitted,
                                  masks, fit.uncertainty)
        predictions = spread["centroid_jacobian"].flatten(0, 1)
    picks = plan(information, fit.uncertainty, int(settings["images"]), criterion, settings.get("targets"),
                 pair, predictions)
    names = fit.uncertainty.names
    result = {
        "dataset": ds.attrs.get("dataset", str(dataset_path)), "model": info["network"],
        "criterion": criterion, "targets": settings.get("targets"), "pair": pair,
        "predict_at": (None if criterion != "predictions" else
                       "the candidates" if not settings.get("predict_at") else settings["predict_at"]),
        "candidates": {"count": len(azimuth), "source": source},
        "sigma_now": summary(names, fit.uncertainty.sigma),
        "next": [{"rank": k + 1, "time": None if times is None else times[p.index].isoformat(),
                  "azimuth_deg": round(float(azimuth[p.index]), 3),
                  "elevation_deg": round(float(elevation[p.index]), 3),
                  "gain": round(p.gain, 5), "sigma_after": summary(names, p.sigma_after)} for k, p in enumerate(picks)],
    }
    if output is not None:
        write_text_atomic(output, json.dumps(result, indent=1) + "\n")
    return result


def summary(names: list[str], sigma: np.ndarray) -> dict:
    """{scalar name: sigma, tensor name: RMS sigma of its entries} (their units)."""
    out: dict = {}
    groups: dict[str, list[float]] = {}
    for name, s in zip(names, sigma):
        if "[" in name:
            groups.setdefault(name.split("[")[0], []).append(float(s))
        else:
            out[name] = float(f"{s:.4g}")
    out.update({f"{k} (rms)": float(f"{np.sqrt(np.mean(np.square(v))):.4g}") for k, v in groups.items()})
    return out


def _candidates(settings: dict, attrs: dict, dataset_path) -> tuple[list | None, np.ndarray, np.ndarray, str]:
    """(times or None, azimuth, elevation, a description) of the candidate sun positions."""
    from helioflow.errors import ConfigError

    if settings.get("sun"):
        sun = np.asarray(settings["sun"], dtype=float).reshape(-1, 2)
        return None, sun[:, 0], sun[:, 1], f"{len(sun)} given sun positions"
    site = settings.get("site") or attrs.get("site")
    if not site:
        raise ConfigError(f"plan: {dataset_path} records no site: give plan.site {{latitude_deg, longitude_deg, "
                          f"altitude_m}} or plan.sun [[azimuth_deg, elevation_deg], ...]")
    start = datetime.fromisoformat(str(settings.get("start")).replace("Z", "+00:00"))
    days, every, low = float(settings["days"]), float(settings["every_minutes"]), float(settings["min_elevation_deg"])
    times, azimuth, elevation = sun_path(site, start, days, every, low)
    if not times:
        raise ConfigError(f"plan: the sun stands below {low} deg at every time of the {days} days from {start}")
    return times, azimuth, elevation, (f"the sun path at {site['latitude_deg']:.4f} N, {site['longitude_deg']:.4f} E "
                                       f"from {start.isoformat()} for {days:g} days every {every:g} min, "
                                       f"above {low:g} deg")
