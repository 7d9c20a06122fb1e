"""The real Snakemake DAG on the tiny config (tests/workflow/tiny_config.yaml) in a temporary folder:
outputs, up-to-date detection, reruns limited to what a config edit touches, config errors, lint."""

import re
import shutil
from pathlib import Path

import pytest
import yaml
from support.pipeline import REPO, TINY, _scheduled, _tiny, _workdir, snakemake

from helioflow.data.hdf5 import read_dataset

ACCEPTED_LINTS = {"Specify a conda environment or container for each rule."}


def _dry_run(workdir: Path, config: dict, name: str) -> set[str]:
    (workdir / name).write_text(yaml.safe_dump(config, sort_keys=False))
    return _scheduled(snakemake(workdir, "-n", "all", "--configfile", name))


@pytest.fixture(scope="module")
def pipeline(tmp_path_factory):
    """`snakemake -j2 all` on the tiny config (2 heliostats, 2 datasets of 6 images of 16 x 16)."""
    workdir = _workdir(tmp_path_factory.mktemp("pipeline"))
    shutil.copy(TINY, workdir / "tiny_config.yaml")
    proc = snakemake(workdir, "-j2", "all", "--configfile", "tiny_config.yaml")
    assert proc.returncode == 0, proc.stderr[-4000:]
    return workdir


R = "results/tiny"
REPORT = f"{R}/report.html"
DATASETS = {"scan": "small", "sky": "small_grid"}


@pytest.mark.slow
def test_all_builds_datasets_figures_logs_and_benchmarks(pipeline):
    for dataset, heliostat in DATASETS.items():
        ds = read_dataset(pipeline / f"{R}/datasets/{dataset}.h5")
        assert ds.images.shape == (6, 16, 16) and ds.images.min() >= 0
        assert (ds.attrs["dataset"], ds.attrs["heliostat"]) == (dataset, heliostat)
        assert (pipeline / f"{R}/figures/datasets/{dataset}.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        assert (pipeline / f"{R}/surfaces/{heliostat}.h5").is_file()
        for rule, name in (("surfaces", heliostat), ("trace", dataset), ("plot_dataset", dataset)):
            assert "wrote" in (pipeline / f"{R}/logs/{rule}/{name}.log").read_text()
            assert (pipeline / f"{R}/benchmarks/{rule}/{name}.tsv").read_text().startswith("s\th:m:s")
    assert not list(pipeline.rglob("*.tmp.*"))
    assert sorted(p.name for p in (pipeline / "results").iterdir()) == ["tiny"]


@pytest.mark.slow
def test_all_builds_the_self_contained_report_with_every_section(pipeline):
    text = (pipeline / REPORT).read_text()
    for heading in ("Datasets", "Table 1", "Sample grids", "PSNR against sun position",
                    "Diagnosis: which effect is missing", "Error ledger", "Field flux maps", "Run times"):
        assert f"<h2>{heading}</h2>" in text
    assert text.count('src="data:image/png;base64,') == len(DATASETS)
    assert not re.findall(r'(?:src|href)="(?!data:|#)', text)
    assert "Not part of this experiment." in text  # the tiny config has no networks, diagnosis or field
    for dataset, heliostat in DATASETS.items():
        assert f"<td>{dataset}</td><td>{heliostat}</td>" in text
    for rule in ("surfaces", "trace", "plot_dataset"):
        assert f"<td>{rule}</td>" in text
    assert (pipeline / f"{R}/benchmarks/report/report.tsv").is_file()


@pytest.mark.slow
def test_a_second_run_has_nothing_to_do(pipeline):
    proc = snakemake(pipeline, "-n", "all", "--configfile", "tiny_config.yaml")
    assert proc.returncode == 0 and "Nothing to be done" in proc.stdout + proc.stderr
    assert _scheduled(proc) == set()


@pytest.mark.slow
def test_editing_one_dataset_reruns_only_its_trace_and_plot(pipeline):
    config = _tiny()
    config["datasets"]["sky"]["trace"]["rays"] = 5000
    assert _dry_run(pipeline, config, "edited_sky.yaml") == {f"{R}/datasets/sky.h5",
                                                              f"{R}/figures/datasets/sky.png", REPORT}
    config = _tiny()
    config["datasets"]["scan"]["sun"]["n"] = 7
    assert _dry_run(pipeline, config, "edited_scan.yaml") == {f"{R}/datasets/scan.h5",
                                                               f"{R}/figures/datasets/scan.png", REPORT}


@pytest.mark.slow
def test_editing_a_heliostat_reruns_its_surfaces_and_its_datasets_only(pipeline):
    config = _tiny()
    config["heliostats"]["small_grid"]["deformation_mm"] = 0.3
    assert _dry_run(pipeline, config, "edited_heliostat.yaml") == {
        f"{R}/surfaces/small_grid.h5", f"{R}/datasets/sky.h5", f"{R}/figures/datasets/sky.png", REPORT}


@pytest.mark.slow
def test_editing_shared_physics_reruns_every_trace_but_no_surfaces(pipeline):
    config = _tiny()
    config["world"]["effects"]["slope_error"]["sigma_mrad"] = 0.7
    assert _dry_run(pipeline, config, "edited_world.yaml") == {REPORT} | {
        f"{R}/datasets/{d}.h5" for d in DATASETS} | {f"{R}/figures/datasets/{d}.png" for d in DATASETS}


def test_a_bad_config_stops_snakemake_with_a_clear_message(tmp_path):
    config = _tiny()
    config["heliostats"]["small"]["mount"] = "foo"
    workdir = _workdir(tmp_path / "run", config)
    proc = snakemake(workdir, "-j1", "all")
    assert proc.returncode != 0
    assert "helioflow: config: " in proc.stderr
    assert "heliostats.small.mount = 'foo'" in proc.stderr and "az_el, juelich" in proc.stderr
    assert "Traceback" not in proc.stderr
    assert not (workdir / "results").exists()


def test_lint_reports_only_the_accepted_lints(tmp_path):
    workdir = _workdir(tmp_path / "lint")
    shutil.copy(REPO / "config.yaml", workdir / "config.yaml")
    proc = snakemake(workdir, "--lint")
    text = proc.stdout + proc.stderr
    assert "Traceback" not in text and "Error" not in text, text
    lints = set(re.findall(r"^\s+\* (.+?):$", text, re.MULTILINE))
    assert proc.returncode == 0 or lints, text  # a non-zero exit must come with parsed lints
    assert lints <= ACCEPTED_LINTS, text
