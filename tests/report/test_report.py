"""The experiment report (report/page.py) on tiny fixture files of every section, and the
report's inputs for a config (workflow.report_inputs)."""

import copy
import json
import re
import struct
import zlib
from pathlib import Path

import numpy as np
import pytest

from helioflow.cli import main
from helioflow.config import load_config
from helioflow.data.hdf5 import CalibrationDataset, write_dataset
from helioflow.errors import DataError
from helioflow.report.html import markdown, nested_tables
from helioflow.report.page import build_report, run_times, write_report
from helioflow.workflow import all_targets, diagnosis_paths, recovery_paths, report_inputs

TINY = Path(__file__).resolve().parents[1] / "workflow" / "tiny_config.yaml"
HEADINGS = ("Datasets", "Table 1", "Sample grids", "PSNR against sun position",
            "What drt recovered of the true heliostats", "Diagnosis: which effect is missing",
            "Error ledger", "Field flux maps", "Leave-one-out on real images", "Run times")
ABSENT = "Not part of this experiment."


def _png(path: Path) -> str:
    """A valid 1 x 1 grey PNG."""
    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", 1, 1, 8, 0, 0, 0, 0))
                     + chunk(b"IDAT", zlib.compress(b"\x00\x80")) + chunk(b"IEND", b""))
    return str(path)


def _dataset(path: Path) -> str:
    write_dataset(path, CalibrationDataset(
        images=np.tile(np.array([[1, 1, 1], [1, 2, 1], [1, 1, 1]], np.float32), (4, 1, 1)),
        azimuth_deg=np.array([-20.0, 0.0, 10.0, 30.0]),
        elevation_deg=np.array([20.0, 30.0, 40.0, 60.0]),
        split=np.array(["train", "train", "interpolation", "extrapolation"]),
        attrs={"dataset": "scan", "heliostat": "small", "source": "synthetic (helioflow trace)"}))
    return str(path)


DIAGNOSIS = {
    "dataset": "scan",
    "model_effects": {"sunshape": {"kind": "pillbox", "half_angle_mrad": 4.65}},
    "error_measure": {"name": "misplaced_flux_fraction", "description": "share of flux in the wrong place"},
    "threshold": 0.1,
    "ranking": [
        {"effect": "tracking", "fitted": {"axis_offset_mrad": 0.52}, "heldout_error_before": 0.4,
         "heldout_error_after": 0.08, "relative_reduction": 0.8, "identifiable": True, "meaningful": True,
         "named_for": "cut"},
        {"effect": "slope_error", "fitted": {"sigma_mrad": 0.86}, "heldout_error_before": 0.08,
         "heldout_error_after": 0.075, "relative_reduction": 0.06, "identifiable": True, "meaningful": True,
         "significance": {"wald": 174.8, "dof": 1, "p": 6.6e-40, "determined": False}, "named_for": "significance"},
        {"effect": "reflectivity", "fitted": {"value": 0.93}, "heldout_error_before": 0.4,
         "heldout_error_after": 0.4, "relative_reduction": -0.001, "identifiable": False},
    ],
    "not_tested": [{"effect": "blocking_shading", "reason": "needs the field geometry"}],
    "signatures": {"rms_centroid_offset_mrad": 0.71, "energy_ratio": 0.99},
    "verdict": "The model lacks a tracking error: fitting tracking cuts held-out error by 80%.",
    "ledger": [{"revision": 1, "model_hash": "abcdef0123456789",
                "model_effects": {"sunshape": {"kind": "pillbox"}},
                "heldout_error": 0.4},
               {"revision": 2, "model_hash": "9876543210fedcba", "model_effects": {"tracking": "fit"},
                "heldout_error": 0.08}],
}
RECOVERY = {"tracking_mrad": {"fitted": [0.1, 0.2], "true": [0.1, 0.25], "max_error": 0.05},
            "surface_mm": {"rms_true": 0.11, "rms_error_over_rms_true": 0.013, "correlation": 0.9999,
                           "facet_correlation": [0.9999]}}
