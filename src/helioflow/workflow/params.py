"""Each rule's parameters: exactly the config a rule's output depends on (and nothing else), so
that editing one config section reruns only the rules that read it (snakemake's params rerun
trigger); with the inputs of the import rules, which follow from them.
"""

from __future__ import annotations

import copy
from pathlib import Path

from helioflow.errors import ConfigError
from helioflow.models.names import parse_model
from helioflow.workflow.datasets import (
    PHYSICS_MODELS,
    dataset_entry,
    dataset_heliostat,
    heliostat_entry,
    images_datasets,
    images_heliostats,
    model_effects,
    paint_heliostats,
    plant_settings,
    shared_of,
    world_effects,
)
from helioflow.workflow.expansion import PLANT_KEY
from helioflow.workflow.field import field_measured, field_names, field_positions
from helioflow.workflow.paths import heliostat_path


def surfaces_params(config: dict, heliostat: str) -> dict:
    """Parameters of rule `surfaces`: the heliostat's config section and its name."""
    return {"name": heliostat, **copy.deepcopy(heliostat_entry(config, heliostat))}


def trace_params(config: dict, dataset: str) -> dict:
    """Parameters of rule `trace`: everything a dataset's images depend on besides the heliostat file."""
    ds = dataset_entry(config, dataset)
    return {
        "dataset": dataset,
        "heliostat": ds["heliostat"],
        "sun": copy.deepcopy(ds["sun"]),
        "splits": copy.deepcopy(ds["splits"]),
        "trace": copy.deepcopy(ds["trace"]),
        "window_m": ds["window_m"],
        "target": copy.deepcopy(config["target"]),
        "world_effects": world_effects(config, dataset),
        "dni_w_m2": config["dni_w_m2"],
        "seed": config["seed"],
        "device": config["device"],
    }


def import_paint_params(config: dict, dataset: str) -> dict:
    """Parameters of rule `import_paint`: the PAINT folder, image resolution (default
    target.resolution), held-out measurement ids, the target filter, the nominal DNI and what becomes
    of the measurements with only a centered image (`centered`, default place)."""
    from helioflow.data.paint import CENTERED_DEFAULT

    ds = dataset_entry(config, dataset)
    if ds.get("source") != "paint":
        raise ConfigError(f"dataset {dataset!r} is not imported from PAINT (source: {ds.get('source')})")
    return {
        "dataset": dataset,
        "paint_dir": ds["paint_dir"],
        "heliostat": ds["heliostat"],
        "resolution": list(ds.get("resolution") or config["target"]["resolution"]),
        "holdout": copy.deepcopy(ds.get("holdout") or []),
        "targets": ds.get("targets"),
        "dni_w_m2": config["dni_w_m2"],
        "centered": ds.get("centered", CENTERED_DEFAULT),
    }


def paint_heliostat_params(config: dict, heliostat: str) -> dict:
    """Parameters of rule `paint_heliostat`: the PAINT directory and folder of the heliostat."""
    for ds in config["datasets"].values():  # the first PAINT dataset of the heliostat (no list of them all)
        if ds.get("source") == "paint" and ds["heliostat"] == heliostat:
            return {"paint_dir": ds["paint_dir"], "heliostat": heliostat}
    raise ConfigError(f"no PAINT dataset takes heliostat {heliostat!r}; PAINT heliostats: "
                      f"{', '.join(paint_heliostats(config)) or 'none'}")


def import_paint_inputs(config: dict, dataset: str) -> dict:
    """Files rule `import_paint` reads: tower-measurements.json, heliostat-properties.json and
    every <id>-calibration-properties.json of the dataset's heliostat with the PNG the import reads:
    its <id>-flux.png, or else its <id>-flux-centered.png (none with centered: skip, which leaves the
    measurement out); with neither the <id>-flux.png, which snakemake then reports missing."""
    from helioflow.data.paint import CALIBRATION_SUFFIX, measurement_pngs

    p = import_paint_params(config, dataset)
    files = _paint_files(p["paint_dir"], p["heliostat"])
    folder = Path(p["paint_dir"]) / p["heliostat"]
    files["measurements"] = []
    for c in sorted(folder.glob(f"*{CALIBRATION_SUFFIX}")):
        whole, centered = measurement_pngs(c)
        if whole.is_file() or not centered.is_file():
            files["measurements"] += [str(c), str(whole)]
        elif p["centered"] != "skip":
            files["measurements"] += [str(c), str(centered)]
    return files


