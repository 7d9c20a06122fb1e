"""The report's field section: the flux figure, the truth / ideal / hybrid maps of field/flux.h5
beside their differences to truth (drawn here), and field/metrics.json as tables."""

from __future__ import annotations

import io
import os
from pathlib import Path

import h5py
import numpy as np

from ..errors import DataError
from .report_html import figure, figure_bytes, nested_tables, read_json

MAP_NAMES = ("truth", "ideal", "hybrid")  # differences are drawn against "truth"


def _point_names(group: h5py.Group, count: int) -> list[str]:
    """Names of `count` stacked maps: the first 1-D string dataset of that length in `group`."""
    for item in group.values():
        if (isinstance(item, h5py.Dataset) and item.ndim == 1 and len(item) == count
                and h5py.check_string_dtype(item.dtype) is not None):
            return list(item.asstr()[()])
    return [str(i) for i in range(count)]


def field_maps(path: str | os.PathLike) -> list[tuple[str, dict[str, np.ndarray]]]:
    """(sun point, {map name: (H, W) flux in W/m^2}) read from field/flux.h5.

    Maps are the datasets named truth / ideal / hybrid anywhere in the file: (H, W) ones in a
    group per sun point (named by the group), or (S, H, W) ones whose points are named by a
    1-D string dataset of length S beside them (else numbered).
    """
    points: dict[str, dict[str, np.ndarray]] = {}

    def visit(name: str, obj) -> None:
        parent, _, leaf = name.rpartition("/")
        if not isinstance(obj, h5py.Dataset) or leaf not in MAP_NAMES or obj.ndim not in (2, 3):
            return
        if obj.ndim == 2:
            points.setdefault(parent or "design point", {})[leaf] = obj[()]
            return
        for label, image in zip(_point_names(obj.parent, obj.shape[0]), obj[()]):
            points.setdefault(label, {})[leaf] = image

    try:
        with h5py.File(path, "r") as f:
            f.visititems(visit)
    except OSError as exc:
        raise DataError(f"{path}: cannot read field flux maps: {exc}") from None
    return list(points.items())


def field_maps_figure(maps: list[tuple[str, dict[str, np.ndarray]]]) -> bytes:
    """PNG: per sun point (rows) the maps side by side on one flux scale, then each map minus
    truth on a symmetric scale."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    diffs = [m for m in MAP_NAMES[1:] if any(m in p and "truth" in p for _, p in maps)]
    diff_columns = [f"{m} − truth" for m in diffs]
    columns = [m for m in MAP_NAMES if any(m in p for _, p in maps)] + diff_columns
    fig, axes = plt.subplots(len(maps), len(columns), figsize=(2.6 * len(columns), 2.4 * len(maps)),
                             squeeze=False, constrained_layout=True)
    for row, (point, panels) in zip(axes, maps):
        images = dict(panels)
        if "truth" in panels:
            images.update({c: panels[m] - panels["truth"]
                           for m, c in zip(diffs, diff_columns) if m in panels})
        vmax = max(float(np.max(panels[m])) for m in panels) or 1.0
        limit = max((float(np.max(np.abs(images[c]))) for c in diff_columns if c in images),
                    default=0.0) or 1.0
        for ax, column in zip(row, columns):
            ax.set_xticks([]), ax.set_yticks([])
            if column not in images:
                ax.set_axis_off()
                continue
            scale = ({"cmap": "inferno", "vmin": 0.0, "vmax": vmax} if column in MAP_NAMES
                     else {"cmap": "RdBu_r", "vmin": -limit, "vmax": limit})
            fig.colorbar(ax.imshow(images[column], **scale), ax=ax, shrink=0.8, label="W/m²")
            ax.set_title(f"{point}: {column}", fontsize=9)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=80)
    plt.close(fig)
    return buf.getvalue()


def field_section(files: dict[str, list[str]]) -> str:
    """The field flux figure, the maps beside their differences to truth, and the metrics."""
    parts = []
    for path in files["field"]:
        suffix = Path(path).suffix
        if suffix == ".png":
            parts.append(figure(path, "field flux maps on the receiver"))
        elif suffix == ".h5" and (maps := field_maps(path)):
            parts += ["<h3>Maps and their differences to truth</h3>",
                      figure_bytes(field_maps_figure(maps), "per sun design point: truth, ideal and hybrid "
                                   "maps on one flux scale, then ideal − truth and hybrid − truth")]
        elif suffix == ".json":
            parts += ["<h3>Metrics against truth</h3>", nested_tables(read_json(path))]
    return "\n".join(parts)