FIELD_METRICS = {"noon": {"ideal": {"flux_accuracy": 0.81, "psnr": 24.5, "peak_flux_error": 0.12,
                                    "intercept": 0.9},
                          "hybrid": {"flux_accuracy": 0.93, "psnr": 31.2, "peak_flux_error": 0.03,
                                     "intercept": 0.91,
                                     "per_heliostat": {"h1": 0.02, "h2": 0.05}}}}


def _benchmark(path: Path, *seconds: float) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    rows = "".join(f"{s}\t0:00:0{int(s)}\t300.5\t700.0\n" for s in seconds)
    path.write_text("s\th:m:s\tmax_rss\tmax_vms\n" + rows)


@pytest.fixture
def files(tmp_path):
    """Every section's inputs as the rules name them, under tmp_path/results/t, and the benchmarks."""
    r = tmp_path / "results" / "t"
    (r / "tables").mkdir(parents=True)
    (r / "tables/table1.md").write_text("**Table 1.** Mean PSNR.\n\n| network | dataset | PSNR train |\n"
                                        "|---|---|---:|\n| nearest | scan | 100.0 |\n")
    (r / "tables/table1.csv").write_text("network,dataset,psnr_train\nnearest,scan,100.0\n")
    (r / "diagnosis").mkdir()
    (r / "diagnosis/scan.json").write_text(json.dumps(DIAGNOSIS))
    (r / "recovery").mkdir()
    (r / "recovery/scan.json").write_text(json.dumps(RECOVERY))
    (r / "field").mkdir()
    (r / "field/metrics.json").write_text(json.dumps(FIELD_METRICS))
    (r / "leave_one_out").mkdir()
    (r / "leave_one_out/aa39.csv").write_text(
        "dataset,id,azimuth_deg,elevation_deg,split,network,psnr,ssim,centroid_mrad,flux_accuracy,misplaced_flux\n"
        "aa39_loo_extra1,extra1,-62.2,23.4,extrapolation,drt,20.634,0.7,3.74,0.6,0.1964\n")
    _benchmark(r / "benchmarks/trace/scan.tsv", 2.5)
    _benchmark(r / "benchmarks/train/scan/nearest.tsv", 1.0, 3.0)
    inputs = {
        "datasets": [_dataset(r / "datasets/scan.h5")],
        "dataset_figures": [_png(r / "figures/datasets/scan.png")],
        "table": [str(r / "tables/table1.md"), str(r / "tables/table1.csv")],
        "samples": [_png(r / "figures/scan/nearest_samples.png")],
        "psnr": [_png(r / "figures/scan/nearest_psnr.png")],
        "data_efficiency": [_png(r / "figures/data_efficiency.png")],
        "recovery": [str(r / "recovery/scan.json")],
        "diagnosis": [str(r / "diagnosis/scan.json")],
        "diagnosis_figures": [_png(r / f"figures/diagnosis/scan_{k}.png")
                              for k in ("signatures", "ranking", "residuals", "location", "ledger")],
        "field": [_png(r / "field/flux.png"), str(r / "field/metrics.json")],
        "leave_one_out": [_png(r / "figures/leave_one_out/aa39.png"), str(r / "leave_one_out/aa39.csv")],
    }
    return inputs, r / "benchmarks"


def _section(text: str, heading: str) -> str:
    return text.split(f"<h2>{heading}</h2>", 1)[1].split("</section>", 1)[0]


