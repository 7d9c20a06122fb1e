"""Rule `leave_one_out`: the held-out scores of a leave-one-out run on a handful of real images.

A PAINT dataset with ``holdout: leave_one_out`` becomes one dataset per measurement
(``<name>_loo_<id>``, see helioflow.workflow.expand_leave_one_out), and every network is trained
on each fold with that one image held out. This collects, per held-out image and network, the
scores the `evaluate` rule wrote for it (PSNR, SSIM, centroid error in mrad, flux accuracy) and
adds the scale-free misplaced flux fraction (helioflow.physics.scene.misplaced_flux: half the
L1 distance of the two images each divided by its own sum), then draws the held-out images
measured and predicted by every network.
"""

from __future__ import annotations

import csv
import io
from pathlib import Path

import numpy as np
import torch

from helioflow.data.hdf5 import read_dataset
from helioflow.errors import DataError
from helioflow.io import write_text_atomic
from helioflow.physics.scene import misplaced_flux
from helioflow.plotting import plt, save_figure

SCORES = ("psnr", "ssim", "centroid_mrad", "flux_accuracy")
COLUMNS = ("dataset", "id", "azimuth_deg", "elevation_deg", "split", "network", *SCORES, "misplaced_flux")


def held_out_index(ds, path) -> int:
    """Index of the one held-out image of a fold dataset; DataError naming the file otherwise."""
    index = np.flatnonzero(np.asarray(ds.split) != "train")
    if len(index) != 1:
        raise DataError(f"{path}: a leave-one-out fold holds out exactly one image; this one holds out {len(index)}")
    return int(index[0])


def _csv_row(path, index: int) -> dict:
    """The `evaluate` rule's per-image CSV row of image `index`."""
    try:
        rows = list(csv.DictReader(io.StringIO(Path(path).read_text(encoding="utf-8"))))
    except OSError as exc:
        raise DataError(f"{path}: cannot read the per-image metrics: {exc}") from None
    row = next((r for r in rows if r.get("index") == str(index)), None)
    if row is None or any(k not in row for k in SCORES):
        raise DataError(f"{path}: no per-image metrics row {index} with columns {', '.join(SCORES)}")
    return row


def _prediction(model_path, ds, index: int) -> np.ndarray:
    """(H, W) the model's image at the sun position of image `index`, in units of the dataset's
    maximum (as the `evaluate` rule scores it)."""
    from helioflow.models.registry import load_model

    model, info = load_model(model_path)
    if not model.controllable:
        raise DataError(f"{model_path}: the {info['network']} model cannot be steered by the sun position; "
                        "a leave-one-out score needs a prediction")
    az = torch.as_tensor(ds.azimuth_deg[index:index + 1], dtype=torch.float32)
    el = torch.as_tensor(ds.elevation_deg[index:index + 1], dtype=torch.float32)
    with torch.no_grad():
        pred = model.predict(az, el, torch.Generator().manual_seed(0))[0].cpu().numpy()
    return pred * float(info["scale"]) / float(ds.images.max())


def leave_one_out(datasets: list[str], models: dict[str, list[str]], metrics: dict[str, list[str]],
                  out_csv, out_figure) -> list[dict]:
    """Score every network on every fold's held-out image; write the CSV and the figure.

    Args:
        datasets: the fold datasets (datasets/<name>_loo_<id>.h5), one image held out in each.
        models: network -> its model file per fold (same order as `datasets`).
        metrics: network -> its per-image metrics CSV per fold (the `evaluate` rule's).
        out_csv: one row per held-out image and network, columns COLUMNS.
        out_figure: columns = held-out images; rows = measured, then each network's prediction,
            titled with PSNR and misplaced flux; images in units of the dataset's maximum.

    Returns:
        The CSV's rows as dicts (numbers as floats); networks in the registry's order (baseline
        first, physics models last), whatever order the config lists them in.
    """
    from helioflow.models.registry import NETWORKS

    order = list(NETWORKS)
    models = {n: models[n] for n in sorted(models, key=lambda n: order.index(n) if n in order else len(order))}
    rows, panels = [], []
    for k, path in enumerate(datasets):
        ds = read_dataset(path)
        i = held_out_index(ds, path)
        measured = ds.images[i] / float(ds.images.max())
        mid = str(ds.extras["measurement_id"][i])
        column = {"title": f"{mid}\naz {ds.azimuth_deg[i]:.0f}°, el {ds.elevation_deg[i]:.0f}°",
                  "measured": measured, "predicted": {}}
        for network in models:
            pred = _prediction(models[network][k], ds, i)
            row = _csv_row(metrics[network][k], i)
            error = float(misplaced_flux(torch.as_tensor(pred[None]), torch.as_tensor(measured[None]))[0])
            rows.append({"dataset": Path(path).stem, "id": mid, "azimuth_deg": float(ds.azimuth_deg[i]),
                         "elevation_deg": float(ds.elevation_deg[i]), "split": str(ds.split[i]), "network": network,
                         **{s: float(row[s]) for s in SCORES}, "misplaced_flux": error})
            column["predicted"][network] = (pred, rows[-1])
        panels.append(column)
    _write_csv(out_csv, rows)
    plot_leave_one_out(panels, list(models), out_figure)
    return rows


def _write_csv(path, rows: list[dict]) -> None:
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=COLUMNS, lineterminator="\n")
    writer.writeheader()
    writer.writerows({k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in r.items()} for r in rows)
    write_text_atomic(path, buf.getvalue())


def plot_leave_one_out(panels: list[dict], networks: list[str], path) -> None:
    """Measured and predicted held-out images, one column per image (see `leave_one_out`)."""
    rows, cols = 1 + len(networks), max(len(panels), 1)
    fig, axes = plt.subplots(rows, cols, figsize=(2.1 * cols + 0.8, 2.2 * rows), squeeze=False)
    for ax in axes.ravel():
        ax.set_xticks([])
        ax.set_yticks([])
    image = None
    for c, panel in enumerate(panels):
        image = axes[0, c].imshow(panel["measured"], cmap="inferno", vmin=0, vmax=1)
        axes[0, c].set_title(panel["title"], fontsize=8)
        for r, network in enumerate(networks, start=1):
            pred, score = panel["predicted"][network]
            axes[r, c].imshow(pred, cmap="inferno", vmin=0, vmax=1)
            axes[r, c].set_title(f"{score['psnr']:.1f} dB, misplaced {score['misplaced_flux']:.2f}", fontsize=7)
    for r, label in enumerate(["measured", *networks]):
        axes[r, 0].set_ylabel(label, fontsize=9)
    if image is not None:
        fig.colorbar(image, ax=axes.ravel().tolist(), shrink=0.8, label="flux / dataset max")
    fig.suptitle("leave-one-out: each image predicted by models fitted on the others", fontsize=10)
    save_figure(fig, path)