def paint_heliostat_inputs(config: dict, heliostat: str) -> dict:
    """Files rule `paint_heliostat` reads: tower-measurements.json and heliostat-properties.json."""
    return _paint_files(**paint_heliostat_params(config, heliostat))


def _paint_files(paint_dir: str, heliostat: str) -> dict:
    return {"tower": str(Path(paint_dir) / "tower-measurements.json"),
            "properties": str(Path(paint_dir) / heliostat / "heliostat-properties.json")}


def _images_dataset(config: dict, dataset: str) -> dict:
    ds = dataset_entry(config, dataset)
    if ds.get("source") != "images":
        raise ConfigError(f"dataset {dataset!r} is not imported from images (source: {ds.get('source')})")
    return ds


def _images_geometry(ds: dict) -> dict:
    """The heliostat of an images dataset: inline (`heliostat_geometry`) or a heliostat-properties.json
    with the WGS84 origin of the ENU frame."""
    if ds.get("heliostat") is not None:
        return {"heliostat_geometry": copy.deepcopy(ds["heliostat"])}
    return {"heliostat_properties": ds["heliostat_properties"], "origin_wgs84": ds.get("origin_wgs84")}


def import_images_params(config: dict, dataset: str) -> dict:
    """Parameters of rule `import_images`: the images folder and CSV, image resolution (default
    target.resolution), target plane, site, heliostat geometry (dataset_heliostat names it), splits
    or held-out image ids, the seed (of the splits) and the nominal DNI."""
    ds = _images_dataset(config, dataset)
    return {
        "dataset": dataset,
        "heliostat": dataset_heliostat(config, dataset),
        "images_dir": ds["images_dir"],
        "csv": ds["csv"],
        "resolution": list(ds.get("resolution") or config["target"]["resolution"]),
        "target": copy.deepcopy(ds["target"]),
        "site": copy.deepcopy(ds.get("site")),
        **_images_geometry(ds),
        "splits": copy.deepcopy(ds.get("splits")),
        "holdout": copy.deepcopy(ds.get("holdout") or []),
        "seed": config["seed"],
        "dni_w_m2": config["dni_w_m2"],
        **({"csv_heliostat": ds["csv_heliostat"]} if "csv_heliostat" in ds else {}),  # a plant's: its rows
    }


def images_heliostat_params(config: dict, heliostat: str) -> dict:
    """Parameters of rule `images_heliostat`: the geometry of the images dataset(s) of that name."""
    for d in images_datasets(config):
        if dataset_heliostat(config, d) == heliostat:
            return {"heliostat": heliostat, **_images_geometry(config["datasets"][d])}
    raise ConfigError(f"no images dataset has heliostat {heliostat!r}; their heliostats: "
                      f"{', '.join(images_heliostats(config)) or 'none'}")


def import_images_inputs(config: dict, dataset: str) -> dict:
    """Files rule `import_images` reads: the CSV, every image it lists and a heliostat-properties.json."""
    p = import_images_params(config, dataset)
    from helioflow.data.images import image_files

    files = {"csv": p["csv"]}
    files["images"] = image_files(p["csv"], p["images_dir"], p.get("csv_heliostat"))
    if p.get("heliostat_properties"):
        files["properties"] = p["heliostat_properties"]
    return files


def images_heliostat_inputs(config: dict, heliostat: str) -> dict:
    """Files rule `images_heliostat` reads: the heliostat-properties.json, if the geometry is one."""
    p = images_heliostat_params(config, heliostat)
    return {"properties": p["heliostat_properties"]} if p.get("heliostat_properties") else {}


def train_params(config: dict, dataset: str, model: str) -> dict:
    """Parameters of rule `train`: the network, its settings section (a plant heliostat's drt: with
    config plant.fit.drt over it), the seed, the train subset; a physics model (raytrace, drt) also
    gets the dataset's model effects and heliostat file."""
    network, count = parse_model(model)
    networks = config.get("networks") or {}
    if network not in networks:
        raise ConfigError(f"unknown network {network!r}: config networks has {', '.join(networks)}")
    settings = copy.deepcopy(networks[network] or {})
    if network == "drt" and PLANT_KEY in config["datasets"][dataset]:
        settings.update(plant_settings(config)["fit"]["drt"])
    if network in PHYSICS_MODELS:
        settings.update(effects=model_effects(config, dataset), heliostat_path=heliostat_path(config, dataset))
    shared = shared_of(config, dataset) if network in PHYSICS_MODELS else None
    return {"network": network, "settings": settings, "seed": config["seed"], "train_images": count,
            "device": config["device"], **({"shared": shared} if shared else {})}


