"""What an expanded config holds: its results folder, its datasets by kind, their heliostats and
effects, the models trained on them, and a plant's settings.
"""

from __future__ import annotations

import copy
import functools
import json
import re
from pathlib import Path

from helioflow.errors import ConfigError
from helioflow.workflow.expansion import FOLD_KEY, PLANT_KEY, fold_datasets, plant_groups
from helioflow.workflow.field import field_measured

IMPORTED_SOURCES = ("paint", "images")  # datasets imported, not traced (no true heliostat behind them)


PHYSICS_MODELS = ("raytrace", "drt")  # models that trace the heliostat file (models/physical.py)


NAME = r"[A-Za-z0-9][A-Za-z0-9_.-]*"  # a dataset or heliostat wildcard (config validation also refuses '..')


def results_dir(config: dict) -> str:
    """results/<experiment>."""
    return f"results/{config['experiment']}"


def check_results_dir(config: dict) -> None:
    """ConfigError when results/<experiment>, or results itself, exists and is not a folder: every
    output of the experiment goes there."""
    path = Path(results_dir(config))
    for folder in (path.parent, path):
        if folder.exists() and not folder.is_dir():
            raise ConfigError(f"{folder} is a file, not a folder: the outputs of experiment "
                              f"{config['experiment']!r} go under {path}/; move the file away or choose another "
                              "experiment name")


def dataset_entry(config: dict, dataset: str) -> dict:
    """Config `datasets.<dataset>`; a ConfigError naming the known datasets for an unknown one."""
    if dataset not in config["datasets"]:
        known = ", ".join(config["datasets"])
        raise ConfigError(f"unknown dataset {dataset!r}: config datasets has {known}")
    return config["datasets"][dataset]


def heliostat_entry(config: dict, heliostat: str) -> dict:
    """Config `heliostats.<heliostat>`; a ConfigError naming the known heliostats for an unknown one."""
    if heliostat not in config["heliostats"]:
        known = ", ".join(config["heliostats"])
        raise ConfigError(f"unknown heliostat {heliostat!r}: config heliostats has {known}")
    return config["heliostats"][heliostat]


def dataset_heliostat(config: dict, dataset: str) -> str:
    """Name of the heliostat a dataset is traced from (or imported with): its `heliostat`, but for
    own images (source: images, whose `heliostat` is the geometry itself) the dataset's name, or
    for a leave-one-out fold its dataset's name (surfaces/<that name>.h5)."""
    ds = dataset_entry(config, dataset)
    if ds.get("source") == "images":
        return ds.get(FOLD_KEY) or dataset
    return ds["heliostat"]


def world_effects(config: dict, dataset: str) -> dict:
    """world.effects with the dataset's `world_effects` entries replacing those of the same name."""
    effects = copy.deepcopy(config["world"].get("effects") or {})
    effects.update(copy.deepcopy(dataset_entry(config, dataset).get("world_effects") or {}))
    return effects


def model_effects(config: dict, dataset: str) -> dict:
    """model.effects with the dataset's `model_effects` entries replacing those of the same name."""
    effects = copy.deepcopy(config["model"].get("effects") or {})
    effects.update(copy.deepcopy(dataset_entry(config, dataset).get("model_effects") or {}))
    return effects


def paint_datasets(config: dict) -> list[str]:
    """Names of the datasets imported from PAINT (source: paint)."""
    return [d for d, ds in config["datasets"].items() if ds.get("source") == "paint"]


def traced_datasets(config: dict) -> list[str]:
    """Names of the datasets the `trace` rule makes (every one not imported: source synthetic)."""
    return [d for d, ds in config["datasets"].items() if ds.get("source") not in IMPORTED_SOURCES]


def images_datasets(config: dict) -> list[str]:
    """Names of the datasets imported from a folder of one's own images (source: images)."""
    return [d for d, ds in config["datasets"].items() if ds.get("source") == "images"]


def images_heliostats(config: dict) -> list[str]:
    """The heliostat files the images datasets write (surfaces/<name>.h5: dataset_heliostat), each
    once, in config order."""
    return list(dict.fromkeys(dataset_heliostat(config, d) for d in images_datasets(config)))


def paint_heliostats(config: dict) -> list[str]:
    """The PAINT heliostat folders the PAINT datasets name, each once, in config order."""
    return list(dict.fromkeys(config["datasets"][d]["heliostat"] for d in paint_datasets(config)))


