"""Output paths, targets and the files rules read: what `snakemake all` makes for a config.
"""

from __future__ import annotations

from pathlib import Path

from helioflow.errors import ConfigError, DataError
from helioflow.models.names import parse_model
from helioflow.workflow.datasets import (
    PHYSICS_MODELS,
    centroid_datasets,
    dataset_heliostat,
    has_plant_table,
    images_datasets,
    images_heliostats,
    models,
    network_datasets,
    paint_datasets,
    paint_heliostats,
    paint_plant_groups,
    plant_flux_settings,
    plant_shared_file,
    plant_shared_settings,
    results_dir,
    shared_of,
)
from helioflow.workflow.expansion import fold_datasets, leave_one_out_groups, plant_groups
from helioflow.workflow.field import field_measured


def existing_upstream_files(config: dict) -> list[Path]:
    """The heliostat files, datasets and model files of the experiment that exist already: what
    `check_readable` looks at before snakemake decides what to rerun."""
    r = Path(results_dir(config))
    imported = dict.fromkeys(paint_heliostats(config) + images_heliostats(config))
    names = [r / "surfaces" / f"{h}.h5" for h in {**config["heliostats"], **imported}]
    names += [r / "datasets" / f"{d}.h5" for d in config["datasets"]]
    names += [r / "models" / d / f"{m}.pt" for d in config["datasets"] for m in models(config)]
    return [p for p in names if p.is_file()]


def check_readable(paths: list[Path]) -> None:
    """DataError naming the first file that is not a whole HDF5 file (.h5) or torch zip archive (.pt):
    a corrupted upstream file is newer than what was made from it, so snakemake would rerun, and first
    delete, everything downstream of it, which then fails on the corrupt file. Checked when snakemake
    starts (common.smk), before any job: cheap checks (the HDF5 header and schema attribute, the zip
    archive's checksums), not the full validation each rule makes of its inputs."""
    import zipfile

    import h5py

    for path in paths:
        try:
            if path.suffix == ".h5":
                with h5py.File(path, "r") as f:
                    if "schema" not in f.attrs:
                        raise OSError("no 'schema' attribute: not a helioflow file")
            else:
                with zipfile.ZipFile(path) as archive:
                    bad = archive.testzip()
                if bad is not None:
                    raise OSError(f"member {bad} fails its checksum")
        except (OSError, zipfile.BadZipFile, EOFError) as exc:
            raise DataError(f"{path} is corrupt ({str(exc).splitlines()[0]}); everything made from it would be rerun "
                            "and deleted first: delete the file to rebuild it, or restore it") from None


def dataset_paths(config: dict) -> list[str]:
    """Every configured dataset file."""
    return [f"{results_dir(config)}/datasets/{d}.h5" for d in config["datasets"]]


def heliostat_path(config: dict, dataset: str) -> str:
    """surfaces/<heliostat>.h5 of a dataset's heliostat."""
    return f"{results_dir(config)}/surfaces/{dataset_heliostat(config, dataset)}.h5"


def train_inputs(config: dict, dataset: str, model: str) -> dict:
    """Files rule `train` reads: the dataset, and for a physics model the heliostat file."""
    inputs: dict[str, str | list[str]] = {"dataset": f"{results_dir(config)}/datasets/{dataset}.h5"}
    if parse_model(model)[0] in PHYSICS_MODELS:
        inputs["heliostat"] = heliostat_path(config, dataset)
        shared = shared_inputs(config, dataset)
        if shared:
            inputs["shared"] = shared
    return inputs


def plan_paths(config: dict) -> list[str]:
    """plan/<dataset>.json of every dataset config `plan.datasets` names (drt must be trained)."""
    if "drt" not in (config.get("networks") or {}):
        return []
    return [f"{results_dir(config)}/plan/{d}.json" for d in (config.get("plan") or {}).get("datasets") or []]


