"""The figures of rules `compose_field` and `plant_flux`: the field's plan, and per sun design point
its flux maps on one flux scale beside each map's difference to a reference map on one symmetric
scale (compose_field: truth, ideal, hybrid against truth; plant_flux: ideal, calibrated against
calibrated)."""

from __future__ import annotations

import os

import numpy as np
import torch

from helioflow.plotting import plt, save_figure


def plot_field_maps(
    path: str | os.PathLike,
    maps: dict[str, np.ndarray],
    reference: str,
    points: list[str],
    sun_deg: np.ndarray,
    scores: list[dict[str, dict]],
    positions: np.ndarray,
    measured: list[int],
    receiver_size_m: tuple[float, float],
    title: str,
    labels: tuple[str, str] = ("raytraced (ideal)", "measured (model)"),
) -> None:
    """Write the field figure (PNG).

    Args:
        maps: {name: (S, H, W) flux (W/m^2)}, drawn in this order; `reference` is one of them.
        points: S design point names; sun_deg: (S, 2) azimuth, elevation (deg).
        scores: per design point {name: {"flux_accuracy", "peak_flux_error", ...}} of every map but
            the reference, against it (field.metrics.map_metrics).
        positions: (N, 3) ENU pivots (m); measured: indices of the measured (calibrated) heliostats.
        receiver_size_m: (width, height) of the receiver (m), for the map axes.
        labels: the plan's legend for the other heliostats and for the measured ones.
    """
    names = list(maps)
    others = [m for m in names if m != reference]
    n_points, n_maps, n_diffs = len(points), len(names), len(others)
    fig = plt.figure(figsize=(2.1 * (n_maps + n_diffs) + 3.4, 2.7 * n_points + 0.9))
    outer = fig.add_gridspec(1, 2, width_ratios=[1.5, 1.08 * (n_maps + n_diffs) + 0.3], wspace=0.22)
    _plan(fig.add_subplot(outer[0]), positions, measured, labels)
    # maps | colour bar | gap | differences | colour bar
    ratios = [1] * n_maps + [0.06, 0.12] + [1] * n_diffs + [0.06]
    grid = outer[1].subgridspec(n_points, len(ratios), width_ratios=ratios, wspace=0.25, hspace=0.4)
    first_diff = n_maps + 2
    w, h = receiver_size_m
    extent = (-w / 2, w / 2, -h / 2, h / 2)
    for row, point in enumerate(points):
        images = {m: maps[m][row] / 1e3 for m in names}  # kW/m^2
        diffs = {m: images[m] - images[reference] for m in others}
        vmax = max(float(im.max()) for im in images.values()) or 1.0
        limit = max(float(np.abs(d).max()) for d in diffs.values()) or 1.0
        panels = [(col, m, images[m], "inferno", 0.0, vmax) for col, m in enumerate(names)]
        panels += [(first_diff + i, m, diffs[m], "RdBu_r", -limit, limit) for i, m in enumerate(others)]
        for col, name, image, cmap, low, high in panels:
            ax = fig.add_subplot(grid[row, col])
            shown = ax.imshow(image, extent=extent, cmap=cmap, vmin=low, vmax=high)
            ax.tick_params(labelsize=6)
            if col < n_maps:
                ax.set_title(name, fontsize=8)
            else:
                s = scores[row][name]
                ax.set_title(f"{name} − {reference}\nflux acc. {s['flux_accuracy']:.3f}, "
                             f"peak {s['peak_flux_error']:+.1%}", fontsize=8)
            if col == 0:
                ax.set_ylabel(f"{point}: az {sun_deg[row, 0]:.0f}°, el {sun_deg[row, 1]:.0f}°\nup (m)", fontsize=8)
            if col in (n_maps - 1, len(ratios) - 2):
                bar = fig.colorbar(shown, cax=fig.add_subplot(grid[row, col + 1]))
                bar.ax.tick_params(labelsize=6)
                bar.ax.set_title("kW/m²", fontsize=6)
    fig.suptitle(title, fontsize=10)
    save_figure(fig, path)


