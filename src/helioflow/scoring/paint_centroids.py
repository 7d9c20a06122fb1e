"""Where the ideal heliostat's spot lands compared with the measured one, per PAINT image.

For every image of an imported PAINT dataset the ideal imported heliostat (no tracking, canting
or surface error) is traced for the measured sun position onto that image's target, aimed at the
target centre (where the calibration aims), and the flux-weighted centroids of the simulated and
the measured image are compared. The difference, in mrad as seen from the heliostat (offset on the
target / slant range heliostat -> target centre), is the real heliostat's pointing error at that
sun position if the conventions are right; a convention error (image flip, target orientation,
mount, sun azimuth sign) shows as offsets of the size of the spot's distance from the aim point
or as a spot ellipse turned the wrong way, which `spot_angle_deg` (major axis from the target's
right axis towards up, both spots) exposes. The ideal centroid equals the aim point to within
millimetres, so it does not test the sun convention; the spot shape does.
"""

from __future__ import annotations

import json
import os

import numpy as np
import torch

from helioflow.data.hdf5 import read_dataset
from helioflow.data.surfaces import read_heliostat
from helioflow.errors import DataError
from helioflow.io import write_text_atomic
from helioflow.physics.effects import resolve
from helioflow.physics.raytrace import trace
from helioflow.physics.target import Target

DEFAULT_SUNSHAPE = {"kind": "pillbox", "half_angle_mrad": 4.65}
SHAPE_THRESHOLD = 0.1  # spot moments use the pixels above this fraction of the image's peak
_EXTRAS = ("measurement_id", "target_name", "target_center_m", "target_normal", "target_size_m",
           "focal_spot_enu_m")


def centroid_check(dataset_path: str | os.PathLike, heliostat_path: str | os.PathLike,
                   sunshape: dict | None = None, cells_per_side: int = 16) -> list[dict]:
    """Per image: centroid offsets measured - ideal (mrad) and both spots' orientation.

    Args:
        dataset_path: a dataset from `import-paint` (needs the per-image target extras).
        heliostat_path: the imported heliostat's geometry (surfaces/{heliostat}.h5); its ideal
            version is traced.
        sunshape: the sun shape of the trace (effect parameters); default a 4.65 mrad pillbox.
        cells_per_side: surface cells per facet side of the kernel trace.

    Returns:
        One dict per image: id, target, azimuth_deg, elevation_deg, slant_m, the centroids (u
        right, v up, m in the target plane) of the ideal trace, the measured image and PAINT's
        UTIS centroid, the offsets image - ideal and UTIS - ideal along right/up and in total
        (mrad), and spot_angle_deg of the ideal and the measured spot.
    """
    ds = read_dataset(dataset_path)
    missing = [k for k in _EXTRAS if k not in ds.extras]
    if missing:
        raise DataError(f"{dataset_path}: missing extras {missing}; expected a dataset from "
                        "`helioflow import-paint`")
    ideal = read_heliostat(heliostat_path).ideal()
    physics = resolve({"sunshape": sunshape or DEFAULT_SUNSHAPE}, ideal, 1000.0)
    heliostat = physics.heliostat.to("cpu", torch.float64)
    e = ds.extras
    rows = []
    for i in range(len(ds.images)):
        width, height = (float(x) for x in e["target_size_m"][i])
        target = Target(torch.as_tensor(e["target_center_m"][i]), torch.as_tensor(e["target_normal"][i]),
                        width, height, tuple(ds.images.shape[1:]),
                        torch.as_tensor(e["aim_point_m"][i]) if "aim_point_m" in e else None)
        az, el = (torch.tensor([np.radians(a)], dtype=torch.float64)
                  for a in (ds.azimuth_deg[i], ds.elevation_deg[i]))
        with torch.no_grad():
            spot = trace(heliostat, target, az, el, physics.optics, rays=0, splat="kernel",
                          cells_per_side=cells_per_side)
        measured = torch.as_tensor(ds.images[i : i + 1], dtype=torch.float64)
        slant = float(np.linalg.norm(e["target_center_m"][i] - heliostat.position.numpy()))
        sim, meas = target.centroid(spot)[0].numpy(), target.centroid(measured)[0].numpy()
        utis = target.to_plane(torch.as_tensor(e["focal_spot_enu_m"][i])).numpy()
        rows.append({
            "id": str(e["measurement_id"][i]), "target": str(e["target_name"][i]),
            "azimuth_deg": float(ds.azimuth_deg[i]), "elevation_deg": float(ds.elevation_deg[i]),
            "slant_m": slant,
            "ideal_uv_m": sim.tolist(), "image_uv_m": meas.tolist(), "utis_uv_m": utis.tolist(),
            **_offsets("image", meas - sim, slant), **_offsets("utis", utis - sim, slant),
            "spot_angle_deg": {"ideal": spot_angle(spot[0], target),
                               "measured": spot_angle(measured[0], target)},
        })
    return rows


def _offsets(name: str, delta_m: np.ndarray, slant_m: float) -> dict:
    mrad = delta_m / slant_m * 1e3
    return {f"{name}_right_mrad": float(mrad[0]), f"{name}_up_mrad": float(mrad[1]),
            f"{name}_mrad": float(np.hypot(*mrad))}


def spot_angle(image: torch.Tensor, target: Target) -> float:
    """Angle (deg, in (-90, 90]) of the major axis of an (H, W) spot from the target's right
    axis towards up: second moments of the pixels above SHAPE_THRESHOLD of the peak."""
    u, v = target.pixel_centres(image.dtype, image.device)
    w = torch.where(image > SHAPE_THRESHOLD * image.max(), image, torch.zeros_like(image))
    total = w.sum()
    uu, vv = u[None, :].expand_as(w), v[:, None].expand_as(w)
    mu, mv = (w * uu).sum() / total, (w * vv).sum() / total
    cuu = (w * (uu - mu) ** 2).sum() / total
    cvv = (w * (vv - mv) ** 2).sum() / total
    cuv = (w * (uu - mu) * (vv - mv)).sum() / total
    return float(torch.rad2deg(0.5 * torch.atan2(2 * cuv, cuu - cvv)))


def format_table(rows: list[dict]) -> str:
    """The per-image offsets as a fixed-width text table (mrad, deg)."""
    header = (f"{'id':>8} {'target':>26} {'az':>7} {'el':>6} {'slant':>6} {'right':>7} {'up':>7} {'total':>6}"
              f" {'utis':>6} {'angle ideal/meas':>17}")
    lines = [header]
    for r in rows:
        a = r["spot_angle_deg"]
        lines.append(f"{r['id']:>8} {r['target']:>26} {r['azimuth_deg']:7.1f} {r['elevation_deg']:6.1f}"
                     f" {r['slant_m']:6.1f} {r['image_right_mrad']:7.2f} {r['image_up_mrad']:7.2f}"
                     f" {r['image_mrad']:6.2f} {r['utis_mrad']:6.2f} {a['ideal']:8.1f}/{a['measured']:6.1f}")
    return "\n".join(lines)


def write_centroid_check(rows: list[dict], path: str | os.PathLike) -> None:
    """Write the rows as JSON (temporary name, then renamed)."""
    units = {"offsets": "mrad", "uv": "m", "angles": "deg"}
    write_text_atomic(path, json.dumps({"units": units, "images": rows}, indent=2))
