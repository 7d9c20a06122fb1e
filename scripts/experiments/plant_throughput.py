"""Where a plant run's time goes: heliostats per hour and the share spent outside the fits, from
snakemake's benchmark files of one experiment and the wall time snakemake printed.

The fits are the jobs that fit (train, diagnose, plant_shared, and the batched train and diagnose of
a plant in groups, config plant.group_size) less each one's process start-up (the Python and torch
imports, `--startup-s`, measured apart with `python -c "import torch, helioflow.cli"`); everything
else (imports of the PAINT folders, evaluation, tables, flux maps, the report, the start-ups) is
outside them. The heliostats are the rows of plant/heliostats.csv.

Run: python scripts/experiments/plant_throughput.py RESULTS_DIR SNAKEMAKE_LOG [--startup-s 2.5]
"""

from __future__ import annotations

import argparse
import re
from collections import defaultdict
from pathlib import Path

FITS = ("train", "diagnose", "plant_shared", "batch_train", "batch_diagnose")


def job_seconds(results: Path) -> dict[str, list[float]]:
    """{rule: [wall s of each job]} from results/benchmarks/<rule>/**.tsv (first column, first row)."""
    out = defaultdict(list)
    for tsv in sorted((results / "benchmarks").rglob("*.tsv")):
        rule = tsv.relative_to(results / "benchmarks").parts[0]
        out[rule].append(float(tsv.read_text().splitlines()[1].split("\t")[0]))
    return dict(out)


def elapsed_s(log: Path) -> float:
    """The wall time of a snakemake run from its printed 'Elapsed time: H:MM:SS.s'."""
    found = re.findall(r"Elapsed time: (\d+):(\d+):([\d.]+)", log.read_text())
    if not found:
        raise SystemExit(f"{log}: no 'Elapsed time' line (a finished snakemake run's output)")
    h, m, s = found[-1]
    return 3600 * int(h) + 60 * int(m) + float(s)


def main() -> None:
    """Parse the command line and run the measurement the module docstring describes."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("results")
    ap.add_argument("log")
    ap.add_argument("--startup-s", type=float, default=2.5, help="one job's Python and torch start-up (s)")
    args = ap.parse_args()
    jobs = job_seconds(Path(args.results))
    wall = elapsed_s(Path(args.log))
    heliostats = len((Path(args.results) / "plant" / "heliostats.csv").read_text().splitlines()) - 1
    total = sum(map(sum, jobs.values()))
    fit_jobs = sum(len(jobs.get(r, [])) for r in FITS)
    fits = sum(sum(jobs.get(r, [])) for r in FITS) - fit_jobs * args.startup_s
    print(f"{heliostats} heliostats in {wall / 60:.1f} min wall: {heliostats / wall * 3600:.0f} heliostats per hour; "
          f"{total:.0f} s of jobs, {total / wall:.2f} jobs running on average")
    print(f"fits (less {args.startup_s} s start-up per fit job): {fits:.0f} s = {100 * fits / total:.0f} %; "
          f"outside the fits {100 * (1 - fits / total):.0f} %")
    print("| rule | jobs | s | s per job | share |\n|---|---|---|---|---|")
    for rule, values in sorted(jobs.items(), key=lambda kv: -sum(kv[1])):
        print(f"| {rule} | {len(values)} | {sum(values):.0f} | {sum(values) / len(values):.1f} | "
              f"{100 * sum(values) / total:.0f} % |")


if __name__ == "__main__":
    main()
