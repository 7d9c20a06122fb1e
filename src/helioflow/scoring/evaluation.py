"""The `evaluate` rule: score one trained model against every image of one dataset.

Scoring (see :mod:`helioflow.scoring.metrics`): the model's normalised prediction is turned
back into flux with the model's scale (the maximum of its training images), then predicted and
measured images are BOTH divided by the maximum of the measured dataset (all splits, one scale
for the dataset), so intensity errors count. Metrics are computed per image and averaged per
split (train, interpolation, extrapolation).

A model that cannot be steered by the sun position (``controllable == False``, the
unconditioned GAN) draws a fixed set of samples once; each measured image is scored against the
sample with the best PSNR. That is an optimistic upper bound on what such a model can offer,
and the JSON says so (``"controllable": false``, ``"note"``).
"""

from __future__ import annotations

import csv
import io
import json
import logging
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from helioflow.data.hdf5 import SPLITS, CalibrationDataset, read_dataset
from helioflow.errors import DataError
from helioflow.io import write_text_atomic
from helioflow.models.registry import load_model
from helioflow.plotting import plt, save_figure
from helioflow.scoring.metrics import METRICS, PSNR_MAX_DB, image_metrics, psnr

log = logging.getLogger(__name__)

CSV_COLUMNS = ("index", "azimuth_deg", "elevation_deg", "split", *METRICS)
SPLIT_COLOURS = {"train": "tab:blue", "interpolation": "tab:green", "extrapolation": "tab:red"}
_BATCH = 256  # sun positions per predict() call


def _geometry(ds: CalibrationDataset, dataset_path) -> tuple[tuple[float, float], float]:
    """((pixel height, pixel width) on the target in m, slant range heliostat -> target centre in m)."""
    missing = [k for k in ("target_size_m", "target_center_m", "heliostat_position_m") if k not in ds.attrs]
    if missing:
        raise DataError(f"{dataset_path}: missing attribute(s) {', '.join(missing)}; "
                        "needed for the centroid error in mrad")
    width, height = (float(v) for v in ds.attrs["target_size_m"])
    rows, cols = ds.images.shape[1:]
    slant = float(np.linalg.norm(np.subtract(ds.attrs["target_center_m"], ds.attrs["heliostat_position_m"])))
    if not slant > 0:
        raise DataError(f"{dataset_path}: target_center_m equals heliostat_position_m; slant range is 0")
    return (height / rows, width / cols), slant


def _predict_all(model, ds: CalibrationDataset, gan_samples: int, seed: int) -> np.ndarray:
    """Normalised model output: (N, H, W) predictions at every dataset image's sun position for a
    controllable model, (gan_samples, H, W) samples for an unconditioned one."""
    generator = torch.Generator().manual_seed(seed)
    n = len(ds.images)
    with torch.no_grad():
        if model.controllable:
            az = torch.as_tensor(ds.azimuth_deg, dtype=torch.float32)
            el = torch.as_tensor(ds.elevation_deg, dtype=torch.float32)
            pred = np.concatenate([model.predict(az[i:i + _BATCH], el[i:i + _BATCH], generator).cpu().numpy()
                                   for i in range(0, n, _BATCH)]) if n else np.zeros((0, *ds.images.shape[1:]))
            return pred.astype(np.float32, copy=False)
        if gan_samples < 1:
            raise DataError(f"gan_samples = {gan_samples}: need at least one sample to score an unconditioned model")
        # positions are ignored by an unconditioned model; any valid ones will do
        samples = model.predict(torch.zeros(gan_samples), torch.full((gan_samples,), 45.0), generator)
    return samples.cpu().numpy().astype(np.float32, copy=False)