def test_report_has_every_section_with_figures_inline_and_no_links_to_files(files, tmp_path):
    inputs, benchmarks = files
    out = tmp_path / "out" / "report.html"
    write_report(out, inputs, benchmarks, "t")
    text = out.read_text()
    assert [p.name for p in out.parent.iterdir()] == ["report.html"]  # one file, no temporary left
    for heading in HEADINGS:
        assert f"<h2>{heading}</h2>" in text and ABSENT not in _section(text, heading)
    pngs = [f for files in inputs.values() for f in files if f.endswith(".png")]
    assert text.count('src="data:image/png;base64,') == len(pngs)
    assert not re.findall(r'(?:src|href)="(?!data:|#)', text)
    assert "<link" not in text and "<script" not in text
    assert 'download="table1.csv" href="data:text/csv;base64,' in text
    assert "<td>scan</td><td>small</td>" in text and "-20.0 … 30.0" in text  # dataset table
    assert '<td class="num">100.0</td>' in _section(text, "Table 1")
    diagnosis = _section(text, "Diagnosis: which effect is missing")
    assert DIAGNOSIS["verdict"] in diagnosis and "axis_offset_mrad = 0.52" in diagnosis
    assert "80 %" in diagnosis and "-0 %" not in diagnosis  # relative reductions
    assert "counts from: relative reduction 10 %" in diagnosis and "needs the field geometry" in diagnosis
    assert "<td>its cut</td>" in diagnosis  # why each selected change is named
    assert "its fitted values (Wald p = 7e-40, value not determined)" in diagnosis
    assert "rms_centroid_offset_mrad" in diagnosis
    recovered = _section(text, "What drt recovered of the true heliostats")
    assert "<h3>scan</h3>" in recovered and "<td>surface_mm</td>" in recovered and "0.013" in recovered
    assert "abcdef012345" in _section(text, "Error ledger")
    field = _section(text, "Field flux maps")
    assert "<td>noon / hybrid</td>" in field and "31.2" in field
    assert "<td>noon / hybrid / per_heliostat</td>" in field
    loo = _section(text, "Leave-one-out on real images")
    assert "<h3>Held-out scores: aa39</h3>" in loo and "<td>extra1</td><td>drt</td>" in loo and ">0.196<" in loo
    runs = _section(text, "Run times")
    assert "<td>train</td><td>scan/nearest</td><td class=\"num\">2.00</td>" in runs  # mean of the repeats
    assert "<td>total</td><td>2 jobs</td><td class=\"num\">4.50</td>" in runs


def test_paint_centroid_checks_are_tabled_in_the_datasets_section(files, tmp_path):
    inputs, _ = files
    path = tmp_path / "aa39_centroids.json"
    row = {"id": "m1", "target": "multi_focus_tower", "azimuth_deg": -12.0, "elevation_deg": 35.0,
           "image_right_mrad": 0.4, "image_up_mrad": -1.25, "image_mrad": 1.31, "utis_mrad": 0.9,
           "spot_angle_deg": {"ideal": 12.0, "measured": 14.5}}
    path.write_text(json.dumps({"units": {"offsets": "mrad"}, "images": [row]}))
    text = _section(build_report({**inputs, "paint_centroids": [str(path)]}, None, "t"), "Datasets")
    assert "<h3>PAINT centroid check: aa39</h3>" in text
    assert "<td>m1</td><td>multi_focus_tower</td>" in text
    assert ">-1.25<" in text and ">14.5<" in text and ">1.31<" in text


def test_a_threshold_of_several_parts_is_listed(tmp_path):
    path = tmp_path / "scan.json"
    threshold = {"relative_reduction": 0.5, "absolute_reduction": 0.01}
    path.write_text(json.dumps({**DIAGNOSIS, "threshold": threshold}))
    text = build_report({"diagnosis": [str(path)]}, None, "t")
    assert "counts from: relative_reduction = 0.5, absolute_reduction = 0.01." in text


def test_sections_the_experiment_leaves_out_say_so(files):
    inputs, _ = files
    text = build_report({"datasets": inputs["datasets"], "dataset_figures": inputs["dataset_figures"],
                         "diagnosis": [], "field": []}, None, "t")
    for heading in HEADINGS[1:-1]:
        assert ABSENT in _section(text, heading), heading
    assert ABSENT not in _section(text, "Datasets")
    assert "No benchmark files yet." in _section(text, "Run times")


