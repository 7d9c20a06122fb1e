"""Where a residual lives, so that a user can guess the physics behind it: against the sun
position, in the image, and on the mirror.

- **Sun position**: each image's error over its noise floor (diagnosis/noise.py), averaged over
  thirds of the images by sun elevation and by azimuth.
- **Image**: the flux the measurement has more (+) or less (-) than the model, each image divided
  by its own sum, in the spot's halves about the model's centroid (above / below, right / left)
  and in its core (model above CORE_FRACTION of its peak) and halo.
- **Mirror**: the model traced one mirror region at a time (each facet cut into `regions` x
  `regions` parts); the light each region sends is re-weighted (bounded least squares, weights
  drawn towards 1) until the sum of the regions' images matches the measurements: first the
  parts of the facets (upper left ... lower right, the same part of every facet together), then
  the facets. A weight below 1 is a part that sends less light than the model says (shaded,
  blocked, soiled, or aimed where the measurement has none), above 1 one that sends more,
  relative to the median part (a common factor is a scale, which shapes cannot tell). Solved for
  the images that carry the residual (over the explained level of noise) and for the others
  separately: shading and blocking come and go with the sun.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
from scipy.optimize import lsq_linear
from torch import Tensor

from helioflow.physics.scene import Scene

CORE_FRACTION = 0.05
REGIONS = 3  # each facet cut into 3 x 3 regions (upper / middle / lower, left / centre / right)
WEIGHT_BOUNDS = (0.0, 3.0)
RIDGE = 1e-3  # weights drawn towards 1 by this fraction of the design matrix's mean squared column
OFF = 0.05  # a part whose weight departs from 1 by more than this is named (the NAMED that depart most)
NAMED = 3
ROW_WORDS, COL_WORDS = ("upper", "middle", "lower"), ("left", "centre", "right")


def by_sun_position(azimuth_deg: np.ndarray, elevation_deg: np.ndarray, over_noise: np.ndarray) -> dict:
    """Error over noise (N,) per image, averaged over thirds of the images by elevation and by
    azimuth: {"elevation_deg": [...], "azimuth_deg": [...]}, each part {range, images, over_noise},
    and `where`: the third of each that carries most, in words."""
    out: dict[str, Any] = {}
    words = []
    for name, angle in (("elevation_deg", elevation_deg), ("azimuth_deg", azimuth_deg)):
        parts: list[dict[str, Any]] = []
        for index in np.array_split(np.argsort(angle), min(3, len(angle))):
            parts.append({"range": [round(float(angle[index].min()), 2), round(float(angle[index].max()), 2)],
                          "images": len(index), "over_noise": round(float(over_noise[index].mean()), 3)})
        out[name] = parts
        worst = max(parts, key=lambda p: p["over_noise"])
        least = min(p["over_noise"] for p in parts)
        words.append(f"{worst['over_noise']:.1f} times the noise at sun {name.split('_')[0]} "
                     f"{worst['range'][0]:.0f} to {worst['range'][1]:.0f} deg "
                     f"({least:.1f} times in the least affected third)")
    out["where"] = " and ".join(words)
    return out


def in_image(scene: Scene, model: Tensor, measured: Tensor) -> dict:
    """Flux the measurements have more (+) or less (-) than the model (fractions of each image's
    flux, mean over images) above and below the model's centroid, right and left of it, in the
    model's core and halo; `where`: the largest, in words. model, measured: (N, H, W)."""
    p = model.double() / model.double().sum((-2, -1), keepdim=True).clamp_min(1e-30)
    m = measured.double() / measured.double().sum((-2, -1), keepdim=True).clamp_min(1e-30)
    r = m - p
    u, v = scene.target.pixel_centres(torch.float64)
    c = scene.target.centroid(p)
    above = v[None, :, None] > c[:, 1, None, None]
    right = u[None, None, :] > c[:, 0, None, None]
    core = p >= CORE_FRACTION * p.amax((-2, -1), keepdim=True)
    sides = {"above": above, "below": ~above, "right": right, "left": ~right, "core": core, "halo": ~core}
    out: dict[str, Any] = {k: round(float((r * mask).sum((-2, -1)).mean()), 4) for k, mask in sides.items()}
    gains, losses = max(out, key=lambda k: out[k]), min(out, key=lambda k: out[k])
    place = {"above": "above the spot's centre", "below": "below the spot's centre", "right": "right of the centre",
             "left": "left of the centre", "core": "in the spot's core", "halo": "in its halo"}
    out["where"] = (f"the measured spots hold {out[gains]:.1%} of their flux {place[gains]} that the model puts "
                    f"{place[losses]}" if out[gains] > 0 else "the measured spots hold their flux where the model does")
    return out


