"""Figures of the diagnosis: residual signatures, the ranking, the worst residual images, the ledger."""

from __future__ import annotations

import textwrap

import numpy as np

from helioflow.plotting import save_figure

SPLIT_COLOURS = {"train": "tab:blue", "interpolation": "tab:green", "extrapolation": "tab:red"}


def _verdict_title(fig, verdict: str) -> None:
    fig.suptitle("\n".join(textwrap.wrap(verdict, 150)), fontsize=8, ha="left", x=0.01)


def plot_signatures(result: dict, path) -> None:
    """Centroid offset, spot width ratio and energy outside the core against sun azimuth and elevation."""
    import matplotlib.pyplot as plt

    per = result["signatures"]["per_image"]
    split = np.asarray(per["split"])
    rows = (("centroid_right_mrad", "centroid offset right (mrad)"), ("centroid_up_mrad", "centroid offset up (mrad)"),
            ("width_ratio", "spot width measured / model"), ("energy_outside_core", "measured flux outside model core"))
    fig, axes = plt.subplots(2, len(rows), figsize=(4 * len(rows), 6.4), squeeze=False)
    for col, (key, label) in enumerate(rows):
        for row, angle in enumerate(("azimuth_deg", "elevation_deg")):
            ax = axes[row, col]
            for name, colour in SPLIT_COLOURS.items():
                m = split == name
                ax.scatter(np.asarray(per[angle])[m], np.asarray(per[key])[m], s=8, c=colour, label=name)
            ax.set_xlabel(f"sun {angle.replace('_deg', '')} (deg)")
            ax.set_ylabel(label, fontsize=8)
    axes[0, 0].legend(fontsize=7)
    _verdict_title(fig, result["verdict"])
    fig.tight_layout(rect=(0, 0, 1, 0.9))
    save_figure(fig, path)


def plot_ranking(result: dict, path) -> None:
    """Held-out error before and after fitting each absent effect, best first."""
    import matplotlib.pyplot as plt

    ranking = result["ranking"]
    fig, ax = plt.subplots(figsize=(7, 0.45 * max(len(ranking), 1) + 1.6))
    names = [r["effect"] + ("" if r["identifiable"] else " (scale: not identifiable)") for r in ranking]
    y = np.arange(len(ranking))[::-1]
    ax.barh(y, [r["heldout_error_before"] for r in ranking], color="lightgray", label="model")
    ax.barh(y, [r["heldout_error_after"] for r in ranking],
            color=["tab:green" if r["meaningful"] else "tab:gray" for r in ranking], label="model + effect (fitted)")
    for yi, r in zip(y, ranking):
        ax.text(r["heldout_error_before"], yi, f" {-r['relative_reduction'] + 0.0:+.0%}", va="center", fontsize=8)
    ax.set_yticks(y, names, fontsize=8)
    ax.set_xlabel(f"held-out {result['error_measure']['name'].replace('_', ' ')}")
    ax.legend(fontsize=7, loc="lower right")
    ax.set_title(f"{result['dataset']}: which missing effect explains the residuals", fontsize=9)
    fig.tight_layout()
    save_figure(fig, path)


def plot_residuals(result: dict, ds, pred: np.ndarray, meas: np.ndarray, error: np.ndarray, path, n: int = 4) -> None:
    """Measured, model and predicted - measured (the evaluate grid's sign) at the n sun positions the
    model fits worst, each image divided by its mean (the shapes the misplaced flux compares): one
    colour scale for all images, one for all differences, with colour bars."""
    import matplotlib.pyplot as plt

    worst = np.argsort(error)[::-1][:n]
    pixels = meas.shape[-1] * meas.shape[-2]
    meas, pred = (x / np.maximum(x.sum((-2, -1), keepdims=True), 1e-30) * pixels for x in (meas, pred))
    peak = max(float(meas[worst].max()), float(pred[worst].max()), 1e-30)
    diff = pred[worst] - meas[worst]
    span = max(float(np.abs(diff).max()), 1e-30)
    fig, axes = plt.subplots(3, len(worst), figsize=(2.6 * len(worst) + 0.8, 7.4), squeeze=False)
    for col, i in enumerate(worst):
        for row, (image, cmap, lo, hi) in enumerate(((meas[i], "inferno", 0, peak), (pred[i], "inferno", 0, peak),
                                                     (diff[col], "RdBu_r", -span, span))):
            ax = axes[row, col]
            shown = ax.imshow(image, cmap=cmap, vmin=lo, vmax=hi)
            ax.set_xticks([])
            ax.set_yticks([])
            if col == len(worst) - 1:
                fig.colorbar(shown, ax=axes[row, :].tolist(), shrink=0.8, label="flux / its mean")
        axes[0, col].set_title(f"{ds.split[i]}, az {ds.azimuth_deg[i]:.0f}°, el {ds.elevation_deg[i]:.0f}°\n"
                               f"misplaced {error[i]:.3f}", fontsize=8)
    for row, label in enumerate(("measured", "model", "predicted − measured")):
        axes[row, 0].set_ylabel(label)
    save_figure(fig, path)


