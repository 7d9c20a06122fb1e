"""The pipeline through `snakemake --profile workflow/profiles/slurm` against a real single-node
SLURM (scripts/start_slurm.sh, which .ci/run starts): every job submitted with sbatch, the same
outputs as a local run.

Runs where SLURM answers (`sinfo` shows an idle node); HELIOFLOW_SLURM=1 (set by .ci/run) makes a
missing SLURM a failure instead of a skip.
"""

import json
import os
import shutil
import subprocess
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest
from support.pipeline import _tiny, _workdir, snakemake

from helioflow.data.hdf5 import read_dataset
from helioflow.data.surfaces import read_heliostat

SLURM_ARGS = ("--profile", "workflow/profiles/slurm",
              # this machine's partition, no accounting (start_slurm.sh), the profile's resources otherwise
              "--default-resources", "slurm_partition=helioflow", "mem_mb=1000", "runtime=10",
              "--slurm-no-account", "--slurm-status-command", "squeue",
              "--slurm-init-seconds-before-status-checks", "2", "--seconds-between-status-checks", "2",
              "--jobs", "4")


def _slurm_up() -> bool:
    if shutil.which("sinfo") is None:
        return False
    proc = subprocess.run(["sinfo", "--noheader", "--format=%T"], capture_output=True, text=True, check=False)
    return proc.returncode == 0 and "idle" in proc.stdout.split()


needs_slurm = pytest.mark.skipif(not _slurm_up() and not os.environ.get(
    "HELIOFLOW_SLURM"), reason="no SLURM here: start one with `sudo bash scripts/start_slurm.sh`")


@needs_slurm
@pytest.mark.slow
def test_the_tiny_experiment_through_the_slurm_profile_gives_the_local_outputs(tmp_path):
    assert _slurm_up(), "HELIOFLOW_SLURM is set but sinfo shows no idle node: did scripts/start_slurm.sh run?"
    config = _tiny()
    config["networks"] = {"nearest": {}}
    local, cluster = (_workdir(tmp_path / name, config) for name in ("local", "slurm"))
    with ThreadPoolExecutor(1) as pool:  # the local run meanwhile: the SLURM run mostly waits on sbatch and squeue
        local_run = pool.submit(snakemake, local, "-j1", "all")
        proc = snakemake(cluster, *SLURM_ARGS, "all", timeout=900)
        local_proc = local_run.result()
    assert local_proc.returncode == 0, local_proc.stderr[-3000:]
    assert proc.returncode == 0, (proc.stdout + proc.stderr)[-3000:]
    submitted = (proc.stdout + proc.stderr).count("has been submitted with SLURM jobid")
    assert submitted >= 8, f"{submitted} jobs went through sbatch"  # surfaces, trace, plot, train, evaluate x 2 ...
    r = "results/tiny"
    for dataset, heliostat in (("scan", "small"), ("sky", "small_grid")):
        a, b = (read_dataset(w / f"{r}/datasets/{dataset}.h5") for w in (local, cluster))
        assert np.array_equal(a.images, b.images) and np.array_equal(a.split, b.split)
        a, b = (read_heliostat(w / f"{r}/surfaces/{heliostat}.h5") for w in (local, cluster))
        assert np.array_equal(a.control_heights.numpy(), b.control_heights.numpy())
        a, b = (json.loads((w / f"{r}/metrics/{dataset}/nearest.json").read_text()) for w in (local, cluster))
        assert a["splits"] == b["splits"]
    assert (local / f"{r}/tables/table1.md").read_text() == (cluster / f"{r}/tables/table1.md").read_text()
    assert (cluster / f"{r}/report.html").is_file()