def test_bad_inputs_raise_one_clear_error_naming_the_file(tmp_path):
    with pytest.raises(DataError, match="unknown report sections \\['figures'\\]"):
        build_report({"figures": []}, None, "t")
    (tmp_path / "not.png").write_text("hello")
    with pytest.raises(DataError, match="not.png: not a PNG image"):
        build_report({"samples": [str(tmp_path / "not.png")]}, None, "t")
    (tmp_path / "c.json").write_text(json.dumps({"units": {}}))
    with pytest.raises(DataError, match="c.json: not a PAINT centroid check"):
        build_report({"paint_centroids": [str(tmp_path / "c.json")]}, None, "t")
    (tmp_path / "d.json").write_text(json.dumps({"dataset": "scan"}))
    with pytest.raises(DataError, match="d.json: not a diagnosis JSON"):
        build_report({"diagnosis": [str(tmp_path / "d.json")]}, None, "t")
    (tmp_path / "l.csv").write_text("id,network\n1,drt\n")
    with pytest.raises(DataError, match="l.csv: not a leave-one-out CSV"):
        build_report({"leave_one_out": [str(tmp_path / "l.csv")]}, None, "t")
    (tmp_path / "r.json").write_text(json.dumps({"dataset": "scan"}))
    with pytest.raises(DataError, match="r.json: not a recovery JSON"):
        build_report({"recovery": [str(tmp_path / "r.json")]}, None, "t")
    with pytest.raises(DataError, match="missing.json: cannot read report input"):
        build_report({"field": [str(tmp_path / "missing.json")]}, None, "t")
    (tmp_path / "b/rule").mkdir(parents=True)
    (tmp_path / "b/rule/x.tsv").write_text("a\tb\n1\t2\n")
    with pytest.raises(DataError, match="x.tsv: not a snakemake benchmark file"):
        run_times(tmp_path / "b")


def test_nested_numbers_become_tables_grouped_by_columns():
    html = nested_tables({"a": {"x": 1, "y": 2.5}, "b": {"x": 3, "y": None}, "units": "mrad"})
    assert html.count("<table>") == 2
    assert "<td>a</td><td class=\"num\">1</td><td class=\"num\">2.5</td>" in html and "<td>–</td>" in html
    lists = nested_tables({"per_image": {"psnr": [float(i) for i in range(20)],
                                         "split": ["train"] * 15 + ["extra"] * 5,
                                         "few": [1, 27.97843]}})
    assert "20 values, 0 … 19" in lists and "20 values: train 15, extra 5" in lists and "[1, 27.98]" in lists
    wide = nested_tables({"per_heliostat": {f"h{i}": float(i) for i in range(20)}})
    assert wide.count("<tr>") == 21  # transposed: header + one row per heliostat


def test_markdown_renders_paragraphs_bold_and_right_aligned_table_columns():
    html = markdown("**Table 1.** Caption `x`.\n\n| a | b |\n|---|---:|\n| u | 1.0 |\n")
    assert "<p><strong>Table 1.</strong> Caption <code>x</code>.</p>" in html
    assert "<th>a</th><th>b</th>" in html and '<td>u</td><td class="num">1.0</td>' in html


def test_cli_report_writes_the_file(files, tmp_path):
    inputs, benchmarks = files
    out = tmp_path / "cli" / "report.html"
    assert main(["report", "--inputs", json.dumps(inputs), "--benchmarks", str(benchmarks),
                 "--experiment", "t", "--output", str(out)]) == 0
    assert "<h1>helioflow report: experiment t</h1>" in out.read_text()