def on_mirror(scene: Scene, effects: dict, tensors: dict, azimuth_deg: Tensor, elevation_deg: Tensor,
              measured: Tensor, affected: np.ndarray, regions: int = REGIONS) -> dict:
    """The light each mirror region sends relative to the model (module doc), over the images that
    carry the residual (`affected`, (N,) bool; all images when none does) and over the others.
    measured: (N, H, W); sun positions (N,) deg.

    The weights are separable: a region's weight is its place's (`pattern`: the same `regions` x
    `regions` parts of every facet, row from the top) times its facet's (`facets`). Canted facets
    aim their images at one spot, so the facets' own weights are determined only as far as their
    images differ (often little), while the part of a facet shows in where its light lands.

    Returns {"regions": [{facet, row, column, right_m, up_m, width_m, height_m}] (facet-major),
    "pattern", "facets", "weight" (the regions': pattern x facet), each {"affected", "others"},
    "affected_images", "where": in words}."""
    h = scene.heliostat
    cells = scene.cells_per_side
    band = torch.arange(cells) * regions // cells  # region row / column of each cell row / column
    place = (band[:, None] * regions + band[None, :]).to(h.facet_size.device)  # (cells, cells) part of a facet

    def weight_of(values: Tensor) -> Tensor:
        return values.to(h.facet_size.dtype).flatten()

    def light(weight: Tensor, index: Tensor) -> Tensor:
        """(n, H, W) the light of the weighted points at the images `index`, the camera's background off."""
        with torch.no_grad():
            image = scene.simulate(effects, tensors, azimuth_deg[index], elevation_deg[index], mirror_weight=weight)
        return image.double().cpu() - background[index.cpu()]

    every = torch.arange(len(measured), device=azimuth_deg.device)
    with torch.no_grad():
        background = scene.simulate(effects, tensors, azimuth_deg, elevation_deg,
                                    mirror_weight=weight_of(torch.zeros(h.n_facets, cells, cells))).double().cpu()
    parts = torch.stack([light(weight_of((place == k).expand(h.n_facets, -1, -1)), every)
                         for k in range(regions * regions)], 1)  # (N, R * R, H, W): each part of every facet
    total = (parts.sum(1) + background).sum((-2, -1)).clamp_min(1e-30)[:, None, None]  # (N, 1, 1) the model's sum
    meas = measured.double().cpu()
    meas = meas / meas.sum((-2, -1), keepdim=True).clamp_min(1e-30) - background / total  # the light to place
    affected = np.asarray(affected, bool)
    layout = [_region(h, f, i, j, regions) for f in range(h.n_facets) for i in range(regions) for j in range(regions)]
    out: dict[str, Any] = {"regions": layout, "pattern": {}, "facets": {}, "weight": {},
                           "affected_images": int(affected.sum())}
    if not affected.any():
        affected = np.ones(len(meas), bool)
    for name, select in (("affected", affected), ("others", ~affected)):
        pattern, facets = np.ones(regions * regions), np.ones(h.n_facets)
        chosen = np.flatnonzero(select)
        if len(chosen):
            index = torch.as_tensor(chosen)
            b = meas[index].reshape(-1).numpy()
            shares = (parts[index] / total[index, None]).movedim(1, -1).reshape(-1, regions * regions)
            pattern = _weights(shares.numpy(), b)
            placed = torch.as_tensor(pattern, dtype=h.facet_size.dtype, device=place.device)[place]  # (cells, cells)
            by_facet = []
            for f in range(h.n_facets):  # each facet, its parts weighted as found
                mask = torch.zeros(h.n_facets, cells, cells, dtype=h.facet_size.dtype, device=place.device)
                mask[f] = placed
                by_facet.append(light(weight_of(mask), index.to(azimuth_deg.device)) / total[index])
            facets = _weights(torch.stack(by_facet, -1).reshape(-1, h.n_facets).numpy(), b)
        out["pattern"][name] = np.round(pattern, 3).tolist()
        out["facets"][name] = np.round(facets, 3).tolist()
        out["weight"][name] = np.round(np.outer(facets, pattern).flatten(), 3).tolist()
    out["where"] = _mirror_words(layout[: regions * regions], out)
    return out


def _region(h, facet: int, row: int, col: int, regions: int) -> dict:
    """Where region (row, col) of `facet` lies on the mirror (heliostat frame, m)."""
    width, height = (float(x) for x in h.facet_size[facet])
    centre = h.facet_translation[facet].tolist()
    return {"facet": facet + 1, "row": ROW_WORDS[row * 3 // regions], "column": COL_WORDS[col * 3 // regions],
            "right_m": round(centre[0] + (col + 0.5 - regions / 2) * width / regions, 4),
            "up_m": round(centre[1] - (row + 0.5 - regions / 2) * height / regions, 4),
            "width_m": round(width / regions, 4), "height_m": round(height / regions, 4)}


def _weights(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(K,) weights w in WEIGHT_BOUNDS minimising |a w - b|^2 + ridge |w - 1|^2, over their median
    (their mean when most are near 0)."""
    k = a.shape[1]
    ridge = np.sqrt(RIDGE * (a**2).sum(0).mean())
    w = lsq_linear(np.vstack((a, ridge * np.eye(k))), np.concatenate((b, ridge * np.ones(k))), bounds=WEIGHT_BOUNDS).x
    typical = float(np.median(w))
    return w / (typical if typical > 0.1 * w.max() else max(float(w.mean()), 1e-9))


def _mirror_words(places: list[dict], out: dict) -> str:
    """The parts of the facets (and the facets) that depart most from the model in the images that
    carry the residual, in words."""
    pattern, facets = np.asarray(out["pattern"]["affected"]), np.asarray(out["facets"]["affected"])
    named = []
    for group, words in (("row", ROW_WORDS), ("column", COL_WORDS)):
        for word in words:
            w = float(np.mean([pattern[k] for k, p in enumerate(places) if p[group] == word]))
            if abs(w - 1.0) > OFF:
                part = "third" if group == "row" else "column"
                named.append((abs(w - 1.0),
                              f"the {word} {part} of every facet sends {w:.2f} times the light the model says"))
    named += [(abs(w - 1.0), f"facet {f + 1} sends {w:.2f} times the light the model says")
              for f, w in enumerate(facets) if abs(w - 1.0) > OFF]
    n = out["affected_images"]
    images = f"in the {n} images that carry the residual" if n else "over all images (none carries a residual)"
    if not named:
        return f"{images}, no part of the mirror sends light more than {OFF:.0%} off the model's"
    return f"{images}, relative to the median part, " + "; ".join(t for _, t in sorted(named, reverse=True)[:NAMED])
