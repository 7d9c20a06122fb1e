"""The experiment report: one self-contained HTML file (figures inline, no external CSS or JS).

`write_report` takes the files of each section as explicit lists (rule `report` passes
`helioflow.workflow.report_inputs(config)`, which decides what a config has) plus the folder of
benchmark files, and writes results/<experiment>/report.html with the sections

    Datasets            figures/datasets/<d>.png and a table read from datasets/<d>.h5
                        (+ paint/<d>_centroids.json of PAINT datasets)
    Table 1             tables/table1.md (rendered) and table1.csv (embedded download)
    Sample grids        figures/<d>/<model>_samples.png
    PSNR / sun position figures/<d>/<model>_psnr.png (+ figures/data_efficiency.png)
    Recovery            recovery/<d>.json: what drt recovered of each synthetic heliostat, as tables
    Fitted heliostats   heliostats/<d>.json and .png: what drt found of each real heliostat, with sigma
    Next images         plan/<d>.json: the calibration images that shrink drt's uncertainty most
    Diagnosis           diagnosis/<d>.json: verdict, ranking, signatures; figures/diagnosis/<d>_*.png
    Error ledger        the `ledger` of each diagnosis JSON and figures/diagnosis/<d>_ledger.png
    Field flux maps     field/flux.png (truth, ideal, hybrid maps beside their differences to truth)
                        and field/metrics.json as tables
    Aim points          field/aim.png and field/aim.json (each aiming judged on the true field), if asked for
    Leave-one-out       figures/leave_one_out/<d>.png and leave_one_out/<d>.csv (held-out scores
                        per real image and network) as a table
    The plant           plant/shared.json (what the heliostats share), plant/plan.png (the plant's
                        plan by pointing error), plant/heliostats.csv: a summary and the worst
                        heliostats (by pointing error), readable for hundreds of heliostats; the
                        whole table as a download; plant/flux/<plant>.json and .png: the flux on
                        its receiver, ideal and calibrated, and the spots calibration moves most
    Run times           benchmarks/<rule>/<wildcards>.tsv (snakemake's benchmark files)

A section whose files are all absent from the inputs says "Not part of this experiment".
Unreadable or malformed inputs raise DataError naming the file.
"""

from __future__ import annotations

import csv
import io
import os
from pathlib import Path

import numpy as np

from helioflow.data.hdf5 import SPLITS, read_dataset
from helioflow.errors import DataError
from helioflow.field.aim import limit_text
from helioflow.io import write_text_atomic
from helioflow.report.diagnosis import diagnosis_section, ledger_section
from helioflow.report.html import (
    download,
    esc,
    figure,
    fixed,
    markdown,
    nested_tables,
    page,
    read_bytes,
    read_json,
    table,
)

SECTIONS = ("datasets", "dataset_figures", "paint_centroids", "table", "samples", "psnr", "data_efficiency",
            "recovery", "heliostats", "plan", "diagnosis", "diagnosis_figures", "field", "aim", "leave_one_out",
            "plant",
            "plant_plan", "plant_shared", "plant_flux", "plant_aim")
PLANT_WORST = 20  # heliostats listed in the report's plant section
ABSENT = '<p class="absent">Not part of this experiment.</p>'


def _paint_centroids(path: str) -> str:
    """Per PAINT image: measured and UTIS centroid offsets from the ideal trace, spot angles."""
    data = read_json(path)
    images = data.get("images") if isinstance(data, dict) else None
    if not isinstance(images, list):
        raise DataError(f"{path}: not a PAINT centroid check (written by `paint-centroids`): "
                        "no `images` list")
    rows = [[r.get("id"), r.get("target"),
             *(fixed(r.get(k), 1) for k in ("azimuth_deg", "elevation_deg")),
             *(fixed(r.get(k), 2) for k in ("image_right_mrad", "image_up_mrad", "image_mrad", "utis_mrad")),
             *(fixed((r.get("spot_angle_deg") or {}).get(k), 1) for k in ("ideal", "measured"))]
            for r in images]
    header = ["id", "target", "sun azimuth (deg)", "sun elevation (deg)", "right (mrad)", "up (mrad)",
              "offset (mrad)", "UTIS offset (mrad)", "spot angle ideal (deg)", "spot angle measured (deg)"]
    return (f"<h3>PAINT centroid check: {esc(Path(path).stem.removesuffix('_centroids'))}</h3>"
            "<p>Spot centroid of each measured image and of PAINT's UTIS estimate minus that of the ideal "
            "heliostat's trace, in mrad as seen from the heliostat; spot orientation in degrees.</p>"
            + table(header, rows))


