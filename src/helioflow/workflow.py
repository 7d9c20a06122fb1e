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


def parse_model(model: str) -> tuple[str, int | None]:
    """'cgan' -> ('cgan', None); 'cgan-n25' -> ('cgan', 25): a network trained on 25 train images."""
    network, sep, count = model.partition("-n")
    if sep and not count.isdigit():
        raise ConfigError(f"model name {model!r}: expected <network> or <network>-n<train images>")
    return network, int(count) if sep else None


def models(config: dict) -> list[str]:
    """Model names trained on every dataset: the networks, then the data-efficiency runs."""
    names = list(config.get("networks") or {})
    efficiency = config.get("data_efficiency") or {}
    names += [f"{n}-n{k}" for n in efficiency.get("networks", []) for k in efficiency.get("train_images", [])]
    return names


def train_params(config: dict, model: str) -> dict:
    """Parameters of rule `train`: the network, its settings section, the seed, the train subset."""
    network, count = parse_model(model)
    networks = config.get("networks") or {}
    if network not in networks:
        raise ConfigError(f"unknown network {network!r}: config networks has {', '.join(networks)}")
    return {"network": network, "settings": copy.deepcopy(networks[network] or {}), "seed": config["seed"],
            "train_images": count}


def evaluate_params(config: dict) -> dict:
    """Parameters of rule `evaluate`."""
    return copy.deepcopy(config.get("evaluation") or {})


def metrics_paths(config: dict, include_efficiency: bool = False) -> list[str]:
    """metrics/<dataset>/<model>.json of every trained network (and data-efficiency run)."""
    names = models(config) if include_efficiency else list(config.get("networks") or {})
    return [f"{results_dir(config)}/metrics/{d}/{m}.json" for d in config["datasets"] for m in names]


def efficiency_metrics(config: dict) -> list[str]:
    """The metrics files the data-efficiency figure reads."""
    plain = set(metrics_paths(config))
    return [p for p in metrics_paths(config, include_efficiency=True) if p not in plain]


def all_targets(config: dict) -> list[str]:
    """What `snakemake all` builds."""
    r = results_dir(config)
    figures = [f"{r}/figures/datasets/{d}.png" for d in config["datasets"]]
    targets = dataset_paths(config) + figures
    if config.get("networks"):
        targets += metrics_paths(config) + [f"{r}/tables/table1.md"]
    if (config.get("data_efficiency") or {}).get("networks"):
        targets += [f"{r}/figures/data_efficiency.png"]
    return targets
