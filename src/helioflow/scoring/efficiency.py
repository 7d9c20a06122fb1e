"""Data efficiency: PSNR against the number of training images (the `data_efficiency` rule)."""

from __future__ import annotations

import csv
import io
import json
import os
from pathlib import Path

from helioflow.io import write_text_atomic
from helioflow.models.names import parse_model
from helioflow.plotting import plt, save_figure

SPLITS_SHOWN = ("interpolation", "extrapolation")


def plot_data_efficiency(metrics_paths: list[str], figure_path: str | os.PathLike, csv_path: str | os.PathLike) -> None:
    """Read metrics/<dataset>/<network>-n<images>.json files; write a CSV (dataset, network,
    train_images, split, psnr) and one panel per dataset: PSNR against training images, one line
    per network and split."""
    rows = []
    for path in metrics_paths:
        network, count = parse_model(Path(path).stem)
        m = json.loads(Path(path).read_text())
        for split in SPLITS_SHOWN:
            rows.append({"dataset": m["dataset"], "network": network, "train_images": count, "split": split,
                         "psnr": m["splits"][split]["psnr"]})
    rows.sort(key=lambda r: (r["dataset"], r["network"], r["split"], r["train_images"]))
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=["dataset", "network", "train_images", "split", "psnr"])
    writer.writeheader()
    writer.writerows(rows)
    write_text_atomic(csv_path, buf.getvalue())
    datasets = sorted({r["dataset"] for r in rows})
    fig, axes = plt.subplots(1, len(datasets), figsize=(4.5 * len(datasets), 3.4), squeeze=False)
    for ax, dataset in zip(axes[0], datasets):
        for network in sorted({r["network"] for r in rows}):
            for split, style in zip(SPLITS_SHOWN, ("-o", "--s")):
                pts = [(r["train_images"], r["psnr"]) for r in rows
                       if r["dataset"] == dataset and r["network"] == network and r["split"] == split
                       and r["psnr"] is not None]
                if pts:
                    ax.plot(*zip(*pts), style, label=f"{network} {split}", ms=4)
        ax.set_xscale("log", base=2)
        ax.set_xlabel("training images")
        ax.set_ylabel("PSNR (dB)")
        ax.set_title(dataset, fontsize=10)
        ax.legend(fontsize=7)
    save_figure(fig, figure_path)