def _datasets_section(files: dict[str, list[str]]) -> str:
    """Table of images per split, sun ranges and heliostat; the sample figures; PAINT checks."""
    rows = []
    for path in files["datasets"]:
        ds = read_dataset(path)
        counts = [int((np.asarray(ds.split) == s).sum()) for s in SPLITS]
        rows.append([ds.attrs.get("dataset", Path(path).stem), ds.attrs.get("heliostat", "?"),
                     ds.attrs.get("source", "?"), len(ds.images), *counts,
                     f"{ds.azimuth_deg.min():.1f} … {ds.azimuth_deg.max():.1f}",
                     f"{ds.elevation_deg.min():.1f} … {ds.elevation_deg.max():.1f}",
                     "×".join(map(str, ds.images.shape[1:]))])
    parts = [table(["dataset", "heliostat", "source", "images", *SPLITS, "sun azimuth (deg)",
                    "sun elevation (deg)", "image size"], rows)]
    parts += [figure(p, f"dataset {Path(p).stem}: sample images") for p in files["dataset_figures"]]
    parts += [_paint_centroids(p) for p in files["paint_centroids"]]
    return "\n".join(parts)


def _table1_section(files: dict[str, list[str]]) -> str:
    """Table 1 from its Markdown, and its CSV as an embedded download."""
    return "\n".join(markdown(read_bytes(p).decode("utf-8")) if Path(p).suffix == ".md"
                     else f"<p>The table with full precision: {download(p)}</p>" for p in files["table"])


def _model_figures(paths: list[str], suffix: str) -> str:
    """figures/<dataset>/<model><suffix>.png, captioned '<dataset>: <model>'."""
    return "\n".join(figure(p, f"{Path(p).parent.name}: {Path(p).stem.removesuffix(suffix)}") for p in paths)


def _samples_section(files: dict[str, list[str]]) -> str:
    return _model_figures(files["samples"], "_samples")


def _psnr_section(files: dict[str, list[str]]) -> str:
    parts = [_model_figures(files["psnr"], "_psnr")]
    if files["data_efficiency"]:
        parts.append("<h3>Data efficiency</h3>")
        parts += [figure(p, "PSNR against the number of training images") for p in files["data_efficiency"]]
    return "\n".join(parts)


def _recovery_section(files: dict[str, list[str]]) -> str:
    """Per synthetic dataset: drt's fitted heliostat against the true one (scoring/recovery.py)."""
    parts = []
    for path in files["recovery"]:
        data = read_json(path)
        if not isinstance(data, dict) or "tracking_mrad" not in data:
            raise DataError(f"{path}: not a recovery JSON (written by `helioflow recovery --output`)")
        parts += [f"<h3>{esc(Path(path).stem)}</h3>", nested_tables(data)]
    return "\n".join(parts)


def _heliostats_section(files: dict[str, list[str]]) -> str:
    """Per real dataset: drt's heliostat, each fitted quantity with its sigma, and the surface map
    (scoring/fitted_heliostat.py)."""
    parts = []
    for path in (p for p in files["heliostats"] if p.endswith(".json")):
        data = read_json(path)
        if not isinstance(data, dict) or "frame" not in data:
            raise DataError(f"{path}: not a fitted heliostat JSON (written by `helioflow fitted-heliostat --output`)")
        rows = [[f"tracking {k}", "mrad", fixed(v["value"], 3), fixed(v["sigma"], 3), v["determined"]]
                for k, v in (data.get("tracking_mrad") or {}).items()]
        if "slope_error_mrad" in data:
            e = data["slope_error_mrad"]
            rows.append(["slope error", "mrad", fixed(e["value"], 3), fixed(e["sigma"], 3), e["determined"]])
        if "canting_mrad" in data:
            rows.append(["canting (RMS over facets)", "mrad", fixed(data["canting_mrad"]["rms"], 3), "", ""])
        if "surface" in data:
            s = data["surface"]
            rows.append(["surface deviation (RMS)", "mm", fixed(s["rms_mm"], 4), "", s["determined"]])
        parts += [f"<h3>{esc(Path(path).stem)}</h3>",
                  table(["quantity", "unit", "fitted", "sigma", "determined"], rows),
                  figure(str(Path(path).with_suffix(".png")), f"{Path(path).stem}: the fitted surface"),
                  download(path, "application/json")]
    return "\n".join(parts)