def scored_images(model, info: dict, ds: CalibrationDataset, model_path, dataset_path, gan_samples: int = 64,
                  seed: int = 0) -> tuple[np.ndarray, np.ndarray, float]:
    """(predicted, measured, dataset maximum): the model's images at every dataset image's sun
    position (an unconditioned model: its best sample per image) and the measured ones, (N, H, W)
    each, both divided by the dataset's maximum (W/m^2) - what the metrics compare (module
    docstring). `info`: the model file's metadata (``load_model``); the paths name the files in errors.

    Raises:
        DataError: an all-zero dataset, or a model whose image shape or output differs from the dataset's.
    """
    network, shape = info["network"], tuple(ds.images.shape[1:])
    model_shape = tuple(int(s) for s in getattr(model, "image_shape", info.get("image_shape", shape)))
    if model_shape != shape:
        raise DataError(f"{model_path}: the {network} model predicts {model_shape[0]}x{model_shape[1]} images, "
                        f"but {dataset_path} holds {shape[0]}x{shape[1]} images; train it on this dataset's resolution")
    dataset_max = float(ds.images.max()) if ds.images.size else 0.0
    if not dataset_max > 0:
        raise DataError(f"{dataset_path}: every image is zero; there is no flux scale to compare against")
    meas = ds.images / dataset_max
    raw = _predict_all(model, ds, gan_samples, seed)
    expected = len(meas) if model.controllable else gan_samples
    if raw.shape != (expected, *shape):
        raise DataError(f"{model_path}: the {network} model returned an array of shape {raw.shape}, "
                        f"expected {(expected, *shape)}")
    raw = raw * (float(info["scale"]) / dataset_max)
    return (raw if model.controllable else raw[_best_samples(raw, meas)]), meas, dataset_max


def _best_samples(samples: np.ndarray, meas: np.ndarray) -> np.ndarray:
    """(N,) index of the sample (S, H, W) with the best PSNR against each measured image (N, H, W)."""
    return np.array([int(np.argmax(psnr(samples, np.broadcast_to(m, samples.shape)))) for m in meas], dtype=int)


def _mean(values: np.ndarray) -> float | None:
    finite = values[np.isfinite(values)]
    return float(finite.mean()) if len(finite) else None


@dataclass
class Evaluation:
    """A model scored on a dataset (`evaluate`): `result` is the metrics JSON's dict
    (`evaluate_model`'s out_json), `per_image` the (N,) metrics of every image (METRICS), `predicted`
    and `measured` the (N, H, W) images as compared (divided by the dataset's maximum)."""

    result: dict
    dataset: CalibrationDataset
    per_image: dict[str, np.ndarray]
    predicted: np.ndarray
    measured: np.ndarray
    title: str


def evaluate(model_path: str | os.PathLike, dataset_path: str | os.PathLike, gan_samples: int = 64, seed: int = 0,
             device: str = "cpu") -> Evaluation:
    """Score a model file on a dataset file (arguments and errors: `evaluate_model`); writes nothing."""
    model, info = load_model(model_path, device)
    ds = read_dataset(dataset_path)
    network = info["network"]
    name = str(ds.attrs.get("dataset", Path(dataset_path).stem))
    pixel_m, slant_m = _geometry(ds, dataset_path)
    pred, meas, dataset_max = scored_images(model, info, ds, model_path, dataset_path, gan_samples, seed)
    per_image = {k: np.asarray(v) for k, v in image_metrics(pred, meas, pixel_m, slant_m).items()}  # (N,) each

    if model.controllable:
        scoring = "prediction at each image's sun position"
    else:
        scoring = f"best of {gan_samples} samples by PSNR per image"
    result: dict = {"network": network, "dataset": name, "controllable": bool(model.controllable), "splits": {}}
    for split in SPLITS:
        idx = ds.indices(split)
        entry = {key: (_mean(per_image[key][idx]) if len(idx) else None) for key in METRICS}
        entry["n"] = len(idx)
        result["splits"][split] = entry
    result.update({
        "model": str(model_path),
        "scoring": f"{scoring}; predicted and measured images divided by the dataset's maximum "
                   f"({dataset_max:.6g} W/m^2); PSNR with data range 1, capped at {PSNR_MAX_DB:g} dB; "
                   "SSIM (scikit-image, data range 1); centroid error in mrad seen from the heliostat; "
                   "flux accuracy 1 - sum|pred - meas| / sum|meas|; means over each split's images",
        "psnr_max_db": PSNR_MAX_DB,
        "dataset_max_w_m2": dataset_max,
        "model_scale_w_m2": float(info["scale"]),
    })
    if not model.controllable:
        result["samples"] = int(gan_samples)
        result["note"] = (f"the {network} network is not conditioned on the sun position, so it cannot predict the "
                          f"spot for a given one; {gan_samples} samples were drawn once (seed {seed}) and each "
                          "measured image is scored against the sample with the best PSNR - an optimistic upper "
                          "bound, not a prediction")
        log.info("%s is not controllable: scored as best of %d samples", network, gan_samples)
    title = f"{network} on {name}" + ("" if model.controllable else f" (best of {gan_samples} samples)")
    return Evaluation(result, ds, per_image, pred, meas, title)