def metrics_paths(config: dict, include_efficiency: bool = False) -> list[str]:
    """metrics/<dataset>/<model>.json of every trained network (and data-efficiency run) on every
    dataset but the field's calibration datasets (network_datasets)."""
    names = models(config) if include_efficiency else list(config.get("networks") or {})
    return [f"{results_dir(config)}/metrics/{d}/{m}.json" for d in network_datasets(config) for m in names]


def efficiency_metrics(config: dict) -> list[str]:
    """The metrics files the data-efficiency figure reads."""
    plain = set(metrics_paths(config))
    return [p for p in metrics_paths(config, include_efficiency=True) if p not in plain]


def diagnosis_paths(config: dict) -> list[str]:
    """diagnosis/<dataset>.json of every dataset when the config has a `diagnosis` section, else none;
    of a leave-one-out dataset the whole one only (every image), not its folds."""
    if "diagnosis" not in config:
        return []
    folds = fold_datasets(config)
    return [f"{results_dir(config)}/diagnosis/{d}.json" for d in network_datasets(config) if d not in folds]


def fitted_heliostat_paths(config: dict) -> list[str]:
    """heliostats/<dataset>.json and .png (rule `fitted_heliostat`) of every real (PAINT or images) dataset
    drt is trained on, when drt is among the networks: of a leave-one-out dataset the whole one, not
    its folds; of a plant none (its table holds each heliostat's fit)."""
    if "drt" not in (config.get("networks") or {}):
        return []
    skip = fold_datasets(config) | {d for members in plant_groups(config).values() for d in members}
    imported = set(paint_datasets(config)) | set(images_datasets(config))
    return [f"{results_dir(config)}/heliostats/{d}.{kind}" for d in network_datasets(config)
            if d in imported and d not in skip for kind in ("json", "png")]


def recovery_paths(config: dict) -> list[str]:
    """recovery/<dataset>.json (rule `recovery`: what drt recovered of the true
    heliostat) of every synthetic dataset the networks are scored on, when `drt` is among them."""
    if "drt" not in (config.get("networks") or {}):
        return []
    imported = set(paint_datasets(config)) | set(images_datasets(config))
    return [f"{results_dir(config)}/recovery/{d}.json" for d in network_datasets(config) if d not in imported]


def report_inputs(config: dict) -> dict[str, list[str]]:
    """Files rule `report` reads, by report section; a section the config leaves out is an empty
    list (the report says "not part of this experiment"). Together they are every final output."""
    r = results_dir(config)
    datasets, networks = network_datasets(config), list(config.get("networks") or {})
    diagnosed = [Path(p).stem for p in diagnosis_paths(config)]
    efficiency = (config.get("data_efficiency") or {}).get("networks")
    # a plant's heliostats get no figures of their own: the plant section summarises hundreds of them
    plant = {d for members in plant_groups(config).values() for d in members}
    return {
        "datasets": dataset_paths(config),
        "dataset_figures": [f"{r}/figures/datasets/{d}.png" for d in config["datasets"] if d not in plant],
        "paint_centroids": [f"{r}/paint/{d}_centroids.json" for d in centroid_datasets(config) if d not in plant],
        "table": [f"{r}/tables/table1.md", f"{r}/tables/table1.csv"] if networks else [],
        "samples": [f"{r}/figures/{d}/{m}_samples.png" for d in datasets if d not in plant for m in networks],
        "psnr": [f"{r}/figures/{d}/{m}_psnr.png" for d in datasets if d not in plant for m in networks],
        "data_efficiency": [f"{r}/figures/data_efficiency.png"] if efficiency else [],
        "recovery": recovery_paths(config),
        "heliostats": fitted_heliostat_paths(config),
        "plan": plan_paths(config),
        "diagnosis": diagnosis_paths(config),
        "diagnosis_figures": [f"{r}/figures/diagnosis/{d}_{kind}.png" for d in diagnosed
                              for kind in ("signatures", "ranking", "residuals", "location", "ledger")],
        "field": [f"{r}/field/flux.png", f"{r}/field/metrics.json"] if "field" in config else [],
        "aim": aim_paths(config),
        "leave_one_out": [p for g in leave_one_out_groups(config)
                          for p in (f"{r}/figures/leave_one_out/{g}.png", f"{r}/leave_one_out/{g}.csv")],
        "plant": plant_table_path(config),
        "plant_plan": [str(Path(p).with_name("plan.png")) for p in plant_table_path(config)],
        "plant_flux": [*plant_flux_paths(config, "png"), *plant_flux_paths(config, "json")],
        "plant_aim": plant_aim_paths(config),
        "plant_shared": plant_shared_path(config),
    }


