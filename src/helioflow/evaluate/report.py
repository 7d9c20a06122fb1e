"""The experiment report: one self-contained HTML file (figures inline, no external CSS or JS).

`write_report` takes the files of each section as explicit lists (rule `report` passes
`helioflow.workflow.report_inputs(config)`, which decides what a config has) plus the folder of
benchmark files, and writes results/<experiment>/report.html with the sections

    datasets            figures/datasets/<d>.png and a table read from datasets/<d>.h5
                        (+ paint/<d>_centroids.json for PAINT datasets)
    Table 1             tables/table1.md (rendered) and table1.csv (embedded download)
    sample grids        figures/<d>/<model>_samples.png
    PSNR / sun position figures/<d>/<model>_psnr.png (+ figures/data_efficiency.png)
    diagnosis           diagnosis/<d>.json: verdict, ranking, signatures; figures/diagnosis/<d>_*.png
    error ledger        the `ledger` of each diagnosis JSON and figures/diagnosis/<d>_ledger.png
    field flux maps     field/flux.png, field/flux.h5 (maps and differences to truth), field/metrics.json
    run times           benchmarks/<rule>/<wildcards>.tsv (snakemake's benchmark files)

A section whose list is empty says "not part of this experiment". Unreadable or malformed
inputs raise DataError naming the file.
"""

from __future__ import annotations

import csv
import io
import os
from pathlib import Path

import numpy as np

from ..data.hdf5 import SPLITS, read_dataset
from ..errors import DataError
from .report_html import (
    download,
    esc,
    figure,
    figure_bytes,
    fmt,
    markdown,
    nested_tables,
    page,
    read_bytes,
    read_json,
    table,
)

SECTIONS = ("datasets", "dataset_figures", "paint_centroids", "table", "samples", "psnr", "data_efficiency",
            "diagnosis", "diagnosis_figures", "field")
MAP_NAMES = ("truth", "ideal", "hybrid")  # field maps; differences are drawn against "truth"
ABSENT = '<p class="absent">Not part of this experiment.</p>'


def _by_name(paths: list[str]) -> dict[str, str]:
    return {Path(p).name: str(p) for p in paths}


def _datasets_section(datasets: list[str], figures: list[str], centroids: list[str]) -> str:
    """Table of images per split, sun ranges and heliostat; the sample figures; PAINT checks."""
    rows = []
    for path in datasets:
        ds = read_dataset(path)
        counts = [int((np.asarray(ds.split) == s).sum()) for s in SPLITS]
        rows.append([ds.attrs.get("dataset", Path(path).stem), ds.attrs.get("heliostat", "?"),
                     ds.attrs.get("source", "?"), len(ds.images), *counts,
                     f"{ds.azimuth_deg.min():.1f} … {ds.azimuth_deg.max():.1f}",
                     f"{ds.elevation_deg.min():.1f} … {ds.elevation_deg.max():.1f}",
                     "×".join(map(str, ds.images.shape[1:]))])
    parts = [table(["dataset", "heliostat", "source", "images", *SPLITS, "sun azimuth (deg)",
                    "sun elevation (deg)", "image size"], rows)]
    parts += [figure(p, f"dataset {Path(p).stem}: sample images") for p in figures]
    parts += [_paint_centroids(p) for p in centroids]
    return "\n".join(parts)


def _fixed(value, digits: int):
    """A number as text with `digits` decimals (a column reads evenly); anything else as it is."""
    return f"{value:.{digits}f}" if isinstance(value, (int, float)) and not isinstance(value, bool) else value


