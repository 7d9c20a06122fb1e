"""Figures: matplotlib with the Agg backend (no display needed), PNGs written whole."""

from __future__ import annotations

import os

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt

from helioflow.io import write_atomic

__all__ = ["plt", "save_figure"]


def save_figure(fig, path: str | os.PathLike) -> None:
    """Save a figure as PNG, written whole (helioflow.io.write_atomic), and close it."""
    try:
        write_atomic(path, lambda tmp: fig.savefig(tmp, format="png", dpi=110, bbox_inches="tight"))
    finally:
        plt.close(fig)