def _plan_section(files: dict[str, list[str]]) -> str:
    """Per planned dataset: the next calibration images and the sigma they leave (models/planning.py)."""
    parts = []
    for path in files["plan"]:
        data = read_json(path)
        if not isinstance(data, dict) or not isinstance(data.get("next"), list):
            raise DataError(f"{path}: not a plan JSON (written by `helioflow plan-measurements --output`)")
        now = data.get("sigma_now") or {}
        keys = list(now)[:8]
        rows = [["now", "", "", "", *[now.get(k) for k in keys]]]
        rows += [[n.get("rank"), n.get("time") or "", n.get("azimuth_deg"), n.get("elevation_deg"),
                  *[(n.get("sigma_after") or {}).get(k) for k in keys]] for n in data["next"]]
        parts += [f"<h3>{esc(Path(path).stem)}</h3>",
                  f"<p>{esc(data.get('criterion'))} over {esc((data.get('candidates') or {}).get('source'))}.</p>",
                  table(["image", "time (UTC)", "azimuth (deg)", "elevation (deg)", *[f"sigma {k}" for k in keys]],
                        rows)]
    return "\n".join(parts)


def _field_section(files: dict[str, list[str]]) -> str:
    """The field figure (compose_field draws the maps beside their differences to truth) and the
    metrics against truth, any nesting of them, as tables."""
    parts = []
    for path in files["field"]:
        if Path(path).suffix == ".png":
            parts.append(figure(path, "field flux maps on the receiver per sun design point"))
        else:
            parts += ["<h3>Metrics against truth</h3>", nested_tables(read_json(path))]
    return "\n".join(parts)


AIM_COLUMNS = ("truth_peak_over_limit", "truth_intercepted_w", "truth_spillage", "truth_area_over_limit",
               "intercept_of_bound", "model_peak_over_limit", "mean_aim_move_m")


def _aim_section(files: dict[str, list[str]]) -> str:
    """Rule optimise_aim's figure and, per design point, each aiming judged on the true field."""
    parts = []
    for path in files["aim"]:
        if Path(path).suffix == ".png":
            parts.append(figure(path, "true flux under each aiming, and the aim points"))
            continue
        result = read_json(path)
        parts.append(f"<p>Flux limit {limit_text(result['limit_kw_m2'])}; {result['heliostats']} heliostats, "
                     f"{len(result['measured'])} measured with {esc(result['network'])}. Every aiming is "
                     "traced on the true field (truth_*); model_peak_over_limit is what its own model "
                     "promised.</p>")
        parts.append(_target_text(result))
        if "keep_probability" in result:
            parts.append(f"<p>hybrid_margin: aimed on the hybrid map so that its peak keeps the limit with probability "
                         f"{result['keep_probability']:g} under the calibrated heliostats' pointing σ "
                         "(model_peak_bound_over_limit: a 95 %-confidence bound of that quantile).</p>")
        for point, row in result["design_points"].items():
            columns = [*AIM_COLUMNS, *(["model_peak_bound_over_limit"] if "keep_probability" in result else []),
                       *(["truth_target_accuracy", "model_target_accuracy"] if "target" in result else [])]
            parts.append(f"<h3>{esc(point)}</h3>")
            parts.append(table(["aiming", *columns], [[s, *(m.get(c) for c in columns)] for s, m in row.items()]))
    return "\n".join(parts)


def _leave_one_out_section(files: dict[str, list[str]]) -> str:
    """Per leave-one-out dataset: the figure of held-out images and the scores as a table."""
    parts = []
    for path in files["leave_one_out"]:
        name = Path(path).stem
        if Path(path).suffix == ".png":
            parts.append(figure(path, f"{name}: each image held out and predicted by models fitted on the others"))
            continue
        try:
            records = list(csv.DictReader(io.StringIO(read_bytes(path).decode("utf-8"))))
        except UnicodeDecodeError as exc:
            raise DataError(f"{path}: not a leave-one-out CSV: {exc}") from None
        keys = ("id", "network", "psnr", "centroid_mrad", "misplaced_flux")
        if not records or any(k not in records[0] for k in keys):
            raise DataError(f"{path}: not a leave-one-out CSV (written by `leave-one-out`): needs columns "
                            f"{', '.join(keys)}")
        rows = [[r["id"], r["network"], fixed(_cell_number(r["psnr"]), 2), fixed(_cell_number(r["centroid_mrad"]), 2),
                 fixed(_cell_number(r["misplaced_flux"]), 3)] for r in records]
        parts += [f"<h3>Held-out scores: {esc(name)}</h3>",
                  table(["held-out id", "network", "PSNR (dB)", "centroid error (mrad)", "misplaced flux"], rows)]
    return "\n".join(parts)