def _paint_centroids(path: str) -> str:
    """Per PAINT image: measured and UTIS centroid offsets from the ideal trace, spot angles."""
    data = read_json(path)
    images = data.get("images") if isinstance(data, dict) else None
    if not isinstance(images, list):
        raise DataError(f"{path}: not a PAINT centroid check (written by `paint-centroids`): no `images` list")
    rows = [[r.get("id"), r.get("target"),
             *(_fixed(r.get(k), 1) for k in ("azimuth_deg", "elevation_deg")),
             *(_fixed(r.get(k), 2) for k in ("image_right_mrad", "image_up_mrad", "image_mrad", "utis_mrad")),
             *(_fixed((r.get("spot_angle_deg") or {}).get(k), 1) for k in ("ideal", "measured"))]
            for r in images]
    return (f"<h3>PAINT centroid check: {esc(Path(path).stem.removesuffix('_centroids'))}</h3>"
            "<p>Spot centroid of each measured image and of PAINT's UTIS estimate minus that of the ideal "
            "heliostat's trace, in mrad as seen from the heliostat; spot orientation in degrees.</p>"
            + table(["id", "target", "sun azimuth (deg)", "sun elevation (deg)", "right (mrad)", "up (mrad)",
                     "offset (mrad)", "UTIS offset (mrad)", "spot angle ideal (deg)", "spot angle measured (deg)"],
                    rows))


def _table1_section(paths: list[str]) -> str:
    parts = []
    for path in paths:
        if Path(path).suffix == ".md":
            parts.append(markdown(read_bytes(path).decode("utf-8")))
        else:
            parts.append(f"<p>The table with full precision: {download(path)}</p>")
    return "\n".join(parts)


def _model_figures(paths: list[str], suffix: str) -> str:
    """figures/<dataset>/<model><suffix>.png, captioned '<dataset>: <model>'."""
    return "\n".join(figure(p, f"{Path(p).parent.name}: {Path(p).stem.removesuffix(suffix)}") for p in paths)


def _psnr_section(psnr: list[str], efficiency: list[str]) -> str:
    parts = [_model_figures(psnr, "_psnr")]
    if efficiency:
        parts.append("<h3>Data efficiency</h3>")
        parts += [figure(p, "PSNR against the number of training images") for p in efficiency]
    return "\n".join(parts)


def _fitted(params: dict) -> str:
    return ", ".join(f"{k} = {v:.4g}" if isinstance(v, float) else f"{k} = {v}" for k, v in (params or {}).items())


def _pct(value) -> str:
    return "–" if value is None else f"{round(100 * value):d} %"


def _diagnosis(path: str) -> dict:
    data = read_json(path)
    if not isinstance(data, dict) or not isinstance(data.get("ranking"), list):
        raise DataError(f"{path}: not a diagnosis JSON (written by `diagnose`): no `ranking` list")
    data.setdefault("dataset", Path(path).stem)
    return data


def _diagnosis_terms(d: dict) -> str:
    """The model the diagnosis started from, its error measure and its threshold."""
    measure = d.get("error_measure") or {}
    threshold = d.get("threshold")
    if isinstance(threshold, dict):
        threshold = _fitted(threshold)
    elif isinstance(threshold, float):
        threshold = f"relative reduction {_pct(threshold)}"
    return (f"<p>Model effects: <code>{esc(fmt(d.get('model_effects', {})))}</code>. Error measure: "
            f"<strong>{esc(measure.get('name', '?'))}</strong>: {esc(measure.get('description', ''))}. "
            f"A reduction counts from: {esc(threshold)}.</p>")


def _diagnosis_section(paths: list[str], figures: list[str]) -> str:
    """Per dataset: verdict, error measure, ranking of the missing effects, signatures, figures."""
    named, parts = _by_name(figures), []
    for path in paths:
        d = _diagnosis(path)
        name = d["dataset"]
        ranking = [[i + 1, r.get("effect"), _fitted(r.get("fitted")), r.get("heldout_error_before"),
                    r.get("heldout_error_after"), _pct(r.get("relative_reduction")), r.get("identifiable")]
                   for i, r in enumerate(d["ranking"])]
        parts += [f"<h3>{esc(name)}</h3>", f'<p class="verdict">{esc(d.get("verdict", ""))}</p>',
                  _diagnosis_terms(d), "<h4>Missing effects, best first</h4>",
                  table(["rank", "effect", "fitted parameters", "held-out error before", "after",
                         "relative reduction", "identifiable"], ranking)]
        if d.get("not_tested"):
            parts += ["<h4>Not tested</h4>",
                      table(["effect", "reason"], [[t.get("effect"), t.get("reason")] for t in d["not_tested"]])]
        if d.get("signatures"):
            parts += ["<h4>Residual signatures</h4>", nested_tables(d["signatures"])]
        parts += [figure(named[f"{name}_{kind}.png"], f"{name}: {label}")
                  for kind, label in (("signatures", "residual signatures against sun position"),
                                      ("ranking", "ranking of the missing effects"),
                                      ("residuals", "residual images at the worst sun positions"))
                  if f"{name}_{kind}.png" in named]
    return "\n".join(parts)


