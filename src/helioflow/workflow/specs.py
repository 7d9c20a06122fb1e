"""Spec files: the parameters and inputs of the rules whose lists grow with the plant (a plant of
thousands exceeds what one command-line argument holds), written to specs/<rule>.json by rule `spec`.
"""

from __future__ import annotations

import json
from pathlib import Path

from helioflow.errors import ConfigError
from helioflow.workflow.datasets import (
    model_effects,
    paint_plant_groups,
    plant_flux_settings,
    plant_settings,
    plant_shared_settings,
    results_dir,
    shared_of,
)
from helioflow.workflow.expansion import plant_groups, plant_heliostat
from helioflow.workflow.params import compose_field_params, optimise_aim_params
from helioflow.workflow.paths import (
    compose_field_inputs,
    efficiency_metrics,
    heliostat_path,
    metrics_paths,
    plant_table_path,
    report_inputs,
)

SPEC_RULES = ("compose_field", "optimise_aim", "report", "table", "data_efficiency", "plant_table", "plant_shared",
              "plant_flux")  # parameters that grow with the plant


def rule_spec(config: dict, rule: str) -> dict:
    """The parameters and input lists of a rule in SPEC_RULES, which grow with the datasets or the
    field past what one command-line argument may hold (128 KiB): rule `spec` writes them to
    specs/<rule>.json and the rule reads that file (`--spec @file`, `--inputs @file`, `--metrics @file`)."""
    if rule == "compose_field":
        return {**compose_field_params(config), **compose_field_inputs(config)}
    if rule == "optimise_aim":
        return {**optimise_aim_params(config), **compose_field_inputs(config)}
    if rule == "report":
        return report_inputs(config)
    if rule == "table":
        return {"metrics": metrics_paths(config)}
    if rule == "data_efficiency":
        return {"metrics": efficiency_metrics(config)}
    if rule == "plant_table":
        return plant_table_spec(config)
    if rule == "plant_shared":
        return plant_shared_spec(config)
    if rule == "plant_flux":
        return plant_flux_spec(config)
    raise ConfigError(f"no spec file for rule {rule!r}; rules with one: {', '.join(SPEC_RULES)}")


def spec_path(config: dict, rule: str) -> str:
    """specs/<rule>.json of a rule in SPEC_RULES."""
    return f"{results_dir(config)}/specs/{rule}.json"


def write_spec(spec: dict, path: str, log_path: str) -> None:
    """Rule `spec`: a rule's parameters (rule_spec) as JSON at `path`, and its size at `log_path`."""
    from helioflow.io import write_text_atomic

    text = json.dumps(spec)
    write_text_atomic(path, text)
    write_text_atomic(log_path, f"{path}: {len(text)} bytes\n")


def plant_table_spec(config: dict) -> dict:
    """Parameters and inputs of rule `plant_table` (scoring.plant.write_plant_table): per plant
    heliostat its dataset, the physics model config plant.model names (which must be among the
    networks), its diagnosis and its plant fit (shared_of; "" without one)."""
    settings = plant_settings(config)
    if not plant_table_path(config):
        return {"pointing_limit_mrad": settings["pointing_limit_mrad"], "heliostats": []}
    if settings["model"] not in (config.get("networks") or {}):
        raise ConfigError(f"plant.model = {settings['model']!r}: the plant table reports that model's fit, but it is "
                          f"not in networks ({', '.join(config.get('networks') or {}) or 'none'})")
    r = results_dir(config)
    return {"pointing_limit_mrad": settings["pointing_limit_mrad"],
            "heliostats": [{"plant": plant, "heliostat": plant_heliostat(config, d), "dataset": d,
                            "dataset_path": f"{r}/datasets/{d}.h5",
                            "model_path": f"{r}/models/{d}/{settings['model']}.pt",
                            "diagnosis_path": f"{r}/diagnosis/{d}.json",
                            "shared_path": (shared_of(config, d) or {}).get("path", "")}
                           for plant, members in plant_groups(config).items() for d in members]}


def plant_shared_spec(config: dict) -> dict:
    """Parameters and inputs of rule `plant_shared` (diagnosis.shared.plant_shared): the settings and,
    per plant entry, its size and the heliostats the plant fit takes (`data.splits.evenly`, plant.shared.heliostats
    of them), each with its dataset, geometry and model effects. Only those are the rule's inputs: a
    plant of thousands has one plant fit that every heliostat's fit waits for, and a short input list
    keeps snakemake's DAG linear in the heliostats."""
    from helioflow.data.splits import evenly  # here: the Snakefile's helpers start without h5py

    r = results_dir(config)
    settings = plant_shared_settings(config)
    if settings is None:
        return {"settings": {}, "device": config["device"], "plants": {}, "sizes": {}}
    groups = plant_groups(config)
    return {"settings": settings, "device": config["device"],
            "plants": {plant: [{"heliostat": plant_heliostat(config, d), "dataset_path": f"{r}/datasets/{d}.h5",
                                "heliostat_path": heliostat_path(config, d), "effects": model_effects(config, d)}
                               for d in evenly(members, settings["heliostats"])]
                       for plant, members in groups.items()},
            "sizes": {plant: len(members) for plant, members in groups.items()}}


def plant_shared_inputs(config: dict) -> list[str]:
    """Files rule `plant_shared` reads (plant_shared_spec's paths)."""
    return [h[k] for members in plant_shared_spec(config)["plants"].values() for h in members
            for k in ("dataset_path", "heliostat_path")]


def plant_flux_spec(config: dict) -> dict:
    """Parameters and inputs of rule `plant_flux` (field.plant.compose_plant), per PAINT plant entry: its PAINT
    directory, model effects (those of its first heliostat's dataset: the entry's) and every
    calibrated heliostat's physics model (plant.model, as the plant table)."""
    settings = plant_flux_settings(config)
    if settings is None:
        return {}
    model = plant_table_spec(config)["heliostats"]
    return {plant: {"plant": plant, "paint_dir": config["datasets"][members[0]]["paint_dir"],
                    "effects": model_effects(config, members[0]), "settings": settings, "device": config["device"],
                    "dni_w_m2": config["dni_w_m2"],
                    "calibrated": [{"heliostat": h["heliostat"], "model_path": h["model_path"]}
                                   for h in model if h["plant"] == plant]}
            for plant, members in paint_plant_groups(config).items()}


def plant_flux_inputs(config: dict, plant: str) -> list[str]:
    """Files rule `plant_flux` reads for one plant entry: the tower file, every heliostat-properties.json
    of its PAINT directory and its calibrated heliostats' physics models."""
    spec = plant_flux_spec(config).get(plant)
    if spec is None:
        raise ConfigError(f"no plant flux map for {plant!r}; plant entries with one: "
                          f"{', '.join(plant_flux_spec(config)) or 'none'}")
    root = Path(spec["paint_dir"])
    return [str(root / "tower-measurements.json"), *sorted(str(p) for p in root.glob("*/heliostat-properties.json")),
            *[c["model_path"] for c in spec["calibrated"]]]


def plant_table_inputs(config: dict) -> list[str]:
    """Files rule `plant_table` reads (plant_table_spec's paths)."""
    heliostats = plant_table_spec(config)["heliostats"]
    return ([h[k] for h in heliostats for k in ("dataset_path", "model_path", "diagnosis_path")]
            + sorted({h["shared_path"] for h in heliostats} - {""}))