def _plant_section(files: dict[str, list[str]]) -> str:
    """The plant table (scoring.plant): how many heliostats, how many are off, which effects the
    diagnoses named how often, and the PLANT_WORST heliostats with the largest pointing error."""
    from helioflow.scoring.plant import COLUMNS, is_off

    parts = [_shared_part(path) for path in files["plant_shared"]]
    parts += [figure(path, "The plant's plan: each calibrated heliostat at its pivot, coloured by its pointing "
                     "error, its marker the effects its diagnosis named, those that are off (pointing beyond the "
                     "limit, or a residual the diagnosis could not explain) ringed red")
              for path in files["plant_plan"]]
    for path in files["plant"]:
        try:
            records = list(csv.DictReader(io.StringIO(read_bytes(path).decode("utf-8"))))
        except UnicodeDecodeError as exc:
            raise DataError(f"{path}: not a plant table: {exc}") from None
        if not records or any(k not in records[0] for k in COLUMNS):
            raise DataError(f"{path}: not a plant table (written by `plant-table`): needs columns {', '.join(COLUMNS)}")
        named: dict[str, int] = {}
        for r in records:
            for effect in filter(None, r["named_effects"].split(";")):
                named[effect] = named.get(effect, 0) + 1
        off = [r for r in records if is_off(r["flags"])]
        summary = [["heliostats", len(records)],
                   ["off: pointing beyond the limit, a residual unexplained or an own widening unnamed", len(off)],
                   *[[f"named: {effect}", count] for effect, count in sorted(named.items(), key=lambda kv: -kv[1])]]
        worst = sorted(records, key=lambda r: -(_cell_number(r["pointing_error_mrad"]) or 0.0))[:PLANT_WORST]
        rows = [[r["heliostat"], r["images"], _shown(r["heldout_error_ideal"], 4),
                 _shown(r["heldout_error_calibrated"], 4), r["named_effects"] or "none",
                 _shown(r["pointing_error_mrad"], 3, r["pointing_error_sigma_mrad"]),
                 _shown(r["canting_rms_mrad"], 3, r["canting_rms_sigma_mrad"]),
                 _shown(r["surface_rms_mm"], 4, r["surface_rms_sigma_mm"]), r["flags"]] for r in worst]
        parts += [table(["", "count"], summary),
                  f"<h3>The {len(worst)} heliostats with the largest pointing error</h3>",
                  table(["heliostat", "images", "held-out error, configured", "with named effects", "named effects",
                         "pointing error (mrad) ± sigma", "canting RMS (mrad) ± sigma", "surface RMS (mm) ± sigma",
                         "flags"], rows),
                  download(path)]
    parts += [_plant_flux_part(path) for path in files["plant_flux"] if path.endswith(".json")]
    parts += [figure(path, f"Plant {Path(path).stem}: ideal and calibrated flux maps on its receiver, and their "
                     "difference") for path in files["plant_flux"] if path.endswith(".png")]
    parts += [_plant_aim_part(path) for path in files["plant_aim"] if path.endswith(".json")]
    parts += [figure(path, f"Plant {Path(path).stem}: the calibrated plant's flux under each aiming, and the aim "
                     "points") for path in files["plant_aim"] if path.endswith(".png")]
    return "\n".join(parts)


def _shown(text: str, digits: int, sigma: str | None = None) -> str:
    """A table cell's number with `digits` decimals, "± sigma" where one is given; "–" for none."""
    value, spread = _cell_number(text), _cell_number(sigma)
    if value is None:
        return "–"
    return fixed(value, digits) if spread is None else f"{fixed(value, digits)} ± {fixed(spread, digits)}"