def _ledger_section(paths: list[str], figures: list[str]) -> str:
    """Per dataset: held-out error of every model revision on the same measurements, oldest first."""
    named, parts = _by_name(figures), []
    for path in paths:
        d = _diagnosis(path)
        name = d["dataset"]
        rows = [[e.get("revision"), str(e.get("model_hash", ""))[:12], e.get("model_effects"), e.get("heldout_error")]
                for e in d.get("ledger") or []]
        parts += [f"<h3>{esc(name)}</h3>", table(["revision", "model hash", "model effects", "held-out error"], rows)]
        if f"{name}_ledger.png" in named:
            parts.append(figure(named[f"{name}_ledger.png"], f"{name}: held-out error of every model revision"))
    return "\n".join(parts)


def field_maps(path: str | os.PathLike) -> list[tuple[str, dict[str, np.ndarray]]]:
    """(sun point, {map name: (H, W) flux}) read from field/flux.h5.

    Maps are the datasets named truth / ideal / hybrid anywhere in the file: (H, W) ones in a
    group per sun point (named by the group), or (S, H, W) ones whose points are named by a
    1-D string dataset of length S beside them (else numbered).
    """
    import h5py

    points: dict[str, dict[str, np.ndarray]] = {}
    try:
        with h5py.File(path, "r") as f:
            def visit(name: str, obj) -> None:
                parent, _, leaf = name.rpartition("/")
                if not isinstance(obj, h5py.Dataset) or leaf not in MAP_NAMES or obj.ndim not in (2, 3):
                    return
                if obj.ndim == 2:
                    points.setdefault(parent or "design point", {})[leaf] = obj[()]
                    return
                labels = [str(i) for i in range(obj.shape[0])]
                for sibling in (f[parent] if parent else f).values():
                    if (isinstance(sibling, h5py.Dataset) and sibling.ndim == 1 and len(sibling) == obj.shape[0]
                            and h5py.check_string_dtype(sibling.dtype) is not None):
                        labels = list(sibling.asstr()[()])
                        break
                for label, image in zip(labels, obj[()]):
                    points.setdefault(label, {})[leaf] = image

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
            images.update({c: panels[m] - panels["truth"] for m, c in zip(diffs, diff_columns) if m in panels})
        vmax = max(float(np.max(panels[m])) for m in panels) or 1.0
        limit = max((float(np.max(np.abs(images[c]))) for c in diff_columns if c in images), default=0.0) or 1.0
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


def _field_section(paths: list[str]) -> str:
    """The field flux figure, the maps beside their differences to truth, and the metrics."""
    parts = []
    for path in paths:
        suffix = Path(path).suffix
        if suffix == ".png":
            parts.append(figure(path, "field flux maps on the receiver"))
        elif suffix == ".h5":
            maps = field_maps(path)
            if maps:
                parts += ["<h3>Maps and their differences to truth</h3>",
                          figure_bytes(field_maps_figure(maps), "per sun design point: truth, ideal and hybrid "
                                       "maps on one flux scale, then ideal − truth and hybrid − truth")]
        elif suffix == ".json":
            parts += ["<h3>Metrics against truth</h3>", nested_tables(read_json(path))]
    return "\n".join(parts)


def _number(text: str) -> float | None:
    try:
        return float(text)
    except (TypeError, ValueError):
        return None


