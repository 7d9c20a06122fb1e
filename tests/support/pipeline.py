"""The pipeline tests' runner (tests/workflow): a work folder beside the repository's Snakefile,
`snakemake` with the venv's commands, the tiny config, and the jobs a dry run schedules."""

import os
import re
import subprocess
import sys
from pathlib import Path

import yaml

from helioflow.config import follow_variant, validate_config
from helioflow.workflow import expand_config

REPO = Path(__file__).resolve().parents[2]
TINY = REPO / "tests" / "workflow" / "tiny_config.yaml"
BIN = Path(sys.executable).parent  # the venv's bin: snakemake and the `helioflow` CLI the rules call


def _workdir(path: Path, config: dict | None = None) -> Path:
    """A fresh folder with the repository's Snakefile and workflow/ (symlinked) and a config."""
    path.mkdir(parents=True, exist_ok=True)
    for name in ("Snakefile", "workflow"):
        (path / name).symlink_to(REPO / name)
    if config is not None:
        (path / "config.yaml").write_text(yaml.safe_dump(config, sort_keys=False))
    return path


def layered(stack: tuple[str, ...], written: dict | None = None) -> dict:
    """config.yaml with the stack's files (paths from the repository root) merged over it as snakemake
    merges `--configfile`s (then `written`, a variant given as a dict), then fitted to what they keep
    (`follow_variant`), validated and expanded, as common.smk does."""
    from snakemake.utils import update_config

    config = yaml.safe_load((REPO / "config.yaml").read_text())
    user: dict = {}
    for path in stack:
        update_config(user, yaml.safe_load((REPO / path).read_text()))
    update_config(user, written or {})
    update_config(config, user)
    follow_variant(config, user)
    return expand_config(validate_config(config, source=" ".join(stack) or "variant"))


PEAK_RSS = ("import resource, subprocess, sys; code = subprocess.call(sys.argv[2:]); "
            "open(sys.argv[1], 'w').write(str(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss)); sys.exit(code)")


def snakemake(workdir: Path, *args: str, timeout: int = 300,
              peak_rss: Path | None = None) -> subprocess.CompletedProcess:
    """`snakemake args` in `workdir` with the venv's commands; `peak_rss`: a file that receives the
    peak resident memory (kB) of snakemake's process."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("SNAKEMAKE")}
    env["PATH"] = f"{BIN}{os.pathsep}{env.get('PATH', '')}"
    command = [str(BIN / "snakemake"), *args]
    if peak_rss is not None:
        command = [sys.executable, "-c", PEAK_RSS, str(peak_rss), *command]
    return subprocess.run(command, cwd=workdir, env=env, capture_output=True, text=True, timeout=timeout)


def _tiny() -> dict:
    return yaml.safe_load(TINY.read_text())


def _scheduled(proc: subprocess.CompletedProcess) -> set[str]:
    """Output files of the jobs a dry run would execute."""
    assert proc.returncode == 0, proc.stderr
    text = proc.stdout + proc.stderr
    return {f for line in re.findall(r"^\s+output: (.+)$", text, re.MULTILINE) for f in line.split(", ")}
