"""The figure of a calibration dataset: sample images with their sun positions and splits."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from helioflow.data.hdf5 import read_dataset
from helioflow.plotting import plt, save_figure


def plot_dataset_samples(dataset_path: str | os.PathLike, output_path: str | os.PathLike, n: int = 12) -> None:
    """A grid of n images spread over the dataset, each titled with sun position and split,
    all on the dataset's common flux scale (kW/m^2), plus the fill fraction of each."""
    ds = read_dataset(dataset_path)
    order = np.lexsort((ds.azimuth_deg, ds.elevation_deg))
    pick = order[np.linspace(0, len(order) - 1, min(n, len(order))).round().astype(int)]
    cols = 6
    rows = int(np.ceil(len(pick) / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(2.1 * cols, 2.3 * rows + 0.4), squeeze=False)
    vmax = ds.images.max() / 1e3
    side = ds.attrs.get("target_size_m", [None])[0]
    fill = ds.extras.get("fill_fraction")
    for ax in axes.ravel():
        ax.axis("off")
    for ax, i in zip(axes.ravel(), pick):
        im = ax.imshow(ds.images[i] / 1e3, cmap="inferno", vmin=0, vmax=vmax)
        extra = f"\nfill {fill[i]:.2f}" if fill is not None else ""
        ax.set_title(f"az {ds.azimuth_deg[i]:.0f}°, el {ds.elevation_deg[i]:.0f}°\n{ds.split[i]}{extra}", fontsize=7)
    fig.colorbar(im, ax=axes.ravel().tolist(), shrink=0.8, label="flux (kW/m²)")
    title = f"{ds.attrs.get('dataset', Path(dataset_path).stem)}: {len(ds.images)} images"
    if side:
        title += f", target window {side:.2f} m"
    fig.suptitle(title, fontsize=10)
    save_figure(fig, output_path)