def train_threads(config: dict, dataset: str, model: str) -> int:
    """torch CPU threads of rule `train`: config torch_threads, but one for the nearest baseline (a
    copy of the training images) and for the field's measured heliostats (many small fits): -j2 runs
    two of those at once."""
    if parse_model(model)[0] == "nearest" or dataset in field_measured(config):
        return 1
    return config["torch_threads"]


# not in the schema: plant.fit.diagnosis takes the same keys ($ref), and defaults there would override
# the config's own diagnosis for every plant heliostat
DIAGNOSIS_DEFAULTS = {"fit_images": 24, "heldout_images": 48, "fit_steps": 80, "rounds": 2, "cells_per_side": 16,
                      "fit_rays": 50_000, "max_effects": 2}


def diagnose_params(config: dict, dataset: str) -> dict:
    """Parameters of rule `diagnose`: the dataset's model effects and the fit settings
    (config `diagnosis`, defaults DIAGNOSIS_DEFAULTS; a plant heliostat's with plant.fit.diagnosis
    over them)."""
    shared = shared_of(config, dataset)
    settings = {**DIAGNOSIS_DEFAULTS, **copy.deepcopy(config.get("diagnosis") or {})}
    if PLANT_KEY in config["datasets"][dataset]:
        settings.update(plant_settings(config)["fit"]["diagnosis"])
    return {"effects": model_effects(config, dataset), "settings": settings,
            "device": config["device"], **({"shared": shared} if shared else {})}


def plan_params(config: dict, dataset: str) -> dict:
    """Parameters of rule `plan_measurements`: config `plan` (with the schema's defaults; its
    `datasets` list says which datasets get a plan) and the device."""
    from helioflow.schema import with_defaults

    settings = with_defaults(config.get("plan"), "plan")
    settings.pop("datasets", None)
    return {"settings": settings, "device": config["device"]}


def evaluate_params(config: dict) -> dict:
    """Parameters of rule `evaluate`: config `evaluation` and the device."""
    return {**copy.deepcopy(config.get("evaluation") or {}), "device": config["device"]}


def optimise_aim_params(config: dict) -> dict:
    """Parameters of rule `optimise_aim`: compose_field's, with "optimise_aim" (config
    field.optimise_aim, the schema's defaults filled in)."""
    return {**compose_field_params(config), "optimise_aim": copy.deepcopy(config["field"]["optimise_aim"])}


def compose_field_params(config: dict) -> dict:
    """Parameters of rule `compose_field`: the template heliostat, every field heliostat's name,
    position and seed, the measured ones, receiver, aim, design points, network, the world and model
    effects of the field (world.effects / model.effects with field.world_effects /
    field.model_effects replacing entries of the same name), trace cells, DNI, seed and device."""
    field = config["field"]
    template = config["heliostats"][field["heliostat"]]
    positions = field_positions(field, template)
    world = copy.deepcopy(config["world"].get("effects") or {})
    world.update(copy.deepcopy(field.get("world_effects") or {}))
    model = copy.deepcopy(config["model"].get("effects") or {})
    model.update(copy.deepcopy(field.get("model_effects") or {}))
    return {
        "template": copy.deepcopy(template),
        "heliostats": {"names": field_names(len(positions)), "positions_m": positions,
                       "seeds": [field["seed"] + i for i in range(len(positions))]},
        "measured": field_measured(config),
        "network": field["network"],
        "receiver": copy.deepcopy(field["receiver"]),
        "aim": copy.deepcopy(field["aim"]),
        "sun": copy.deepcopy(field["sun"]),
        "world_effects": world,
        "model_effects": model,
        "cells_per_side": field["cells_per_side"],
        "dni_w_m2": config["dni_w_m2"],
        "seed": config["seed"],
        "device": config["device"],
    }