def name_pattern(names: list[str]) -> str:
    """A wildcard regex matching exactly `names` (one that never matches for none): keeps a rule
    to the datasets or heliostats it can make."""
    return "|".join(re.escape(n) for n in names) or "(?!)"


def centroid_datasets(config: dict) -> list[str]:
    """The PAINT datasets whose centroid check (rule paint_centroids) the report shows: every one
    but the leave-one-out folds (the whole dataset holds their images)."""
    folds = fold_datasets(config)
    return [d for d in paint_datasets(config) if d not in folds]


def models(config: dict) -> list[str]:
    """Model names trained on every dataset: the networks, then the data-efficiency runs."""
    names = list(config.get("networks") or {})
    efficiency = config.get("data_efficiency") or {}
    names += [f"{n}-n{k}" for n in efficiency.get("networks", []) for k in efficiency.get("train_images", [])]
    return names


def network_datasets(config: dict) -> list[str]:
    """The datasets every network is trained and scored on, and diagnosed: all but the field's
    calibration datasets, which train only field.network (see compose_field_inputs)."""
    field = set(field_measured(config))
    return [d for d in config["datasets"] if d not in field]


def has_plant_table(config: dict) -> bool:
    """Whether the config has plant entries (expand_plants) and a diagnosis: a plant table."""
    return bool(plant_groups(config)) and "diagnosis" in config


def plant_settings(config: dict) -> dict:
    """Config `plant` with the schema's defaults filled in (helioflow.schema): how a plant's
    heliostats are fitted (`fit`) and batched (`group_size`), the plant fit (`shared`), the table's
    model and pointing limit, the flux maps (`flux`). A fresh copy each call; the parameter
    functions ask for it per heliostat, so the filling is done once per distinct section."""
    return json.loads(_filled_plant(json.dumps(config.get("plant"), sort_keys=True)))


@functools.lru_cache(maxsize=16)
def _filled_plant(section: str) -> str:
    """plant_settings of a `plant` section given as JSON, as JSON."""
    from helioflow.schema import with_defaults

    return json.dumps(with_defaults(json.loads(section), "plant"))


def plant_shared_settings(config: dict) -> dict | None:
    """The plant fit's settings (config plant.shared, with the schema's defaults), None when the
    config has no plant entry or sets `plant.shared: false` (each heliostat fitted alone)."""
    if not _plant_fit_wanted(config) or not plant_groups(config):
        return None
    return plant_settings(config)["shared"]


def _plant_fit_wanted(config: dict) -> bool:
    """Whether a plant's heliostats are fitted with the plant fit (`plant.shared` is not false)."""
    return plant_settings(config)["shared"] is not False


def plant_shared_file(config: dict) -> str:
    """plant/shared.json: the plant fit's output (rule plant_shared)."""
    return f"{results_dir(config)}/plant/shared.json"


def shared_of(config: dict, dataset: str) -> dict | None:
    """{"path": plant/shared.json, "plant": its entry} for a heliostat of a plant whose shared effects
    the plant fit sets (rules train and diagnose take them from there: the key `shared` of their
    specs, absent for every other dataset), else None."""
    ds = config["datasets"][dataset]
    # a plant heliostat's dataset: its plant exists, so the fit runs where wanted (plant_shared_settings),
    # decided without going over every dataset (snakemake asks for every job)
    if PLANT_KEY not in ds or FOLD_KEY in ds or not _plant_fit_wanted(config):
        return None
    return {"path": plant_shared_file(config), "plant": ds[PLANT_KEY]}


def paint_plant_groups(config: dict) -> dict[str, list[str]]:
    """plant_groups of the PAINT plant entries: only a PAINT directory holds the whole field's geometry
    (an images plant's CSV and properties files hold its calibrated heliostats only), so only these
    get a flux map."""
    return {p: m for p, m in plant_groups(config).items() if config["datasets"][m[0]]["source"] == "paint"}


def plant_flux_settings(config: dict) -> dict | None:
    """The plant flux maps' settings (config plant.flux, with the schema's defaults), None when there
    is no plant table (has_plant_table) or `plant.flux: false`."""
    flux = plant_settings(config)["flux"]
    if not has_plant_table(config) or flux is False:
        return None
    return flux