def plot_ledger(result: dict, path) -> None:
    """Held-out error of every model revision on these measurements, oldest first."""
    import matplotlib.pyplot as plt

    ledger = result["ledger"]
    fig, ax = plt.subplots(figsize=(6, 3.2))
    x = [e["revision"] for e in ledger]
    ax.plot(x, [e["heldout_error"] for e in ledger], "o-")
    current = [e for e in ledger if e.get("current")]
    ax.plot([e["revision"] for e in current], [e["heldout_error"] for e in current], "o", color="tab:red",
            markersize=9, label="current model")
    if current:
        ax.legend(fontsize=7)
    for e in ledger:
        label = ", ".join(sorted(e["model_effects"])) or "(no effects)"
        ax.annotate(textwrap.fill(label, 28), (e["revision"], e["heldout_error"]), fontsize=6,
                    textcoords="offset points", xytext=(4, 4))
    ax.set_xticks(x)
    ax.set_xlabel("model revision")
    ax.set_ylabel(f"held-out {result['error_measure']['name'].replace('_', ' ')}")
    ax.set_ylim(bottom=0)
    ax.set_title(f"{result['dataset']}: error ledger", fontsize=9)
    fig.tight_layout()
    save_figure(fig, path)


def plot_location(result: dict, path) -> None:
    """Where the remaining residual lives: error over noise against sun elevation and azimuth, the
    flux the measurements have more or less than the model in each part of the spot, and the light
    each mirror region sends relative to the model in the images that carry the residual and in the others."""
    import matplotlib.pyplot as plt
    from matplotlib.patches import Rectangle

    loc, per = result["location"], result["signatures"]["per_image"]
    ratio = np.asarray(per["remaining_error"]) / np.maximum(np.asarray(per["noise_floor"]), 1e-12)
    split = np.asarray(per["split"])
    fig = plt.figure(figsize=(15, 10.5))
    grid = fig.add_gridspec(2, 6, height_ratios=(1, 1.3))
    axes = [fig.add_subplot(grid[0, 2 * i:2 * i + 2]) for i in range(3)]
    axes += [fig.add_subplot(grid[1, 3 * i:3 * i + 3]) for i in range(2)]
    for ax, angle in zip(axes[:2], ("elevation_deg", "azimuth_deg")):
        for name, colour in SPLIT_COLOURS.items():
            m = split == name
            ax.scatter(np.asarray(per[angle])[m], ratio[m], s=10, c=colour, label=name)
        ax.axhline(result["threshold"]["explained_over_noise"], color="k", lw=0.8, ls="--", label="explained below")
        ax.set_xlabel(f"sun {angle.replace('_deg', '')} (deg)")
        ax.set_ylabel("remaining error / noise floor")
        ax.set_ylim(bottom=0)
    axes[0].legend(fontsize=7)
    sides = ("above", "below", "right", "left", "core", "halo")
    values = [loc["image"][k] for k in sides]
    axes[2].bar(sides, values, color=["tab:red" if v > 0 else "tab:blue" for v in values])
    axes[2].axhline(0, color="k", lw=0.8)
    axes[2].set_ylabel("measured − model flux (fraction of the image)")
    axes[2].set_title("where in the spot", fontsize=9)
    regions, mirror = loc["mirror"]["regions"], loc["mirror"]["weight"]
    span = max(0.1, max(abs(w - 1.0) for key in ("affected", "others") for w in mirror[key]))
    colours = plt.Normalize(1.0 - span, 1.0 + span)
    n = loc["mirror"]["affected_images"]
    over = f"{result['threshold']['explained_over_noise']} x noise"
    for ax, key, title in ((axes[3], "affected",
                            f"the {n} images over {over}" if n else f"all images (none over {over})"),
                           (axes[4], "others", "the other images" if n else "(no other images)")):
        for r, w in zip(regions, mirror[key]):
            ax.add_patch(Rectangle((r["right_m"] - r["width_m"] / 2, r["up_m"] - r["height_m"] / 2), r["width_m"],
                                   r["height_m"], facecolor=plt.cm.RdBu(colours(w)), edgecolor="white", lw=0.5))
            ax.text(r["right_m"], r["up_m"], f"{w:.2f}", ha="center", va="center", fontsize=7)
        ax.set_xlim(min(r["right_m"] - r["width_m"] for r in regions),
                    max(r["right_m"] + r["width_m"] for r in regions))
        ax.set_ylim(min(r["up_m"] - r["height_m"] for r in regions), max(r["up_m"] + r["height_m"] for r in regions))
        ax.set_aspect("equal")
        ax.set_xlabel("mirror right (m), seen from the target")
        ax.set_ylabel("up (m)")
        ax.set_title(f"light sent / model's: {title}", fontsize=9)
    fig.colorbar(plt.cm.ScalarMappable(colours, "RdBu"), cax=fig.add_axes((0.93, 0.12, 0.012, 0.3)),
                 label="relative light (1 = model)")
    _verdict_title(fig, result["verdict"])
    fig.subplots_adjust(top=0.8, hspace=0.3, wspace=0.9, left=0.06, right=0.9)
    save_figure(fig, path)


def plot_diagnosis(result: dict, ds, pred: np.ndarray, meas: np.ndarray, error: np.ndarray, figures: dict) -> None:
    """All five figures; `figures` maps signatures, ranking, residuals, location, ledger to paths."""
    plot_location(result, figures["location"])
    plot_signatures(result, figures["signatures"])
    plot_ranking(result, figures["ranking"])
    plot_residuals(result, ds, pred, meas, error, figures["residuals"])
    plot_ledger(result, figures["ledger"])
