"""The plant's plan (rule plant_table -> plant/plan.png): every calibrated heliostat at its pivot
(east, north; m, the tower at the origin), coloured by its pointing error (mrad, one colour scale),
its marker telling the effects its diagnosis named (the MARKED most common sets each a shape of
their own, the rest one shape), a red ring around those that are off (scoring.plant.is_off: pointing
beyond the limit, a residual the diagnosis could not explain, or a widening of its own it did not
name). Readable for hundreds of
heliostats: one marker each, no labels but the legend's; the heliostats without a pointing error
(a model without kinematics) grey."""

from __future__ import annotations

import os
from collections import Counter

import numpy as np

from helioflow.plotting import plt, save_figure
from helioflow.scoring.plant import is_off

SHAPES = ("o", "s", "^", "D", "v", "P", "X")  # the first MARKED combinations; the rest "*"
MARKED = len(SHAPES)


def _number(text) -> float:
    return float(text) if text not in ("", None) else float("nan")


def plot_plant_plan(path: str | os.PathLike, rows: list[dict], pointing_limit_mrad: float) -> None:
    """Write the plan figure (PNG) of plant table rows (scoring.plant COLUMNS: east_m, north_m,
    pointing_error_mrad, named_effects, flags)."""
    east = np.array([_number(r["east_m"]) for r in rows])
    north = np.array([_number(r["north_m"]) for r in rows])
    pointing = np.array([_number(r["pointing_error_mrad"]) for r in rows])
    named = [";".join(sorted(filter(None, r["named_effects"].split(";")))) or "none" for r in rows]
    flagged = np.array([is_off(r["flags"]) for r in rows])
    order = [c for c, _ in Counter(named).most_common()]
    shape = {c: SHAPES[i] if i < MARKED else "*" for i, c in enumerate(order)}
    fig, ax = plt.subplots(figsize=(7.5, 6.2))
    known = np.isfinite(pointing)
    top = float(np.nanmax(pointing)) if known.any() else 1.0
    vmax = max(top, pointing_limit_mrad)
    size = 46 if len(rows) <= 100 else 18
    shown = None
    for combination in order:
        at = np.array([n == combination for n in named])
        if (at & ~known).any():
            ax.scatter(east[at & ~known], north[at & ~known], s=size, marker=shape[combination], color="0.6")
        if (at & known).any():
            shown = ax.scatter(east[at & known], north[at & known], c=pointing[at & known], s=size,
                               marker=shape[combination], cmap="viridis", vmin=0.0, vmax=vmax, edgecolors="k",
                               linewidths=0.3)
    legend = [(c.replace(";", " + "), shape[c]) for c in order[:MARKED]]
    legend += [("other combinations", "*")] if len(order) > MARKED else []
    for label, marker in legend:  # the legend's markers white: the colour is the pointing error
        ax.scatter([], [], s=size, marker=marker, color="w", edgecolors="k", label=label)
    if flagged.any():
        ax.scatter(east[flagged], north[flagged], s=size * 3.2, facecolors="none", edgecolors="tab:red",
                   linewidths=1.0, label=f"off ({int(flagged.sum())}): pointing or residual")
    ax.scatter([0.0], [0.0], s=70, marker="^", color="k", label="tower")
    if shown is not None:
        bar = fig.colorbar(shown, ax=ax, shrink=0.85)
        bar.set_label(f"pointing error (mrad); red: the limit, {pointing_limit_mrad:g} mrad", fontsize=8)
        bar.ax.axhline(pointing_limit_mrad, color="tab:red", linewidth=1.0)
        bar.ax.tick_params(labelsize=7)
    ax.set_aspect("equal")
    ax.set_xlabel("east (m)", fontsize=8)
    ax.set_ylabel("north (m)", fontsize=8)
    ax.tick_params(labelsize=7)
    ax.legend(fontsize=7, loc="best", title="named effects", title_fontsize=7)
    worst = f", the worst {top:.2f} mrad" if known.any() else ""
    ax.set_title(f"{len(rows)} calibrated heliostats{worst}", fontsize=9)
    save_figure(fig, path)
