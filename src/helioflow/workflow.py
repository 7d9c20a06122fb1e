"""Pure helpers the Snakefile binds: output paths, targets and each rule's parameters.

Each `*_params` function returns exactly the config a rule's output depends on (and nothing
else), so editing one config section reruns only the rules that read it (snakemake's params
rerun trigger), and tests can call them without snakemake.
"""

from __future__ import annotations

import copy
import re
from pathlib import Path

from .errors import ConfigError

PHYSICS_MODELS = ("raytrace", "drt")  # models that trace the heliostat file (models/physical.py)


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


def model_effects(config: dict, dataset: str) -> dict:
    """model.effects with the dataset's `model_effects` entries replacing those of the same name."""
    effects = copy.deepcopy(config["model"].get("effects") or {})
    effects.update(copy.deepcopy(_dataset(config, dataset).get("model_effects") or {}))
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


def paint_datasets(config: dict) -> list[str]:
    """Names of the datasets imported from PAINT (source: paint)."""
    return [d for d, ds in config["datasets"].items() if ds.get("source") == "paint"]


def paint_heliostats(config: dict) -> list[str]:
    """The PAINT heliostat folders the PAINT datasets name, each once, in config order."""
    return list(dict.fromkeys(config["datasets"][d]["heliostat"] for d in paint_datasets(config)))


def name_pattern(names: list[str]) -> str:
    """A wildcard regex matching exactly `names` (one that never matches for none): keeps a rule
    to the datasets or heliostats it can make."""
    return "|".join(re.escape(n) for n in names) or "(?!)"


def import_paint_params(config: dict, dataset: str) -> dict:
    """Parameters of rule `import_paint`: the PAINT folder, image resolution (default
    target.resolution), held-out measurement ids and the target filter."""
    ds = _dataset(config, dataset)
    if ds.get("source") != "paint":
        raise ConfigError(f"dataset {dataset!r} is not imported from PAINT (source: {ds.get('source')})")
    return {
        "dataset": dataset,
        "paint_dir": ds["paint_dir"],
        "heliostat": ds["heliostat"],
        "resolution": list(ds.get("resolution") or config["target"]["resolution"]),
        "holdout": list(ds.get("holdout") or []),
        "targets": ds.get("targets"),
    }


def paint_heliostat_params(config: dict, heliostat: str) -> dict:
    """Parameters of rule `paint_heliostat`: the PAINT directory and folder of the heliostat."""
    for d in paint_datasets(config):
        if config["datasets"][d]["heliostat"] == heliostat:
            return {"paint_dir": config["datasets"][d]["paint_dir"], "heliostat": heliostat}
    raise ConfigError(f"no PAINT dataset takes heliostat {heliostat!r}; PAINT heliostats: "
                      f"{', '.join(paint_heliostats(config)) or 'none'}")


def import_paint_inputs(config: dict, dataset: str) -> dict:
    """Files rule `import_paint` reads: tower-measurements.json, heliostat-properties.json and
    every <id>-calibration-properties.json with its <id>-flux.png of the dataset's heliostat."""
    p = import_paint_params(config, dataset)
    files = _paint_files(p["paint_dir"], p["heliostat"])
    folder = Path(p["paint_dir"]) / p["heliostat"]
    files["measurements"] = [str(f) for c in sorted(folder.glob("*-calibration-properties.json"))
                             for f in (c, c.with_name(c.name.replace("-calibration-properties.json", "-flux.png")))]
    return files


def paint_heliostat_inputs(config: dict, heliostat: str) -> dict:
    """Files rule `paint_heliostat` reads: tower-measurements.json and heliostat-properties.json."""
    return _paint_files(**paint_heliostat_params(config, heliostat))


def _paint_files(paint_dir: str, heliostat: str) -> dict:
    return {"tower": str(Path(paint_dir) / "tower-measurements.json"),
            "properties": str(Path(paint_dir) / heliostat / "heliostat-properties.json")}


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


def train_params(config: dict, dataset: str, model: str) -> dict:
    """Parameters of rule `train`: the network, its settings section, the seed, the train subset;
    a physics model (raytrace, drt) also gets the dataset's model effects and heliostat file."""
    network, count = parse_model(model)
    networks = config.get("networks") or {}
    if network not in networks:
        raise ConfigError(f"unknown network {network!r}: config networks has {', '.join(networks)}")
    settings = copy.deepcopy(networks[network] or {})
    if network in PHYSICS_MODELS:
        settings.update(effects=model_effects(config, dataset), heliostat_path=heliostat_path(config, dataset))
    return {"network": network, "settings": settings, "seed": config["seed"], "train_images": count}


def heliostat_path(config: dict, dataset: str) -> str:
    """surfaces/<heliostat>.h5 of a dataset's heliostat."""
    return f"{results_dir(config)}/surfaces/{dataset_heliostat(config, dataset)}.h5"


def train_inputs(config: dict, dataset: str, model: str) -> dict:
    """Files rule `train` reads: the dataset, and for a physics model the heliostat file."""
    inputs = {"dataset": f"{results_dir(config)}/datasets/{dataset}.h5"}
    if parse_model(model)[0] in PHYSICS_MODELS:
        inputs["heliostat"] = heliostat_path(config, dataset)
    return inputs


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


def diagnosis_paths(config: dict) -> list[str]:
    """diagnosis/<dataset>.json of every dataset when the config has a `diagnosis` section, else none."""
    if "diagnosis" not in config:
        return []
    return [f"{results_dir(config)}/diagnosis/{d}.json" for d in config["datasets"]]


def report_inputs(config: dict) -> dict[str, list[str]]:
    """Files rule `report` reads, by report section; a section the config leaves out is an empty
    list (the report says "not part of this experiment"). Together they are every final output."""
    r = results_dir(config)
    datasets, networks = list(config["datasets"]), list(config.get("networks") or {})
    diagnosed = [Path(p).stem for p in diagnosis_paths(config)]
    efficiency = (config.get("data_efficiency") or {}).get("networks")
    return {
        "datasets": dataset_paths(config),
        "dataset_figures": [f"{r}/figures/datasets/{d}.png" for d in datasets],
        "paint_centroids": [f"{r}/paint/{d}_centroids.json" for d in paint_datasets(config)],
        "table": [f"{r}/tables/table1.md", f"{r}/tables/table1.csv"] if networks else [],
        "samples": [f"{r}/figures/{d}/{m}_samples.png" for d in datasets for m in networks],
        "psnr": [f"{r}/figures/{d}/{m}_psnr.png" for d in datasets for m in networks],
        "data_efficiency": [f"{r}/figures/data_efficiency.png"] if efficiency else [],
        "diagnosis": diagnosis_paths(config),
        "diagnosis_figures": [f"{r}/figures/diagnosis/{d}_{kind}.png" for d in diagnosed
                              for kind in ("signatures", "ranking", "residuals", "ledger")],
        "field": [f"{r}/field/flux.png", f"{r}/field/metrics.json"] if "field" in config else [],
    }


def report_path(config: dict) -> str:
    """results/<experiment>/report.html."""
    return f"{results_dir(config)}/report.html"


def all_targets(config: dict) -> list[str]:
    """What `snakemake all` builds: the report, whose inputs (`report_inputs`) are everything else."""
    return [report_path(config)]