def _plan(ax, positions: np.ndarray, measured: list[int], labels: tuple[str, str]) -> None:
    """Plan view of the field: pivots (east, north), the measured ones marked, the tower at the origin."""
    ax.scatter(positions[:, 0], positions[:, 1], s=8, color="0.55", label=labels[0])
    ax.scatter(positions[measured, 0], positions[measured, 1], s=28, color="tab:red", label=labels[1])
    ax.scatter([0.0], [0.0], s=60, marker="^", color="k", label="tower")
    ax.set_aspect("equal")
    ax.set_xlabel("east (m)", fontsize=8)
    ax.set_ylabel("north (m)", fontsize=8)
    ax.tick_params(labelsize=7)
    ax.legend(fontsize=7, loc="lower left")
    ax.set_title(f"field: {len(positions)} heliostats, {len(measured)} {labels[1].split()[0]}", fontsize=9)


def plot_aim_maps(
    path: str | os.PathLike,
    maps: dict[str, list[np.ndarray]],
    aims: dict[str, list[np.ndarray]],
    points: list[str],
    limit_w_m2: float | torch.Tensor,
    receiver_size_m: tuple[float, float],
    title: str,
    arrows: tuple[str, str],
) -> None:
    """Write rule optimise_aim's figure (PNG): per design point the true flux map under each aiming
    on one flux scale, the limit drawn as a contour, and the aim points on the receiver.

    Args:
        maps: {strategy: S maps (H, W) of the true flux (W/m^2)}, drawn in this order.
        aims: {strategy: S arrays (N, 2) of aim points (right, up; m from the receiver centre)}.
        points: S design point names.
        limit_w_m2: the flux limit (W/m^2): one value or an (H, W) map (field.aim.limit_map).
        receiver_size_m: (width, height) of the receiver (m).
        arrows: (from, to): the two aimings whose aim points are joined by arrows.
    """
    names = list(maps)
    limit = limit_w_m2.cpu().numpy() if isinstance(limit_w_m2, torch.Tensor) else limit_w_m2
    w, h = receiver_size_m
    extent = (-w / 2, w / 2, -h / 2, h / 2)
    fig = plt.figure(figsize=(2.5 * (len(names) + 1) + 1.0, 2.6 * len(points) + 0.8))
    # maps | colour bar | gap | aim points
    grid = fig.add_gridspec(len(points), len(names) + 3, width_ratios=[1] * len(names) + [0.06, 0.25, 1],
                            wspace=0.3, hspace=0.45)
    vmax = max(float(np.max(m)) for m in maps.values()) / 1e3 or 1.0
    for row, point in enumerate(points):
        for col, name in enumerate(names):
            ax, image = fig.add_subplot(grid[row, col]), maps[name][row]
            shown = ax.imshow(image / 1e3, extent=extent, cmap="inferno", vmin=0.0, vmax=vmax)
            ratio = image / limit
            if ratio.max() > 1:
                ax.contour(ratio, levels=[1.0], colors="cyan", linewidths=0.8, extent=extent, origin="upper")
            ax.set_title(f"{name}: peak {ratio.max():.2f} × limit", fontsize=8)
            ax.tick_params(labelsize=6)
            if col == 0:
                ax.set_ylabel(f"{point}\nup (m)", fontsize=8)
        bar = fig.colorbar(shown, cax=fig.add_subplot(grid[row, len(names)]))
        bar.ax.tick_params(labelsize=6)
        bar.ax.set_title("kW/m²", fontsize=6)
        ax = fig.add_subplot(grid[row, -1])
        for name, marker in zip(names, ("o", "x", "+", ".")):
            a = aims[name][row]
            ax.scatter(a[:, 0], a[:, 1], s=14, marker=marker, label=name)
        start, chosen = aims[arrows[0]][row], aims[arrows[1]][row]
        ax.quiver(start[:, 0], start[:, 1], chosen[:, 0] - start[:, 0], chosen[:, 1] - start[:, 1],
                  angles="xy", scale_units="xy", scale=1, width=0.004, color="0.4")
        ax.set_xlim(-w / 2, w / 2)
        ax.set_ylim(-h / 2, h / 2)
        ax.set_aspect("equal")
        ax.set_title(f"aim points (arrows: {arrows[0]} → {arrows[1]})", fontsize=8)
        ax.tick_params(labelsize=6)
        ax.legend(fontsize=6, loc="lower left")
    fig.suptitle(f"{title}; cyan: flux above the limit", fontsize=10)
    save_figure(fig, path)