def write_evaluation(evaluation: Evaluation, out_json, out_csv, out_grid_png, out_psnr_png) -> None:
    """Write an `evaluate` result: the metrics JSON, the per-image CSV and the two figures
    (`evaluate_model`'s outputs)."""
    e = evaluation
    write_text_atomic(out_json, json.dumps(e.result, indent=2, allow_nan=False) + "\n")
    _write_csv(out_csv, e.dataset, e.per_image)
    plot_prediction_grid(e.dataset, e.measured, e.predicted, e.per_image["psnr"], e.title, out_grid_png)
    plot_psnr_vs_sun(e.dataset, e.per_image["psnr"], e.title, out_psnr_png)
    for split in SPLITS:
        s = e.result["splits"][split]
        if s["n"]:
            log.info("%s %s: n=%d PSNR %.2f dB, SSIM %.3f", e.title, split, s["n"], s["psnr"], s["ssim"])


def evaluate_model(model_path: str | os.PathLike, dataset_path: str | os.PathLike, out_json, out_csv,
                   out_grid_png, out_psnr_png, gan_samples: int = 64, seed: int = 0, device: str = "cpu") -> dict:
    """Rule `evaluate`: score a model file on a dataset file (`evaluate`), then write the metrics
    JSON, the per-image CSV and two figures (`write_evaluation`).

    Args:
        model_path: a file written by :func:`helioflow.models.registry.train_network`.
        dataset_path: a calibration dataset (``helioflow.dataset/1``) with the attributes
            ``target_size_m`` [w, h], ``target_center_m`` and ``heliostat_position_m``.
        out_json: {"network", "dataset", "controllable", "splits": {split: {"psnr" (dB),
            "ssim", "centroid_mrad", "flux_accuracy", "n"}}, plus "model", "scoring",
            "psnr_max_db", "dataset_max_w_m2", "model_scale_w_m2" and, for an unconditioned
            model, "samples" and "note"}. Split values are means over the split's images
            (centroid and flux accuracy over images where they are defined); a split without
            images has n = 0 and null metrics.
        out_csv: one row per dataset image: index, azimuth_deg, elevation_deg, split, psnr,
            ssim, centroid_mrad, flux_accuracy.
        out_grid_png: measured / predicted / difference images over a spread of sun positions
            from the interpolation and extrapolation splits (the train split if both are empty).
        out_psnr_png: PSNR against sun azimuth and elevation, coloured by split.
        gan_samples: samples drawn once (seeded) for a model with ``controllable == False``.
        seed: seed of the generator handed to ``model.predict``.
        device: where the model predicts (cpu | cuda | auto); the metrics are computed on the CPU.
    Returns:
        the JSON's dict.
    Raises:
        DataError: unreadable files, missing attributes, or a model whose image shape differs
            from the dataset's.
    """
    evaluation = evaluate(model_path, dataset_path, gan_samples, seed, device)
    write_evaluation(evaluation, out_json, out_csv, out_grid_png, out_psnr_png)
    return evaluation.result


def _write_csv(path, ds: CalibrationDataset, per_image: dict) -> None:
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(CSV_COLUMNS)
    for i in range(len(ds.images)):
        writer.writerow([i, f"{ds.azimuth_deg[i]:.6g}", f"{ds.elevation_deg[i]:.6g}", str(ds.split[i]),
                         *(f"{float(per_image[k][i]):.8g}" for k in METRICS)])
    write_text_atomic(path, buf.getvalue())