def test_report_inputs_of_the_tiny_config_list_the_expected_files():
    config = load_config(TINY)
    r = "results/tiny"
    assert all_targets(config) == [f"{r}/report.html"]
    assert report_inputs(config) == {
        "datasets": [f"{r}/datasets/scan.h5", f"{r}/datasets/sky.h5"],
        "dataset_figures": [f"{r}/figures/datasets/scan.png", f"{r}/figures/datasets/sky.png"],
        "paint_centroids": [], "table": [], "samples": [], "psnr": [], "data_efficiency": [], "recovery": [],
        "heliostats": [], "plan": [], "diagnosis": [], "diagnosis_figures": [], "field": [], "aim": [],
        "leave_one_out": [], "plant": [], "plant_plan": [], "plant_flux": [], "plant_shared": [],
        "plant_aim": [],
    }
    config = copy.deepcopy(config)
    config.update(networks={"nearest": {}}, diagnosis={}, field={})
    inputs = report_inputs(config)
    assert inputs["table"] == [f"{r}/tables/table1.md", f"{r}/tables/table1.csv"]
    assert inputs["samples"] == [f"{r}/figures/{d}/nearest_samples.png" for d in ("scan", "sky")]
    assert inputs["diagnosis"] == diagnosis_paths(config)
    assert diagnosis_paths(config) == [f"{r}/diagnosis/{d}.json" for d in ("scan", "sky")]
    assert f"{r}/figures/diagnosis/sky_ledger.png" in inputs["diagnosis_figures"]
    assert len(inputs["diagnosis_figures"]) == 10
    assert inputs["field"] == [f"{r}/field/flux.png", f"{r}/field/metrics.json"]
    assert inputs["recovery"] == [] and inputs["plan"] == []  # drt is not among the networks
    config.update(networks={"drt": {}}, plan={"datasets": ["sky"]})
    assert report_inputs(config)["plan"] == [f"{r}/plan/sky.json"]  # the datasets config `plan` names


def test_recovery_files_are_the_synthetic_datasets_drt_is_scored_on():
    config = copy.deepcopy(load_config(TINY))
    assert recovery_paths(config) == []
    config["networks"] = {"nearest": {}, "drt": {}}
    assert recovery_paths(config) == ["results/tiny/recovery/scan.json", "results/tiny/recovery/sky.json"]
    config["datasets"]["sky"]["source"] = "paint"  # real images: no true heliostat to compare with
    assert recovery_paths(config) == ["results/tiny/recovery/scan.json"]


def test_the_plant_section_shows_what_the_heliostats_share(tmp_path):
    blur = {"value": 1.4159, "sigma": 0.04827, "kept_chi2_per_dof": 1.0,
            "alone": {"P000": {"value": 1.4159, "sigma": 0.04827, "kept": True},
                      "P001": {"value": 1.678, "sigma": 0.04381, "kept": False}}}
    shared = {"plant": {"verdict": "Shared by the 2 heliostats fitted: camera (camera.blur_px = 1.416 +- 0.048).",
                        "shared": [{"effect": "camera", "values": {"camera.blur_px": blur}},
                                   {"effect": "sunshape", "values": {}}],
                        "tried": [{"change": "camera", "heldout_error": 0.0212, "relative_reduction": 0.94,
                                   "meaningful": True},
                                  {"change": "sunshape: buie", "heldout_error": 0.2391, "relative_reduction": 0.32,
                                   "meaningful": False}]}}
    path = tmp_path / "shared.json"
    path.write_text(json.dumps(shared))
    text = _section(build_report({"plant_shared": [str(path)]}, None, "t"), "The plant")
    assert "<h3>Shared by the heliostats of plant</h3>" in text and "camera (camera.blur_px = 1.416" in text
    assert ("<td>camera.blur_px</td><td>1.4159 ± 0.05</td><td>P000 1.416 ± 0.05, P001 1.678 ± 0.04 (own widening)</td>"
            "<td class=\"num\">1.00</td>") in text
    assert "<td>sunshape: buie</td>" in text and ">32 %<" in text
    path.write_text(json.dumps({"plant": {"shared": []}}))
    with pytest.raises(DataError, match="shared.json: not a plant fit"):
        build_report({"plant_shared": [str(path)]}, None, "t")


