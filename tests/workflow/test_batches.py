"""A plant's heliostats in groups (config plant.group_size, helioflow/batch.py): one job per group and
step runs exactly the commands the per-heliostat rules would, in one process, each into its own log."""

import json
import re
import shlex
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import h5py
import numpy as np
import pytest
import yaml

from helioflow.batch import batch_job, plant_batches, run_batch
from helioflow.config import validate_config
from helioflow.errors import ConfigError, HelioflowError
from helioflow.workflow import expand_config

REPO = Path(__file__).resolve().parents[2]
PAINT = REPO / "tests" / "data" / "paint"


def _config(group_size: int) -> dict:
    config = yaml.safe_load((REPO / "tests" / "workflow" / "tiny_config.yaml").read_text())
    config["datasets"]["jul"] = {"source": "paint", "paint_dir": str(PAINT), "resolution": [16, 16],
                                 "heliostats": "all"}
    config.update(networks={"drt": {}, "nearest": {}}, diagnosis={}, plant={"group_size": group_size})
    return config


def test_a_plants_heliostats_go_in_groups_of_group_size_in_the_entrys_order():
    config = expand_config(validate_config(_config(2)))
    assert plant_batches(config) == {"jul_g0": ["jul_AA31", "jul_AA39"], "jul_g1": ["jul_AC43", "jul_AD37"],
                                     "jul_g2": ["jul_AU46"]}
    assert plant_batches(expand_config(validate_config(_config(1)))) == {}  # the default: one job per heliostat
    job = batch_job(config, "diagnose", "jul_g2")
    assert job["logs"] == ["results/tiny/logs/diagnose/jul_AU46.log"]
    assert "results/tiny/plant/shared.json" in job["input"] and "results/tiny/diagnosis/jul_AU46.json" in job["output"]
    with pytest.raises(ConfigError, match="no batch 'jul_g3'; batches: jul_g0, jul_g1, jul_g2"):
        batch_job(config, "train", "jul_g3")


def _commands(output: str) -> set[tuple[tuple[str, ...], str]]:
    """(helioflow arguments after --threads, log) of every helioflow command a `snakemake -n -p` printed,
    a batch's commands each on its own."""
    found = set()
    for line in output.splitlines():
        if not line.startswith("helioflow "):
            continue
        words = shlex.split(line)
        redirect = words.index(">")
        argv, log = words[3:redirect], words[redirect + 1]
        if argv[0] == "batch":
            found |= {(tuple(c["argv"]), c["log"]) for c in json.loads(argv[2])}
        else:
            found.add((tuple(argv), log))
    return found


def test_a_group_runs_the_per_heliostat_rules_commands_and_the_rest_runs_as_before(dry_run):
    alone = _commands(dry_run(_config(1), "-p"))
    output = dry_run(_config(2), "-p")
    grouped = _commands(output)
    assert grouped == alone  # the same steps with the same arguments and logs, whichever job runs them
    jobs = dict(re.findall(r"^(\w+)\s+(\d+)$", output, re.MULTILINE))
    for stage in ("import", "train", "evaluate", "diagnose"):
        assert jobs[f"{stage}_batch_jul_g0"] == jobs[f"{stage}_batch_jul_g1"] == "1"
    # the per-heliostat rules keep the other datasets: tiny's two traced ones, two networks each
    assert "import_paint" not in jobs and "paint_heliostat" not in jobs
    assert jobs["train"] == "4" and jobs["evaluate"] == "4" and jobs["diagnose"] == "2"


def _moved(command: dict, folder: Path) -> dict:
    """A command with its outputs and log (results/... paths) in `folder`."""
    def move(arg: str) -> str:
        return str(folder / Path(arg).name) if arg.startswith("results/") else arg
    return {"argv": [move(a) for a in command["argv"]], "log": move(command["log"])}


def test_a_batch_writes_what_its_steps_write_alone(tmp_path):
    """The import step of two heliostats in one process against each step in its own: the same data."""
    config = expand_config(validate_config(_config(2)))
    commands = batch_job(config, "import", "jul_g0")["commands"]
    batched = [_moved(c, tmp_path / "batch") for c in commands]
    (tmp_path / "commands.json").write_text(json.dumps(batched))
    subprocess.run([sys.executable, "-m", "helioflow", "batch", "--commands", f"@{tmp_path / 'commands.json'}"],
                   check=True, capture_output=True, text=True)
    (tmp_path / "alone").mkdir()
    for c in commands:
        subprocess.run([sys.executable, "-m", "helioflow", *_moved(c, tmp_path / "alone")["argv"]], check=True,
                       capture_output=True, text=True)
    assert all("wrote" in Path(c["log"]).read_text() for c in batched)  # each step's own log
    names = sorted(p.name for p in (tmp_path / "batch").glob("*.h5"))
    assert names == ["AA31.h5", "AA39.h5", "jul_AA31.h5", "jul_AA39.h5"]
    for name in names:
        with h5py.File(tmp_path / "batch" / name) as a, h5py.File(tmp_path / "alone" / name) as b:
            arrays = [k for k in _keys(a) if isinstance(a[k], h5py.Dataset)]
            assert arrays and _keys(a) == _keys(b)
            for key in arrays:
                assert np.array_equal(a[key][()], b[key][()]), (name, key)


def _keys(group) -> list[str]:
    keys = []
    group.visit(keys.append)
    return sorted(keys)


def test_the_first_failing_step_stops_the_batch_with_one_error_naming_its_log(tmp_path):
    ran = []

    def step(name, fail=None):
        def func(args):
            ran.append(name)
            print(f"{name} ran")
            if fail is not None:
                raise fail
        return SimpleNamespace(step=name, func=func)

    steps = {"a": step("a"), "b": step("b", HelioflowError("datasets/x.h5: not an HDF5 file")), "c": step("c")}
    commands = [{"argv": [k], "log": str(tmp_path / f"{k}.log")} for k in steps]
    with pytest.raises(HelioflowError, match=rf"step 2 of 3, b \(log {re.escape(str(tmp_path))}/b.log\): "
                                             r"datasets/x.h5: not an HDF5 file"):
        run_batch(commands, lambda argv: steps[argv[0]])
    assert ran == ["a", "b"] and (tmp_path / "a.log").read_text() == "a ran\n"
    assert (tmp_path / "b.log").read_text() == "b ran\nhelioflow b: error: datasets/x.h5: not an HDF5 file\n"
    steps["b"] = step("b", KeyError("images"))  # a bug: its traceback in the step's log, one line out
    with pytest.raises(HelioflowError, match=r"KeyError: 'images' \(traceback in the log\)"):
        run_batch(commands, lambda argv: steps[argv[0]])
    assert "Traceback" in (tmp_path / "b.log").read_text()
