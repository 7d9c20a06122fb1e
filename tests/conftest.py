"""Fixtures shared by the test folders."""

import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch
import yaml

from helioflow.models.training import train

if os.environ.get("PYTEST_XDIST_WORKER"):  # a worker beside others (pyproject: -n auto): one core each, as the
    torch.set_num_threads(1)               # pipeline's jobs (torch_threads 1); two threads each would oversubscribe


class Stopped(Exception):
    """Stands for a killed training job."""


@pytest.fixture
def train_stopped_after():
    """`train(model, data, loop, checkpoint, steps_done)`: the training loop, stopped (as by a kill)
    once `steps_done` steps are done; what it leaves is the checkpoint it wrote by then."""

    def run(model, data, loop, checkpoint, steps_done: int) -> None:
        step = model.training_step
        calls = iter(range(steps_done + 1))

        def counted(*args, **kwargs):
            if next(calls) == steps_done:
                raise Stopped
            return step(*args, **kwargs)

        model.training_step = counted
        with pytest.raises(Stopped):
            train(model, data, loop, checkpoint, progress=False)

    return run


SNAKEMAKE = Path(sys.executable).parent / "snakemake"
REPO = Path(__file__).resolve().parents[1]


@pytest.fixture
def dry_run(tmp_path):
    """`dry_run(config, *flags)`: `snakemake -n all *flags` on `config` (a dict, written as config.yaml
    beside links to the repository's Snakefile and workflow in tmp_path); asserts it succeeds and
    returns its output (stdout and stderr). snakemake is a requirement (requirements.txt): without it
    the test fails."""
    assert SNAKEMAKE.exists(), f"{SNAKEMAKE} is missing: install requirements.txt into this env"

    def run(config: dict, *flags: str) -> str:
        for name in ("Snakefile", "workflow"):
            if not (tmp_path / name).exists():
                (tmp_path / name).symlink_to(REPO / name)
        (tmp_path / "config.yaml").write_text(yaml.safe_dump(config))
        env = {k: v for k, v in os.environ.items() if not k.startswith("SNAKEMAKE")}
        env["PATH"] = f"{SNAKEMAKE.parent}{os.pathsep}{env.get('PATH', '')}"
        proc = subprocess.run([str(SNAKEMAKE), "-n", "all", *flags], cwd=tmp_path, env=env, capture_output=True,
                              text=True, timeout=300, check=False)
        assert proc.returncode == 0, proc.stderr
        return proc.stdout + proc.stderr

    return run