def _plant_rows(n: int) -> list[dict]:
    """n plant table rows (scoring.plant COLUMNS): heliostat k points k x 0.2 mrad off, names 9 kinds
    of named effects, the last two off (pointing beyond 1 mrad), the first with a canting its fit does
    not determine (flagged, not off)."""
    kinds = ["tracking", "tracking;canting", "tracking;surface", "tracking;slope_error", "canting", "surface",
             "slope_error", "tracking;canting;surface", ""]
    return [{"plant": "plant", "heliostat": f"P{k:03d}", "dataset": f"plant_P{k:03d}", "east_m": 4.0 * k - 20,
             "north_m": 30.0 + k % 3, "images": 16, "heldout_error_ideal": 0.2, "heldout_error_calibrated": 0.05,
             "named_effects": kinds[k % len(kinds)], "pointing_error_mrad": round(0.2 * k, 3),
             "pointing_error_sigma_mrad": 0.01, "canting_rms_mrad": 0.31, "canting_rms_sigma_mrad": 0.02,
             "surface_rms_mm": "", "surface_rms_sigma_mm": "",
             "flags": "pointing > 1 mrad" if k >= n - 2 else "canting not determined" if k == 0 else ""}
            for k in range(n)]


def test_the_plant_section_shows_the_plan_the_worst_heliostats_and_the_plants_flux(tmp_path):
    import csv

    from helioflow.scoring.plant import COLUMNS
    from helioflow.scoring.plant_figure import plot_plant_plan

    rows = _plant_rows(12)
    table = tmp_path / "heliostats.csv"
    with open(table, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=COLUMNS)
        writer.writeheader()
        writer.writerows(rows)
    plan = tmp_path / "plan.png"
    plot_plant_plan(plan, rows, 1.0)  # 9 combinations of named effects: 7 shapes, the rest one
    flux = {"heliostats": 14, "calibrated": ["P000", "P001"], "design_points": {"noon": {
        "calibrated": {"peak_flux_kw_m2": 120.5, "power_on_receiver_kw": 95.1, "intercept": 0.912},
        "ideal": {"flux_accuracy": 0.871, "peak_flux_error": 0.052, "centroid_error_m": 0.031},
        "heliostats": {"P000": {"shift_m": 0.41}, "P001": {"shift_m": 0.07}}}}}
    (tmp_path / "plant.json").write_text(json.dumps(flux))
    files = {"plant": [str(table)], "plant_plan": [str(plan)],
             "plant_flux": [str(tmp_path / "plant.json"), str(plan)]}
    text = _section(build_report(files, None, "t"), "The plant")
    assert '<td>heliostats</td><td class="num">12</td>' in text
    off = "off: pointing beyond the limit, a residual unexplained or an own widening unnamed"
    assert f'<td>{off}</td><td class="num">2</td>' in text
    worst = re.findall(r"<tr><td>(P\d+)</td>", text)
    assert worst[:3] == ["P011", "P010", "P009"]  # by pointing error, largest first
    assert "<td>0.310 ± 0.020</td><td>–</td>" in text
    assert text.count("data:image/png;base64,") == 2 and "coloured by its pointing error" in text
    assert "Flux on the receiver of plant: 14 heliostats, 2 calibrated" in text
    cells = re.sub(r' class="num"', "", text)
    assert "<td>noon</td><td>120.50</td><td>95.1</td><td>0.912</td><td>0.871</td><td>+5.2 %</td>" in cells
    assert cells.index("<td>P000</td><td>noon</td><td>0.410</td>") < cells.index("<td>P001</td><td>noon</td>")
    (tmp_path / "plant.json").write_text(json.dumps({"heliostats": 3}))
    with pytest.raises(DataError, match="plant.json: not a plant flux map"):
        build_report(files, None, "t")