def run_times(benchmark_dir: str | os.PathLike) -> list[dict]:
    """One row per benchmark file under benchmark_dir (<rule>/<wildcards>.tsv): rule, wildcards,
    mean wall seconds `s` over the file's repeats and the largest max_rss (MB, None if absent)."""
    root, rows = Path(benchmark_dir), []
    for path in sorted(root.rglob("*.tsv")):
        try:
            records = list(csv.DictReader(io.StringIO(path.read_text(encoding="utf-8")), delimiter="\t"))
        except (OSError, UnicodeDecodeError) as exc:
            raise DataError(f"{path}: cannot read benchmark file: {exc}") from None
        seconds = [_number(r.get("s")) for r in records]
        if not records or None in seconds:
            raise DataError(f"{path}: not a snakemake benchmark file (needs a column `s` of seconds)")
        rss = [v for v in (_number(r.get("max_rss")) for r in records) if v is not None]
        rel = path.relative_to(root).with_suffix("")
        rows.append({"rule": rel.parts[0], "wildcards": "/".join(rel.parts[1:]), "s": sum(seconds) / len(seconds),
                     "max_rss_mb": max(rss) if rss else None})
    return rows


def _hms(seconds: float) -> str:
    minutes, s = divmod(round(seconds), 60)
    return f"{minutes // 60}:{minutes % 60:02d}:{s:02d}"


def _run_times_section(benchmark_dir: str | os.PathLike | None) -> str:
    rows = run_times(benchmark_dir) if benchmark_dir is not None and Path(benchmark_dir).is_dir() else []
    if not rows:
        return '<p class="absent">No benchmark files yet.</p>'
    total = sum(r["s"] for r in rows)
    return ("<p>Wall time of each job from snakemake's benchmark files (mean over repeats); jobs that ran "
            "in parallel overlap, so the total is the summed job time, not the elapsed time.</p>"
            + table(["rule", "wildcards", "s", "h:m:s", "max RSS (MB)"],
                    [[r["rule"], r["wildcards"], _fixed(r["s"], 2), _hms(r["s"]), _fixed(r["max_rss_mb"], 1)]
                     for r in rows],
                    total=["total", f"{len(rows)} jobs", _fixed(total, 2), _hms(total), None]))


def build_report(inputs: dict[str, list[str]], benchmark_dir: str | os.PathLike | None, experiment: str) -> str:
    """The report's HTML from the files of each section (keys of SECTIONS; missing keys are empty)."""
    unknown = sorted(set(inputs) - set(SECTIONS))
    if unknown:
        raise DataError(f"unknown report sections {unknown}; known: {', '.join(SECTIONS)}")
    get = {key: [str(p) for p in inputs.get(key) or []] for key in SECTIONS}

    def section(files: list[str], render) -> str:
        return render() if files else ABSENT

    sections = [
        ("datasets", "Datasets", section(get["datasets"] + get["dataset_figures"] + get["paint_centroids"], lambda: _datasets_section(
            get["datasets"], get["dataset_figures"], get["paint_centroids"]))),
        ("table1", "Table 1", section(get["table"], lambda: _table1_section(get["table"]))),
        ("samples", "Sample grids", section(get["samples"], lambda: _model_figures(get["samples"], "_samples"))),
        ("psnr", "PSNR against sun position", section(get["psnr"] + get["data_efficiency"], lambda: _psnr_section(
            get["psnr"], get["data_efficiency"]))),
        ("diagnosis", "Diagnosis: which effect is missing", section(get["diagnosis"], lambda: _diagnosis_section(
            get["diagnosis"], get["diagnosis_figures"]))),
        ("ledger", "Error ledger", section(get["diagnosis"], lambda: _ledger_section(
            get["diagnosis"], get["diagnosis_figures"]))),
        ("field", "Field flux maps", section(get["field"], lambda: _field_section(get["field"]))),
        ("runtimes", "Run times", _run_times_section(benchmark_dir)),
    ]
    return page(f"helioflow report: experiment {experiment}", sections)


def write_report(output: str | os.PathLike, inputs: dict[str, list[str]], benchmark_dir: str | os.PathLike | None,
                 experiment: str) -> None:
    """Write build_report(...) to `output` (temporary name, then renamed)."""
    text = build_report(inputs, benchmark_dir, experiment)
    output = Path(output)
    output.parent.mkdir(parents=True, exist_ok=True)
    tmp = output.with_name(f".{output.name}.tmp")
    tmp.write_text(text, encoding="utf-8")
    os.replace(tmp, output)
