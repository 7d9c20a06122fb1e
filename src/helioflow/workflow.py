"""Pure helpers the Snakefile binds: output paths, targets and each rule's parameters.

Each `*_params` function returns exactly the config a rule's output depends on (and nothing
else), so editing one config section reruns only the rules that read it (snakemake's params
rerun trigger), and tests can call them without snakemake.
"""

from __future__ import annotations

import copy

from .errors import ConfigError


def results_dir(config: dict) -> str:
    """results/<experiment>."""
    return f"results/{config['experiment']}"


def _dataset(config: dict, dataset: str) -> dict:
    if dataset not in config["datasets"]:
        known = ", ".join(config["datasets"])
        raise ConfigError(f"unknown dataset {dataset!r}: config datasets has {known}")
    return config["datasets"][dataset]


def _heliostat(config: dict, heliostat: str) -> dict:
    if heliostat not in config["heliostats"]:
        known = ", ".join(config["heliostats"])
        raise ConfigError(f"unknown heliostat {heliostat!r}: config heliostats has {known}")
    return config["heliostats"][heliostat]


def dataset_heliostat(config: dict, dataset: str) -> str:
    """Name of the heliostat a dataset is traced from."""
    return _dataset(config, dataset)["heliostat"]


def surfaces_params(config: dict, heliostat: str) -> dict:
    """Parameters of rule `surfaces`: the heliostat's config section and its name."""
    return {"name": heliostat, **copy.deepcopy(_heliostat(config, heliostat))}


def world_effects(config: dict, dataset: str) -> dict:
    """world.effects with the dataset's `world_effects` entries replacing those of the same name."""
    effects = copy.deepcopy(config["world"].get("effects") or {})
    effects.update(copy.deepcopy(_dataset(config, dataset).get("world_effects") or {}))
    return effects


def trace_params(config: dict, dataset: str) -> dict:
    """Parameters of rule `trace`: everything a dataset's images depend on besides the heliostat file."""
    ds = _dataset(config, dataset)
    return {
        "dataset": dataset,
        "heliostat": ds["heliostat"],
        "sun": copy.deepcopy(ds["sun"]),
        "splits": copy.deepcopy(ds["splits"]),
        "trace": copy.deepcopy(ds["trace"]),
        "window_m": ds.get("window_m", "auto"),
        "target": copy.deepcopy(config["target"]),
        "world_effects": world_effects(config, dataset),
        "dni_w_m2": config["dni_w_m2"],
        "seed": config["seed"],
        "device": config["device"],
    }


def dataset_paths(config: dict) -> list[str]:
    """Every configured dataset file."""
    return [f"{results_dir(config)}/datasets/{d}.h5" for d in config["datasets"]]


def all_targets(config: dict) -> list[str]:
    """What `snakemake all` builds."""
    figures = [f"{results_dir(config)}/figures/datasets/{d}.png" for d in config["datasets"]]
    return dataset_paths(config) + figures