def _plant_flux_part(path: str) -> str:
    """plant/flux/<plant>.json (field.plant): per design point the calibrated map and the ideal one
    against it, and the PLANT_WORST heliostats whose spots calibration moves furthest."""
    data = read_json(path)
    if not isinstance(data, dict) or "design_points" not in data:
        raise DataError(f"{path}: not a plant flux map (written by `plant-flux`): needs design_points")
    rows = [[point, fixed(p["calibrated"]["peak_flux_kw_m2"], 2), fixed(p["calibrated"]["power_on_receiver_kw"], 1),
             fixed(p["calibrated"]["intercept"], 3), fixed(p["ideal"]["flux_accuracy"], 3),
             f"{100 * p['ideal']['peak_flux_error']:+.1f} %", fixed(p["ideal"]["centroid_error_m"], 3)]
            for point, p in data["design_points"].items()]
    shifts = sorted(((h["shift_m"], name, point) for point, p in data["design_points"].items()
                     for name, h in p["heliostats"].items() if h["shift_m"] is not None), reverse=True)[:PLANT_WORST]
    return "\n".join([
        f"<h3>Flux on the receiver of {esc(Path(path).stem)}: {data['heliostats']} heliostats, "
        f"{len(data['calibrated'])} calibrated</h3>",
        table(["design point", "peak (kW/m²)", "on the receiver (kW)", "intercept", "ideal map: flux accuracy",
               "its peak error", "its centroid error (m)"], rows),
        table(["heliostat", "design point", "spot moved by calibration (m)"],
              [[name, point, fixed(shift, 3)] for shift, name, point in shifts]) if shifts else "",
        download(path, "application/json")])


def _target_text(result: dict) -> str:
    """A paragraph on an aim JSON's target distribution; empty without one."""
    if "target" not in result:
        return ""
    cells = result["target"]
    return (f"<p>The optimised aimings approach a target distribution ({len(cells)} x {len(cells[0])} cells, "
            "scaled to the reflected power) under the limit instead of maximising the power: target_accuracy = "
            "1 − Σ|F − T| / Σ T.</p>")


PLANT_AIM_COLUMNS = ("calibrated_peak_over_limit", "calibrated_intercepted_w", "calibrated_spillage",
                     "calibrated_area_over_limit", "model_peak_over_limit", "mean_aim_move_m")


def _plant_aim_part(path: str) -> str:
    """plant/aim/<plant>.json (field.plant_aim): per design point each aiming judged on the calibrated plant."""
    data = read_json(path)
    if not isinstance(data, dict) or "design_points" not in data or "limit_kw_m2" not in data:
        raise DataError(f"{path}: not a plant aim (written by `plant-aim`): needs limit_kw_m2 and design_points")
    extra = ["model_peak_bound_over_limit"] if "keep_probability" in data else []
    extra += ["calibrated_target_accuracy", "model_target_accuracy"] if "target" in data else []
    parts = [f"<h3>Aim points on the receiver of {esc(Path(path).stem)}: limit {limit_text(data['limit_kw_m2'])}, "
             f"{len(data['heliostats'])} heliostats, {len(data['calibrated'])} calibrated</h3>",
             "<p>Each aiming is traced on the calibrated plant (calibrated_*): a real plant has no truth to judge on; "
             "model_peak_over_limit is what its own model promised.</p>", _target_text(data)]
    for point, row in data["design_points"].items():
        columns = [*PLANT_AIM_COLUMNS, *extra]
        parts += [f"<h4>{esc(point)}</h4>",
                  table(["aiming", *columns], [[s, *(m.get(c) for c in columns)] for s, m in row.items()])]
    return "\n".join([*parts, download(path, "application/json")])


def _shared_part(path: str) -> str:
    """plant/shared.json (diagnosis.shared): per plant entry the verdict, the shared values with their
    sigma beside what each heliostat alone makes of them (marked where the level set it aside as a
    widening of its own), and every shared change tried."""
    data = read_json(path)
    if not isinstance(data, dict) or not all(isinstance(v, dict) and "verdict" in v for v in data.values()):
        raise DataError(f"{path}: not a plant fit (written by `plant-shared`): needs a verdict per plant entry")
    parts = []
    for plant, entry in data.items():
        values = [[name, f"{fixed(v['value'], 4)} ± {fixed(v['sigma'], 2)}",
                   ", ".join(f"{h} {fixed(a['value'], 3)} ± {fixed(a['sigma'], 2)}"
                             + ("" if a["kept"] else " (own widening)") for h, a in v["alone"].items()),
                   fixed(v.get("kept_chi2_per_dof", "–"), 2)]
                  for s in entry.get("shared", []) for name, v in s.get("values", {}).items()]
        tried = [[t["change"], fixed(t["heldout_error"], 4), f"{100 * t['relative_reduction']:.0f} %",
                  "yes" if t["meaningful"] else "no"] for t in entry.get("tried", [])]
        parts += [f"<h3>Shared by the heliostats of {esc(plant)}</h3>", f"<p>{esc(entry['verdict'])}</p>",
                  table(["shared value", "plant fit ± sigma", "each heliostat alone ± sigma",
                         "chi^2 / dof of those kept"], values) if values else "",
                  table(["shared change tried", "plant held-out error", "cut", "counts"], tried),
                  download(path, "application/json")]
    return "\n".join(parts)


