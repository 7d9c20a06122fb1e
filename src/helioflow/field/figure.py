"""The figure of rule `compose_field`: the field's plan, and per sun design point the truth, ideal and
hybrid maps on one flux scale beside ideal - truth and hybrid - truth on one symmetric scale."""

from __future__ import annotations

import os

import numpy as np

from helioflow.plotting import plt, save_figure

MAPS = ("truth", "ideal", "hybrid")


def plot_field_maps(
    path: str | os.PathLike,
    maps: dict[str, np.ndarray],
    points: list[str],
    sun_deg: np.ndarray,
    scores: list[dict[str, dict]],
    positions: np.ndarray,
    measured: list[int],
    receiver_size_m: tuple[float, float],
    title: str,
) -> None:
    """Write the field figure (PNG).

    Args:
        maps: {"truth" | "ideal" | "hybrid": (S, H, W) flux (W/m^2)}.
        points: S design point names; sun_deg: (S, 2) azimuth, elevation (deg).
        scores: per design point {"ideal" | "hybrid": {"flux_accuracy", "peak_flux_error", ...}}.
        positions: (N, 3) ENU pivots (m); measured: indices of the measured heliostats.
        receiver_size_m: (width, height) of the receiver (m), for the map axes.
    """
    n_points = len(points)
    fig = plt.figure(figsize=(16.0, 2.7 * n_points + 0.9))
    outer = fig.add_gridspec(1, 2, width_ratios=[1.5, 6.4], wspace=0.12)
    _plan(fig.add_subplot(outer[0]), positions, measured)
    # truth ideal hybrid | colour bar | gap | ideal - truth, hybrid - truth | colour bar
    grid = outer[1].subgridspec(
        n_points, 8, width_ratios=[1, 1, 1, 0.06, 0.12, 1, 1, 0.06], wspace=0.25, hspace=0.4
    )
    w, h = receiver_size_m
    extent = (-w / 2, w / 2, -h / 2, h / 2)
    for row, point in enumerate(points):
        images = {m: maps[m][row] / 1e3 for m in MAPS}  # kW/m^2
        diffs = {m: images[m] - images["truth"] for m in MAPS[1:]}
        vmax = max(float(im.max()) for im in images.values())
        limit = max(float(np.abs(d).max()) for d in diffs.values()) or 1.0
        panels = [
            (col, m, images[m], {"cmap": "inferno", "vmin": 0, "vmax": vmax}) for col, m in enumerate(MAPS)
        ]
        panels += [
            (col, m, diffs[m], {"cmap": "RdBu_r", "vmin": -limit, "vmax": limit})
            for col, m in zip((5, 6), MAPS[1:])
        ]
        for col, name, image, style in panels:
            ax = fig.add_subplot(grid[row, col])
            shown = ax.imshow(image, extent=extent, **style)
            ax.tick_params(labelsize=6)
            if col < 5:
                ax.set_title(name, fontsize=8)
            else:
                s = scores[row][name]
                ax.set_title(
                    f"{name} − truth\nflux acc. {s['flux_accuracy']:.3f}, peak {s['peak_flux_error']:+.1%}",
                    fontsize=8,
                )
            if col == 0:
                ax.set_ylabel(
                    f"{point}: az {sun_deg[row, 0]:.0f}°, el {sun_deg[row, 1]:.0f}°\nup (m)", fontsize=8
                )
            if col in (2, 6):
                bar = fig.colorbar(shown, cax=fig.add_subplot(grid[row, col + 1]))
                bar.ax.tick_params(labelsize=6)
                bar.ax.set_title("kW/m²", fontsize=6)
    fig.suptitle(title, fontsize=10)
    save_figure(fig, path)


def _plan(ax, positions: np.ndarray, measured: list[int]) -> None:
    """Plan view of the field: pivots (east, north), the measured ones marked, the tower at the origin."""
    ax.scatter(positions[:, 0], positions[:, 1], s=8, color="0.55", label="raytraced (ideal)")
    ax.scatter(
        positions[measured, 0], positions[measured, 1], s=28, color="tab:red", label="measured (model)"
    )
    ax.scatter([0.0], [0.0], s=60, marker="^", color="k", label="tower")
    ax.set_aspect("equal")
    ax.set_xlabel("east (m)", fontsize=8)
    ax.set_ylabel("north (m)", fontsize=8)
    ax.tick_params(labelsize=7)
    ax.legend(fontsize=7, loc="lower left")
    ax.set_title(f"field: {len(positions)} heliostats, {len(measured)} measured", fontsize=9)