def _spread(ds: CalibrationDataset, idx: np.ndarray, k: int) -> np.ndarray:
    """Up to k indices of idx spread evenly over its sun positions (sorted by elevation, azimuth)."""
    if k <= 0 or not len(idx):
        return idx[:0]
    order = idx[np.lexsort((ds.azimuth_deg[idx], ds.elevation_deg[idx]))]
    return order[np.unique(np.linspace(0, len(order) - 1, min(k, len(order))).round().astype(int))]


def grid_indices(ds: CalibrationDataset, columns: int = 8) -> np.ndarray:
    """Image indices for the prediction grid: half from interpolation, half from extrapolation
    (a split with fewer images leaves its columns to the other); the train split if both are empty."""
    interp, extrap = ds.indices("interpolation"), ds.indices("extrapolation")
    if not len(interp) and not len(extrap):
        return _spread(ds, ds.indices("train"), columns)
    k_extrap = min(len(extrap), columns - min(len(interp), columns // 2))
    k_interp = min(len(interp), columns - k_extrap)
    return np.concatenate((_spread(ds, interp, k_interp), _spread(ds, extrap, k_extrap)))


def plot_prediction_grid(ds: CalibrationDataset, meas: np.ndarray, pred: np.ndarray, psnr_db: np.ndarray,
                         title: str, path, columns: int = 8) -> None:
    """Rows measured / predicted / signed difference (predicted - measured), one column per sun
    position; images in units of the dataset's maximum flux."""
    pick = grid_indices(ds, columns)
    k = max(len(pick), 1)
    fig, axes = plt.subplots(3, k, figsize=(1.9 * k + 1.2, 6.4), squeeze=False)
    for ax in axes.ravel():
        ax.set_xticks([])
        ax.set_yticks([])
    if not len(pick):
        axes[0, 0].text(0.5, 0.5, "no images", ha="center", va="center", transform=axes[0, 0].transAxes)
        fig.suptitle(title)
        save_figure(fig, path)
        return
    vmax = float(max(meas[pick].max(), pred[pick].max(), 1e-12))
    diff = pred[pick] - meas[pick]
    dmax = float(max(np.abs(diff).max(), 1e-12))
    rows = []
    for col, i in enumerate(pick):
        rows = [axes[0, col].imshow(meas[i], cmap="inferno", vmin=0, vmax=vmax),
                axes[1, col].imshow(pred[i], cmap="inferno", vmin=0, vmax=vmax),
                axes[2, col].imshow(diff[col], cmap="RdBu_r", vmin=-dmax, vmax=dmax)]
        axes[0, col].set_title(f"az {ds.azimuth_deg[i]:.0f}°, el {ds.elevation_deg[i]:.0f}°\n{ds.split[i]}\n"
                               f"PSNR {psnr_db[i]:.1f} dB", fontsize=7)
    for r, label in enumerate(("measured", "predicted", "predicted − measured")):
        axes[r, 0].set_ylabel(label, fontsize=8)
        fig.colorbar(rows[r], ax=axes[r].tolist(), shrink=0.9, pad=0.01,
                     label="flux / dataset max" if r < 2 else "difference")
    fig.suptitle(title, fontsize=10)
    save_figure(fig, path)


def plot_psnr_vs_sun(ds: CalibrationDataset, psnr_db: np.ndarray, title: str, path) -> None:
    """PSNR of every image against sun azimuth and elevation, coloured by split."""
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.8), sharey=True)
    for split in SPLITS:
        idx = ds.indices(split)
        if not len(idx):
            continue
        for ax, x in zip(axes, (ds.azimuth_deg, ds.elevation_deg)):
            ax.scatter(x[idx], psnr_db[idx], s=14, color=SPLIT_COLOURS[split], label=f"{split} ({len(idx)})")
    axes[0].set_xlabel("sun azimuth (deg, 0 = south, +90 = east)")
    axes[1].set_xlabel("sun elevation (deg)")
    axes[0].set_ylabel(f"PSNR (dB, capped at {PSNR_MAX_DB:g})")
    for ax in axes:
        ax.grid(alpha=0.3)
    if axes[0].has_data():
        axes[0].legend(fontsize=8)
    fig.suptitle(title, fontsize=10)
    save_figure(fig, path)