# (anchor, heading, the input sections it shows, renderer of the files by section)
LAYOUT = (
    ("datasets", "Datasets", ("datasets", "dataset_figures", "paint_centroids"), _datasets_section),
    ("table1", "Table 1", ("table",), _table1_section),
    ("samples", "Sample grids", ("samples",), _samples_section),
    ("psnr", "PSNR against sun position", ("psnr", "data_efficiency"), _psnr_section),
    ("recovery", "What drt recovered of the true heliostats", ("recovery",), _recovery_section),
    ("heliostats", "The fitted heliostats", ("heliostats",), _heliostats_section),
    ("plan", "The next calibration images", ("plan",), _plan_section),
    ("diagnosis", "Diagnosis: which effect is missing", ("diagnosis",), diagnosis_section),
    ("ledger", "Error ledger", ("diagnosis",), ledger_section),
    ("field", "Field flux maps", ("field",), _field_section),
    ("aim", "Aim points under the flux limit", ("aim",), _aim_section),
    ("leave_one_out", "Leave-one-out on real images", ("leave_one_out",), _leave_one_out_section),
    ("plant", "The plant", ("plant_shared", "plant", "plant_plan", "plant_flux", "plant_aim"), _plant_section),
)


def _cell_number(text: str | None) -> float | None:
    """A CSV cell as a number; None when empty or not a number."""
    if text is None:
        return None
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
        read = [_cell_number(r.get("s")) for r in records]
        seconds = [s for s in read if s is not None]
        if not records or len(seconds) < len(read):
            raise DataError(f"{path}: not a snakemake benchmark file (needs a column `s` of seconds)")
        rss = [v for v in (_cell_number(r.get("max_rss")) for r in records) if v is not None]
        rel = path.relative_to(root).with_suffix("")
        rows.append({"rule": rel.parts[0], "wildcards": "/".join(rel.parts[1:]),
                     "s": sum(seconds) / len(seconds), "max_rss_mb": max(rss) if rss else None})
    return rows


def _hms(seconds: float) -> str:
    minutes, s = divmod(round(seconds), 60)
    return f"{minutes // 60}:{minutes % 60:02d}:{s:02d}"


def _run_times_section(benchmark_dir: str | os.PathLike | None) -> str:
    """Per job: rule, wildcards, wall time, peak memory; and the summed job time."""
    rows = run_times(benchmark_dir) if benchmark_dir is not None and Path(benchmark_dir).is_dir() else []
    if not rows:
        return '<p class="absent">No benchmark files yet.</p>'
    total = sum(r["s"] for r in rows)
    body = [[r["rule"], r["wildcards"], fixed(r["s"], 2), _hms(r["s"]), fixed(r["max_rss_mb"], 1)]
            for r in rows]
    return ("<p>Wall time of each job from snakemake's benchmark files (mean over repeats); jobs that ran "
            "in parallel overlap, so the total is the summed job time, not the elapsed time.</p>"
            + table(["rule", "wildcards", "s", "h:m:s", "max RSS (MB)"], body,
                    total=["total", f"{len(rows)} jobs", fixed(total, 2), _hms(total), None]))


def build_report(inputs: dict[str, list[str]], benchmark_dir: str | os.PathLike | None,
                 experiment: str) -> str:
    """The report's HTML from the files of each section (keys of SECTIONS; missing keys are empty)."""
    unknown = sorted(set(inputs) - set(SECTIONS))
    if unknown:
        raise DataError(f"unknown report sections {unknown}; known: {', '.join(SECTIONS)}")
    files = {key: [str(p) for p in inputs.get(key) or []] for key in SECTIONS}
    sections = [(anchor, heading, render(files) if any(files[k] for k in shows) else ABSENT)
                for anchor, heading, shows, render in LAYOUT]
    sections.append(("runtimes", "Run times", _run_times_section(benchmark_dir)))
    return page(f"helioflow report: experiment {experiment}", sections)


def write_report(output: str | os.PathLike, inputs: dict[str, list[str]],
                 benchmark_dir: str | os.PathLike | None, experiment: str) -> None:
    """Write build_report(...) to `output` (temporary name, then renamed)."""
    text = build_report(inputs, benchmark_dir, experiment)
    write_text_atomic(output, text)