def report_path(config: dict) -> str:
    """results/<experiment>/report.html."""
    return f"{results_dir(config)}/report.html"


def all_targets(config: dict) -> list[str]:
    """What `snakemake all` builds: the report, whose inputs (`report_inputs`) are everything else."""
    return [report_path(config)]


def compose_field_inputs(config: dict) -> dict[str, list[str]]:
    """Files rule `compose_field` reads: models/<heliostat>/<network>.pt and datasets/<heliostat>.h5
    of every measured heliostat, in field_measured order."""
    r, measured = results_dir(config), field_measured(config)
    network = (config.get("field") or {}).get("network")
    return {"models": [f"{r}/models/{m}/{network}.pt" for m in measured],
            "datasets": [f"{r}/datasets/{m}.h5" for m in measured]}


def aim_paths(config: dict) -> list[str]:
    """field/aim.png and field/aim.json, the outputs of rule optimise_aim, when config field.optimise_aim
    asks for them."""
    if not (config.get("field") or {}).get("optimise_aim"):
        return []
    return [f"{results_dir(config)}/field/aim.png", f"{results_dir(config)}/field/aim.json"]


def plant_table_path(config: dict) -> list[str]:
    """plant/heliostats.csv when the config has a plant table (has_plant_table)."""
    if not has_plant_table(config):
        return []
    return [f"{results_dir(config)}/plant/heliostats.csv"]


def plant_shared_path(config: dict) -> list[str]:
    """plant/shared.json (rule plant_shared) when the plant fit runs (plant_shared_settings)."""
    return [plant_shared_file(config)] if plant_shared_settings(config) is not None else []


def shared_inputs(config: dict, dataset: str) -> list[str]:
    """[plant/shared.json] for a dataset shared_of gives one, else []."""
    shared = shared_of(config, dataset)
    return [] if shared is None else [shared["path"]]


def plant_flux_paths(config: dict, kind: str = "png") -> list[str]:
    """plant/flux/<plant entry>.<kind> (kind h5, png or json) of every PAINT plant entry, when the maps
    are made."""
    if plant_flux_settings(config) is None:
        return []
    return [f"{results_dir(config)}/plant/flux/{plant}.{kind}" for plant in paint_plant_groups(config)]


def plant_aim_paths(config: dict) -> list[str]:
    """plant/aim/<plant entry>.png and .json, the outputs of rule plant_aim, when config
    plant.flux.optimise_aim asks for them."""
    if not (plant_flux_settings(config) or {}).get("optimise_aim"):
        return []
    return [f"{results_dir(config)}/plant/aim/{plant}.{kind}" for plant in paint_plant_groups(config)
            for kind in ("png", "json")]


def leave_one_out_inputs(config: dict, group: str) -> dict[str, list[str]]:
    """Files rule `leave_one_out` reads for one group: per fold (in order) its dataset, and per
    network its model and per-image metrics CSV (keys model_<network>, metrics_<network>)."""
    folds = leave_one_out_groups(config).get(group)
    if not folds:
        raise ConfigError(f"no leave-one-out dataset {group!r}; leave-one-out datasets: "
                          f"{', '.join(leave_one_out_groups(config)) or 'none'}")
    r = results_dir(config)
    inputs = {"datasets": [f"{r}/datasets/{f}.h5" for f in folds]}
    for network in config.get("networks") or {}:
        inputs[f"model_{network}"] = [f"{r}/models/{f}/{network}.pt" for f in folds]
        inputs[f"metrics_{network}"] = [f"{r}/metrics/{f}/{network}.csv" for f in folds]
    return inputs
