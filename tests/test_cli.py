"""`helioflow <step>`: user errors print one line `helioflow <step>: error: ...` and exit with 2."""

import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from helioflow.cli import main
from helioflow.config import load_config
from helioflow.data.hdf5 import read_dataset
from helioflow.data.synthetic import config_hash
from helioflow.workflow import trace_params

REPO = Path(__file__).resolve().parents[1]
TINY = REPO / "tests" / "workflow" / "tiny_config.yaml"
BIN = Path(sys.executable).parent  # the venv's bin, where the `helioflow` script lives


@pytest.fixture(autouse=True)
def _keep_torch_threads():
    """main() sets torch's thread count; restore it for the other tests of this process."""
    threads = torch.get_num_threads()
    yield
    torch.set_num_threads(threads)


def _one_error_line(stderr: str, step: str) -> str:
    lines = stderr.strip().splitlines()
    assert len(lines) == 1, stderr
    assert lines[0].startswith(f"helioflow {step}: error: ")
    return lines[0]


def test_trace_with_a_missing_heliostat_file_exits_2_naming_it(tmp_path):
    missing = tmp_path / "surfaces" / "nothing_here.h5"
    out = tmp_path / "x.h5"
    env = {**os.environ, "PATH": f"{BIN}{os.pathsep}{os.environ.get('PATH', '')}"}
    proc = subprocess.run(
        ["helioflow", "trace", "--config", str(TINY), "--name", "scan", "--heliostat", str(missing),
         "--output", str(out)],
        capture_output=True, text=True, env=env, cwd=tmp_path, timeout=120,
    )
    assert proc.returncode == 2
    line = _one_error_line(proc.stderr, "trace")
    assert str(missing) in line and "does not exist" in line
    assert proc.stdout == ""
    assert not out.exists() and not list(tmp_path.rglob("*.h5"))


def test_surfaces_with_an_unknown_heliostat_exits_2_listing_the_known_ones(tmp_path, capsys):
    out = tmp_path / "s.h5"
    assert main(["surfaces", "--config", str(TINY), "--name", "nope", "--output", str(out)]) == 2
    line = _one_error_line(capsys.readouterr().err, "surfaces")
    assert "'nope'" in line and "small, small_grid" in line
    assert not out.exists()


def test_a_bad_config_file_exits_2_naming_file_key_and_value(tmp_path, capsys):
    bad = tmp_path / "bad.yaml"
    bad.write_text(TINY.read_text().replace("mount: juelich", "mount: foo"))
    out = tmp_path / "s.h5"
    assert main(["surfaces", "--config", str(bad), "--name", "small", "--output", str(out)]) == 2
    line = _one_error_line(capsys.readouterr().err, "surfaces")
    assert str(bad) in line and "heliostats.small_grid.mount = 'foo'" in line and "az_el, juelich" in line


@pytest.mark.parametrize("argv, says", [
    (["trace", "--spec", "{not json", "--heliostat", "h.h5", "--output", "o.h5"], "Expecting property name"),
    (["trace", "--heliostat", "h.h5", "--output", "o.h5"], "--config FILE and --name NAME"),
], ids=["spec not JSON", "neither spec nor config"])
def test_bad_arguments_exit_2_with_one_line(tmp_path, monkeypatch, capsys, argv, says):
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 2
    assert says in _one_error_line(capsys.readouterr().err, "trace")
    assert not list(tmp_path.iterdir())


def test_by_hand_steps_match_what_the_pipeline_would_trace(tmp_path):
    """`--config FILE --name NAME` runs the same step with the same parameters as the Snakefile's --spec."""
    surfaces, dataset = tmp_path / "small.h5", tmp_path / "scan.h5"
    assert main(["surfaces", "--config", str(TINY), "--name", "small", "--output", str(surfaces)]) == 0
    assert main(["trace", "--config", str(TINY), "--name", "scan", "--heliostat", str(surfaces),
                 "--output", str(dataset)]) == 0
    ds = read_dataset(dataset)
    assert ds.images.shape == (6, 16, 16)
    assert ds.attrs["config_hash"] == config_hash(trace_params(load_config(TINY), "scan"))


def test_help_answers_without_loading_torch():
    """`helioflow --help` and each subcommand's help come from the parser alone: no torch import
    (which takes seconds), so they answer at once."""
    code = ("import sys; from helioflow.cli import parser; p = parser(); p.format_help(); "
            "[a.choices[c].format_help() for a in p._subparsers._group_actions for c in a.choices]; "
            "print('torch' in sys.modules)")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert proc.stdout.strip() == "False", proc.stderr
