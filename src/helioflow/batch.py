"""A plant's heliostats in groups (config `plant.group_size`): one job runs one step for a group.

Per heliostat the pipeline runs five short-lived steps (import, geometry, train, evaluate,
diagnose); each process starts by importing torch and helioflow (3-5 s), which for a plant of
hundreds was most of the 22 % of job time outside the fits (measured on a 30-heliostat plant,
docs/benchmarks.md). With `plant.group_size: N` the rules in workflow/rules/batches.smk
run each step for N heliostats of a plant entry in one process (`helioflow batch`), writing every
heliostat's outputs and log where the per-heliostat rules write them. A group's job runs on one
torch thread, so that snakemake's -j runs groups side by side (on these small fits two one-thread
jobs do 1.5x the work of one two-thread job). A failed group is rerun whole: group_size 1 keeps
one job per heliostat and step (the default is the schema's, 3).
"""

from __future__ import annotations

import contextlib
import json
import logging
import re
import time
import traceback
from dataclasses import dataclass
from pathlib import Path

from helioflow import workflow
from helioflow.errors import ConfigError, HelioflowError

BATCH_STAGES = ("import", "train", "evaluate", "diagnose")  # in the order a group's jobs run


def plant_batches(config: dict) -> dict[str, list[str]]:
    """{batch: its datasets} of an expanded config: every plant entry's heliostat datasets (in the
    entry's order) in groups of `plant.group_size`, named '<entry>_g<k>'; {} for group_size 1."""
    size = workflow.plant_settings(config)["group_size"]
    if size <= 1:
        return {}
    batches = {}
    for plant, members in workflow.plant_groups(config).items():
        width = len(str((len(members) - 1) // size))
        batches.update({f"{plant}_g{k // size:0{width}d}": members[k:k + size] for k in range(0, len(members), size)})
    return batches


def batched_datasets(config: dict) -> list[str]:
    """The datasets whose steps run in batches (plant_batches): the per-heliostat rules leave them."""
    return [d for members in plant_batches(config).values() for d in members]


def batched_heliostats(config: dict, batches: dict[str, list[str]] | None = None) -> dict[str, str]:
    """{heliostat: the batch whose import job writes its geometry}: the first batch with it (of
    `batches`, default plant_batches)."""
    owner: dict[str, str] = {}
    for batch, members in (plant_batches(config) if batches is None else batches).items():
        for d in members:
            owner.setdefault(workflow.dataset_heliostat(config, d), batch)
    return owner


def unbatched(names, batched: set[str]) -> str:
    """A wildcard regex matching exactly the `names` a per-heliostat rule makes: all but the batched."""
    return workflow.name_pattern([n for n in names if n not in batched])


def rule_name(stage: str, batch: str) -> str:
    """The snakemake rule of a batch's step: '<stage>_batch_<batch>' with '-' and '.' as '_'."""
    return re.sub(r"[^A-Za-z0-9_]", "_", f"{stage}_batch_{batch}")


@dataclass(frozen=True)
class _Plan:
    """What every batch job is planned from, worked out once: the config, its batches, which batch
    writes each heliostat's geometry, the results folder."""

    config: dict
    batches: dict[str, list[str]]
    owner: dict[str, str]
    results: str

    @classmethod
    def of(cls, config: dict) -> _Plan:
        batches = plant_batches(config)
        return cls(config, batches, batched_heliostats(config, batches), workflow.results_dir(config))


def _command(argv: list[str], log: str) -> dict:
    return {"argv": argv, "log": log}


# per imported source: (the CLI step, rule of the dataset, its params and inputs, rule of the geometry, its params)
IMPORTS = {
    "paint": ("import-paint", "import_paint", workflow.import_paint_params, workflow.import_paint_inputs,
              "paint_heliostat", workflow.paint_heliostat_params),
    "images": ("import-images", "import_images", workflow.import_images_params, workflow.import_images_inputs,
               "images_heliostat", workflow.images_heliostat_params),
}


def _import_commands(plan: _Plan, batch: str) -> tuple[list, list, list]:
    config, r = plan.config, plan.results
    commands, inputs, outputs = [], [], []
    for d in plan.batches[batch]:
        step, rule, params, files, geometry_rule, geometry_params = IMPORTS[config["datasets"][d]["source"]]
        dataset = f"{r}/datasets/{d}.h5"
        commands.append(_command([step, "--spec", json.dumps(params(config, d)), "--output", dataset],
                                 f"{r}/logs/{rule}/{d}.log"))
        inputs += [p for ps in files(config, d).values() for p in ([ps] if isinstance(ps, str) else ps)]
        outputs.append(dataset)
        heliostat = workflow.dataset_heliostat(config, d)
        if plan.owner[heliostat] == batch:
            geometry = workflow.heliostat_path(config, d)
            commands.append(_command([step, "--spec", json.dumps(geometry_params(config, heliostat)),
                                      "--heliostat-output", geometry], f"{r}/logs/{geometry_rule}/{heliostat}.log"))
            outputs.append(geometry)
    return commands, list(dict.fromkeys(inputs)), outputs


def _train_commands(plan: _Plan, batch: str) -> tuple[list, list, list]:
    config, r = plan.config, plan.results
    commands, inputs, outputs = [], [], []
    for d in plan.batches[batch]:
        for model in workflow.models(config):
            stem = f"{r}/models/{d}/{model}"
            commands.append(_command(["train", "--spec", json.dumps(workflow.train_params(config, d, model)),
                                      "--dataset", f"{r}/datasets/{d}.h5", "--output", f"{stem}.pt",
                                      "--curve", f"{stem}_curve.csv", "--curve-figure", f"{stem}_curve.png"],
                                     f"{r}/logs/train/{d}/{model}.log"))
            inputs += [p for ps in workflow.train_inputs(config, d, model).values()
                       for p in ([ps] if isinstance(ps, str) else ps)]
            outputs += [f"{stem}.pt", f"{stem}_curve.csv", f"{stem}_curve.png"]
    return commands, list(dict.fromkeys(inputs)), outputs


def _evaluate_commands(plan: _Plan, batch: str) -> tuple[list, list, list]:
    config, r = plan.config, plan.results
    commands, inputs, outputs = [], [], []
    spec = json.dumps(workflow.evaluate_params(config))
    for d in plan.batches[batch]:
        for model in workflow.models(config):
            files = {"--model": f"{r}/models/{d}/{model}.pt", "--dataset": f"{r}/datasets/{d}.h5",
                     "--metrics": f"{r}/metrics/{d}/{model}.json", "--per-image": f"{r}/metrics/{d}/{model}.csv",
                     "--grid": f"{r}/figures/{d}/{model}_samples.png", "--psnr": f"{r}/figures/{d}/{model}_psnr.png"}
            commands.append(_command(["evaluate", "--spec", spec, *(x for kv in files.items() for x in kv)],
                                     f"{r}/logs/evaluate/{d}/{model}.log"))
            inputs += [files["--model"], files["--dataset"]]
            outputs += [p for flag, p in files.items() if flag not in ("--model", "--dataset")]
    return commands, inputs, outputs


DIAGNOSIS_FIGURES = ("signatures", "ranking", "residuals", "location", "ledger")


def _diagnose_commands(plan: _Plan, batch: str) -> tuple[list, list, list]:
    config, r = plan.config, plan.results
    commands, inputs, outputs = [], [], []
    for d in plan.batches[batch]:
        figures = {kind: f"{r}/figures/diagnosis/{d}_{kind}.png" for kind in DIAGNOSIS_FIGURES}
        argv = ["diagnose", "--spec", json.dumps(workflow.diagnose_params(config, d)),
                "--dataset", f"{r}/datasets/{d}.h5", "--heliostat", workflow.heliostat_path(config, d),
                "--output", f"{r}/diagnosis/{d}.json", "--ledger", f"{r}/ledger/{d}.json",
                *(x for kind, path in figures.items()
                  for x in (f"--{kind}-figure" if kind == "ledger" else f"--{kind}", path))]
        commands.append(_command(argv, f"{r}/logs/diagnose/{d}.log"))
        inputs += [f"{r}/datasets/{d}.h5", workflow.heliostat_path(config, d), *workflow.shared_inputs(config, d)]
        outputs += [f"{r}/diagnosis/{d}.json", *figures.values()]
    return commands, list(dict.fromkeys(inputs)), outputs


STAGE_COMMANDS = {"import": _import_commands, "train": _train_commands, "evaluate": _evaluate_commands,
                  "diagnose": _diagnose_commands}


def batch_job(config: dict, stage: str, batch: str) -> dict:
    """One batch's step as a snakemake job: {"commands": [{"argv": helioflow arguments, "log": the
    heliostat's log}], "input": files read, "output": files written, "logs": the heliostats' logs},
    each command the one the per-heliostat rule runs (its paths are those rules' paths)."""
    if stage not in STAGE_COMMANDS:
        raise ConfigError(f"no batched step {stage!r}; steps: {', '.join(BATCH_STAGES)}")
    plan = _Plan.of(config)
    if batch not in plan.batches:
        raise ConfigError(f"no batch {batch!r}; batches: {', '.join(plan.batches) or 'none (plant.group_size 1)'}")
    return _job(plan, stage, batch)


def batch_jobs(config: dict) -> dict[tuple[str, str], dict]:
    """{(step, batch): batch_job} of every batch and step (batch_stages), planned in one pass (a plant
    of thousands has hundreds of them)."""
    plan = _Plan.of(config)
    return {(stage, batch): _job(plan, stage, batch) for batch in plan.batches for stage in batch_stages(config)}


def _job(plan: _Plan, stage: str, batch: str) -> dict:
    commands, inputs, outputs = STAGE_COMMANDS[stage](plan, batch)
    return {"commands": commands, "input": inputs, "output": outputs, "logs": [c["log"] for c in commands]}


def batch_stages(config: dict) -> list[str]:
    """The steps a config's batches run: import, train and evaluate when there are networks, diagnose
    when there is a diagnosis."""
    networks = bool(config.get("networks"))
    return [s for s in BATCH_STAGES if (s not in ("train", "evaluate") or networks)
            and (s != "diagnose" or "diagnosis" in config)]


@contextlib.contextmanager
def _logging_to(path: str):
    """stdout, stderr and the root logger into `path` (truncated), as a rule's `> log 2>&1` would."""
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    root = logging.getLogger()
    with open(path, "w") as stream:
        handler = logging.StreamHandler(stream)
        handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(name)s: %(message)s"))
        saved = root.handlers[:]
        root.handlers = [handler]
        try:
            with contextlib.redirect_stdout(stream), contextlib.redirect_stderr(stream):
                yield stream
        finally:
            root.handlers = saved


def run_batch(commands: list[dict], parse) -> None:
    """Run each {"argv", "log"} of a batch in this process, in order, its output in its log; `parse`
    turns argv into the subcommand's arguments (cli.parser().parse_args). The first that fails
    stops the batch with a HelioflowError naming its log (where its error or traceback is)."""
    log = logging.getLogger(__name__)
    for i, command in enumerate(commands, 1):
        args = parse(command["argv"])
        start = time.perf_counter()
        with _logging_to(command["log"]) as stream:
            try:
                args.func(args)
                failure = None
            except HelioflowError as exc:
                failure = str(exc)
                print(f"helioflow {args.step}: error: {exc}", file=stream)
            except Exception as exc:  # a bug: its traceback goes to the heliostat's log, as in its own job
                failure = f"{type(exc).__name__}: {exc} (traceback in the log)"
                traceback.print_exc(file=stream)
        if failure is not None:
            raise HelioflowError(f"step {i} of {len(commands)}, {args.step} (log {command['log']}): {failure}")
        log.info("%d/%d %s: %.1f s (log %s)", i, len(commands), args.step, time.perf_counter() - start, command["log"])
