"""Pure helpers the Snakefile binds: output paths, targets and each rule's parameters.

Each `*_params` function returns exactly the config a rule's output depends on (and nothing
else), so editing one config section reruns only the rules that read it (snakemake's params
rerun trigger), and tests can call them without snakemake.
"""

from __future__ import annotations

import copy
import functools
import json
import re
from pathlib import Path

from helioflow.errors import ConfigError, DataError
from helioflow.models.names import parse_model

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
    """Name of the heliostat a dataset is traced from (or imported with): its `heliostat`, but for
    own images (source: images, whose `heliostat` is the geometry itself) the dataset's name, or
    for a leave-one-out fold its dataset's name (surfaces/<that name>.h5)."""
    ds = _dataset(config, dataset)
    if ds.get("source") == "images":
        return ds.get(FOLD_KEY) or dataset
    return ds["heliostat"]


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


def import_paint_params(config: dict, dataset: str) -> dict:
    """Parameters of rule `import_paint`: the PAINT folder, image resolution (default
    target.resolution), held-out measurement ids, the target filter, the nominal DNI and what becomes
    of the measurements with only a centered image (`centered`, default place)."""
    from helioflow.data.paint import CENTERED_DEFAULT

    ds = _dataset(config, dataset)
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
    ds = _dataset(config, dataset)
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


def dataset_paths(config: dict) -> list[str]:
    """Every configured dataset file."""
    return [f"{results_dir(config)}/datasets/{d}.h5" for d in config["datasets"]]


def models(config: dict) -> list[str]:
    """Model names trained on every dataset: the networks, then the data-efficiency runs."""
    names = list(config.get("networks") or {})
    efficiency = config.get("data_efficiency") or {}
    names += [f"{n}-n{k}" for n in efficiency.get("networks", []) for k in efficiency.get("train_images", [])]
    return names


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
        settings.update(plant_settings(config)["fit"].get("drt", {}))
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


DIAGNOSIS_DEFAULTS = {"fit_images": 24, "heldout_images": 48, "fit_steps": 80, "rounds": 2, "cells_per_side": 16,
                      "fit_rays": 50_000, "max_effects": 2}


def diagnose_params(config: dict, dataset: str) -> dict:
    """Parameters of rule `diagnose`: the dataset's model effects and the fit settings
    (config `diagnosis`, defaults DIAGNOSIS_DEFAULTS; a plant heliostat's with plant.fit.diagnosis
    over them)."""
    shared = shared_of(config, dataset)
    settings = {**DIAGNOSIS_DEFAULTS, **copy.deepcopy(config.get("diagnosis") or {})}
    if PLANT_KEY in config["datasets"][dataset]:
        settings.update(plant_settings(config)["fit"].get("diagnosis", {}))
    return {"effects": model_effects(config, dataset), "settings": settings,
            "device": config["device"], **({"shared": shared} if shared else {})}


PLAN_DEFAULTS = {"images": 8, "criterion": "d_optimal", "days": 7.0, "every_minutes": 30.0, "min_elevation_deg": 10.0}


def plan_params(config: dict, dataset: str) -> dict:
    """Parameters of rule `plan_measurements`: config `plan` (defaults PLAN_DEFAULTS; its
    `datasets` list says which datasets get a plan) and the device."""
    settings = {**PLAN_DEFAULTS, **copy.deepcopy(config.get("plan") or {})}
    settings.pop("datasets", None)
    return {"settings": settings, "device": config["device"]}


def plan_paths(config: dict) -> list[str]:
    """plan/<dataset>.json of every dataset config `plan.datasets` names (drt must be trained)."""
    if "drt" not in (config.get("networks") or {}):
        return []
    return [f"{results_dir(config)}/plan/{d}.json" for d in (config.get("plan") or {}).get("datasets") or []]


def evaluate_params(config: dict) -> dict:
    """Parameters of rule `evaluate`: config `evaluation` and the device."""
    return {**copy.deepcopy(config.get("evaluation") or {}), "device": config["device"]}


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
        "plant_shared": plant_shared_path(config),
    }


def report_path(config: dict) -> str:
    """results/<experiment>/report.html."""
    return f"{results_dir(config)}/report.html"


def all_targets(config: dict) -> list[str]:
    """What `snakemake all` builds: the report, whose inputs (`report_inputs`) are everything else."""
    return [report_path(config)]


# --- the field (config `field`, rule compose_field) --------------------------------------------

FIELD_PREFIX = "field_"
LAYOUT_DEFAULTS = {"spacing_m": "auto", "clearance_m": 1.0, "sector_deg": 120.0, "pivot_height_m": 0.0}
FIELD_ONLY_EFFECTS = ("blocking_shading",)  # acts in field traces only: left out of calibration datasets


def field_size(field: dict) -> int:
    """Number of heliostats of the field's layout (layout.n, or the rows of the list / CSV file)."""
    layout = field["layout"]
    if layout["kind"] in ("fermat", "radial"):
        return layout["n"]
    if layout["kind"] == "list":
        return len(layout["positions"])
    return len(field_positions(field, {}))


def field_positions(field: dict, template: dict) -> list[list[float]]:
    """Pivot positions of the field's layout (`layout_positions`), computed once per layout and
    template mirror: snakemake asks for them for every job while it builds the DAG."""
    layout = field["layout"]
    csv = Path(layout["csv"]) if layout["kind"] == "csv" else None
    stamp = (csv.stat().st_mtime_ns, csv.stat().st_size) if csv is not None and csv.is_file() else None
    mirror = mirror_size(template) if layout["kind"] in ("fermat", "radial") else None  # list, csv: not used
    key = json.dumps([layout, mirror, stamp], sort_keys=True)
    return [list(row) for row in _positions_of(key)]


@functools.lru_cache(maxsize=8)
def _positions_of(key: str) -> list[list[float]]:
    layout, mirror, _ = json.loads(key)
    return layout_positions(layout, mirror)


def layout_positions(layout: dict, mirror: list[float] | None) -> list[list[float]]:
    """Pivot positions, (n, 3) ENU in m rounded to the mm, of a field layout (config field.layout)
    for a template mirror of `mirror` = (width, height) m.

    fermat / radial: helioflow.physics.layout.fermat_spiral / radial_staggered of layout.n
    heliostats outside min_radius_m in a sector of sector_deg around north, pivots pivot_height_m
    up, no two closer than spacing_m (auto: the template mirror's diagonal plus clearance_m,
    layout.min_spacing); list: the rows [east, north(, up)] of layout.positions; csv: the rows of
    the file layout.csv (a header row is allowed). Defaults: LAYOUT_DEFAULTS.
    """
    from helioflow.physics import layout as geometry

    spec = {**LAYOUT_DEFAULTS, **layout}
    if spec["kind"] == "list":
        positions = geometry.positions_from_list(spec["positions"], "field.layout.positions")
    elif spec["kind"] == "csv":
        try:
            positions = geometry.load_positions(spec["csv"])
        except DataError as exc:
            raise ConfigError(f"field.layout.csv: {exc}") from None
    else:
        spacing = spec["spacing_m"]
        if spacing == "auto":
            assert mirror is not None, "an auto spacing needs the template mirror"
            width, height = mirror
            spacing = geometry.min_spacing(width, height, spec["clearance_m"])
        generate = geometry.fermat_spiral if spec["kind"] == "fermat" else geometry.radial_staggered
        positions = generate(spec["n"], spacing, spec["min_radius_m"], spec["sector_deg"],
                             spec["pivot_height_m"])
    return [[round(x, 3) for x in row] for row in positions.tolist()]


def mirror_size(heliostat: dict) -> tuple[float, float]:
    """(width, height) in m of a heliostat section's mirror: its facets and the gaps between them."""
    f = heliostat["facets"]
    gap = f.get("gap_m", 0.0)
    return f["cols"] * f["width_m"] + (f["cols"] - 1) * gap, f["rows"] * f["height_m"] + (f["rows"] - 1) * gap


def field_names(n: int) -> list[str]:
    """field_000, field_001, ... (at least three digits; more for fields of 1000 and more)."""
    width = max(3, len(str(n - 1)))
    return [f"{FIELD_PREFIX}{i:0{width}d}" for i in range(n)]


def measured_indices(field: dict, n: int) -> list[int]:
    """Sorted layout indices of the measured heliostats: measured.indices, or a seeded random
    choice (numpy default_rng(measured.seed)) of max(1, round(fraction * n)) heliostats."""
    measured = field["measured"]
    if "indices" in measured:
        bad = [i for i in measured["indices"] if i >= n]
        if bad:
            raise ConfigError(f"field.measured.indices has {bad[0]}, but the field has {n} heliostats "
                              f"(indices 0 to {n - 1})")
        return sorted(measured["indices"])
    import numpy as np

    count = max(1, round(measured["fraction"] * n))
    return sorted(np.random.default_rng(measured.get("seed", 0)).choice(n, count, replace=False).tolist())


def field_measured(config: dict) -> list[str]:
    """Names of the measured field heliostats, which are also their calibration datasets' names
    (none without a field section)."""
    field = config.get("field")
    if not field:
        return []
    names = field_names(field_size(field))
    return [names[i] for i in measured_indices(field, len(names))]


def field_heliostats(config: dict) -> dict[str, dict]:
    """The generated `heliostats` entries of the measured field heliostats (field_measured): field
    heliostat i is the template's section with its own position and seed (field.seed + i), so that
    the `surfaces` rule gives it its own errors. The others need no entry: compose_field builds them
    from their positions and seeds (compose_field_params)."""
    field = config["field"]
    template = config["heliostats"][field["heliostat"]]
    positions = field_positions(field, template)
    names = field_names(len(positions))
    return {names[i]: {**copy.deepcopy(template), "position_m": positions[i], "seed": field["seed"] + i}
            for i in measured_indices(field, len(positions))}


def _field_effects(effects: dict | None) -> dict:
    return {k: copy.deepcopy(v) for k, v in (effects or {}).items() if k not in FIELD_ONLY_EFFECTS}


def field_datasets(config: dict) -> dict[str, dict]:
    """The generated `datasets` entries: one calibration dataset per measured heliostat, named
    like it, from field.calibration. Its world (and model) effects are field.world_effects
    (model_effects) without the field-only ones, then the calibration's own entries: the
    calibration images see the same atmosphere as the field."""
    field = config["field"]
    calibration = copy.deepcopy(field["calibration"])
    world = {**_field_effects(field.get("world_effects")), **calibration.pop("world_effects", {})}
    model = {**_field_effects(field.get("model_effects")), **calibration.pop("model_effects", {})}
    return {name: {"source": "synthetic", "heliostat": name, **copy.deepcopy(calibration),
                   "world_effects": copy.deepcopy(world), "model_effects": copy.deepcopy(model)}
            for name in field_measured(config)}


def facing(position_m, center_m, normal):
    """Distance (m) of a point (3,), or of points (n, 3), in front of a plane (centre, normal towards
    the field): > 0 when a heliostat there can see the plane, <= 0 when it is in the plane or behind
    it. A float for one point, an (n,) array for several."""
    import numpy as np

    n = np.asarray(normal, dtype=float)
    distance = np.subtract(position_m, center_m) @ (n / np.linalg.norm(n))
    return float(distance) if np.ndim(distance) == 0 else distance


def check_field_geometry(config: dict) -> None:
    """ConfigError naming the heliostat when a field heliostat is behind the receiver (or, measured,
    behind the calibration target), or when two pivots are closer than the mirror diagonal (their
    mirrors would collide: list and csv layouts; fermat and radial keep their spacing)."""
    import numpy as np
    from scipy.spatial import cKDTree

    from helioflow.physics.layout import min_spacing

    field = config["field"]
    template = config["heliostats"][field["heliostat"]]
    positions = field_positions(field, template)
    names = field_names(len(positions))
    xyz = np.asarray(positions)
    receiver, target = field["receiver"], config["target"]
    measured = np.zeros(len(xyz), dtype=bool)
    measured[measured_indices(field, len(xyz))] = True
    behind = np.nonzero(facing(xyz, receiver["center_m"], receiver["normal"]) <= 0)[0]
    if len(behind):
        i = int(behind[0])
        raise ConfigError(f"field: heliostat {names[i]} at {positions[i]} is behind the receiver (field.receiver."
                          f"center_m {receiver['center_m']}, normal {receiver['normal']}): it cannot reach it")
    behind = np.nonzero(measured & (facing(xyz, target["center_m"], target["normal"]) <= 0))[0]
    if len(behind):
        i = int(behind[0])
        raise ConfigError(f"field: measured heliostat {names[i]} at {positions[i]} is behind the calibration target "
                          f"(target.center_m {target['center_m']}, normal {target['normal']}): it cannot see it")
    if field["layout"]["kind"] not in ("list", "csv") or len(xyz) < 2:
        return
    diagonal = min_spacing(*mirror_size(template))
    xy = xyz[:, :2]
    pairs = [(a, b) for a, b in cKDTree(xy).query_pairs(diagonal) if np.linalg.norm(xy[a] - xy[b]) < diagonal]
    if pairs:
        a, b = min(pairs)
        raise ConfigError(f"field.layout: heliostats {names[a]} {positions[a]} and {names[b]} {positions[b]} are "
                          f"{np.linalg.norm(xy[a] - xy[b]):.2f} m apart, less than the mirror diagonal "
                          f"{diagonal:.2f} m: "
                          "their mirrors would collide")


def expand_field(config: dict) -> dict:
    """The config with the field's generated `heliostats` and `datasets` entries added (a copy; the
    config itself without a field section). Applied right after validation (common.smk, the
    CLI), so that the existing surfaces, trace, train and evaluate rules build the field's
    heliostat geometries, calibration datasets and models. A generated name already in use
    raises ConfigError."""
    config = copy.deepcopy(config)
    if not config.get("field"):
        return config
    check_field_geometry(config)
    generated = set(field_names(field_size(config["field"])))
    for section, entries in (("heliostats", field_heliostats(config)), ("datasets", field_datasets(config))):
        taken = sorted(generated & set(config[section]))
        if taken:
            raise ConfigError(f"field: the generated name {taken[0]!r} is already in {section}; rename that "
                              f"entry (field heliostats and their datasets are named {FIELD_PREFIX}<index>)")
        config[section].update(entries)
    return config


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


def network_datasets(config: dict) -> list[str]:
    """The datasets every network is trained and scored on, and diagnosed: all but the field's
    calibration datasets, which train only field.network (see compose_field_inputs)."""
    field = set(field_measured(config))
    return [d for d in config["datasets"] if d not in field]


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


# --- leave-one-out on a handful of real images (PAINT or images datasets with holdout: leave_one_out)

LEAVE_ONE_OUT = "leave_one_out"
LOO_MAX_FOLDS = 20  # more measurements than this: hold out a list of ids instead
FOLD_KEY = "leave_one_out_of"  # marks a generated fold with its dataset's name


def leave_one_out_ids(dataset: dict) -> list[str]:
    """The measurement ids of a PAINT dataset on its `targets` (all when null), in import order, or
    the image ids of an images dataset's CSV; ConfigError naming the folder or CSV when it cannot be
    read or holds fewer than two."""
    if dataset.get("source") == "images":
        from helioflow.data.images import image_ids

        try:
            ids = image_ids(dataset["csv"], dataset.get("csv_heliostat"))
        except DataError as exc:
            raise ConfigError(f"holdout: leave_one_out needs the image ids: {exc}") from None
        if len(ids) < 2:
            raise ConfigError(f"holdout: leave_one_out needs at least two images; {dataset['csv']} has {len(ids)}")
        return ids
    from helioflow.data.paint import CENTERED_DEFAULT, measurement_targets

    try:
        targets = measurement_targets(dataset["paint_dir"], dataset["heliostat"],
                                      dataset.get("centered", CENTERED_DEFAULT))
    except DataError as exc:
        raise ConfigError(f"holdout: leave_one_out needs the measurement ids: {exc}") from None
    keep = dataset.get("targets")
    ids = [i for i, t in targets.items() if keep is None or t in keep]
    if len(ids) < 2:
        raise ConfigError(f"holdout: leave_one_out needs at least two measurements; "
                          f"{Path(dataset['paint_dir']) / dataset['heliostat']} has {len(ids)}"
                          + (f" on targets {keep}" if keep is not None else ""))
    return ids


def leave_one_out_folds(name: str, dataset: dict) -> dict[str, dict]:
    """The fold datasets of a PAINT or images dataset with holdout: leave_one_out: '<name>_loo_<id>' per
    measurement id (leave_one_out_ids), each the dataset with that one id held out and marked
    with FOLD_KEY = name."""
    ids = leave_one_out_ids(dataset)
    if len(ids) > LOO_MAX_FOLDS:
        raise ConfigError(f"datasets.{name}.holdout: leave_one_out would make {len(ids)} datasets, each training "
                          f"every network (at most {LOO_MAX_FOLDS}); hold out a list of ids instead")
    bad = [i for i in ids if not re.fullmatch(r"[A-Za-z0-9_-]+", i)]
    if bad:
        raise ConfigError(f"datasets.{name}.holdout: leave_one_out names a dataset per id, but id {bad[0]!r} has "
                          "characters other than letters, digits, '_' and '-'")
    return {f"{name}_loo_{i}": {**copy.deepcopy(dataset), "holdout": [i], FOLD_KEY: name} for i in ids}


def expand_leave_one_out(config: dict) -> dict:
    """The config (a copy) with every PAINT or images dataset whose holdout is leave_one_out followed by its
    folds (leave_one_out_folds), in place of it in `datasets`' order, so that the existing
    import and train rules run per fold; the dataset itself stays with every image training (no
    holdout): the calibration on all its images, which is diagnosed and written out
    (fitted_heliostat_paths), while the folds score how well such a fit predicts an image it has
    not seen. A fold name already in use raises ConfigError."""
    def whole_and_folds(name: str, ds: dict) -> dict | None:
        if ds.get("holdout") != LEAVE_ONE_OUT:
            return None
        whole = {k: v for k, v in copy.deepcopy(ds).items() if k != "holdout"}
        return {name: whole, **leave_one_out_folds(name, ds)}

    return _expand_datasets(config, whole_and_folds, "fold")


def _expand_datasets(config: dict, generated, what: str) -> dict:
    """The config (a copy) with each dataset for which generated(name, entry) gives {name: entry}
    replaced by those (which may keep its own name), in its place in `datasets`' order (None: kept);
    a generated name already in use raises ConfigError."""
    config = copy.deepcopy(config)
    datasets = {}
    for name, ds in config["datasets"].items():
        entries = generated(name, ds)
        if entries is None:
            datasets[name] = ds
            continue
        taken = sorted((set(entries) - {name}) & set(config["datasets"]))
        if taken:
            raise ConfigError(f"datasets.{name}: the {what} name {taken[0]!r} is already a dataset; rename it")
        datasets.update(entries)
    config["datasets"] = datasets
    return config


PLANT_KEY = "plant_of"  # marks a generated heliostat dataset with its plant entry's name


def expand_plants(config: dict) -> dict:
    """The config (a copy) with every dataset that takes a plant (`heliostats`: all, a glob or a list)
    replaced, in place in `datasets`' order, by one dataset per heliostat named '<entry>_<heliostat>',
    marked with PLANT_KEY = the entry's name, so that the existing import, train, evaluate and
    diagnose rules run per heliostat: a PAINT entry's with `heliostat` set to its folder
    (data.paint.plant_heliostats), an images entry's with `csv_heliostat` set to its name in the
    CSV's heliostat column (data.images.csv_heliostats) and heliostat_properties to its own file.
    A generated name already in use raises ConfigError."""
    # here: `helioflow --help` starts without torch
    from helioflow.data.images import HELIOSTAT_PLACEHOLDER, csv_heliostats
    from helioflow.data.paint import plant_heliostats

    def members(name: str, ds: dict) -> dict | None:
        if "heliostats" not in ds:
            return None
        entry = {k: v for k, v in ds.items() if k != "heliostats"}
        if ds["source"] == "images":
            return {f"{name}_{h}": {**copy.deepcopy(entry), "csv_heliostat": h, PLANT_KEY: name,
                                    "heliostat_properties":
                                        ds["heliostat_properties"].replace(HELIOSTAT_PLACEHOLDER, h)}
                    for h in csv_heliostats(ds["csv"], ds["heliostats"])}
        return {f"{name}_{h}": {**copy.deepcopy(entry), "heliostat": h, PLANT_KEY: name}
                for h in plant_heliostats(ds["paint_dir"], ds["heliostats"])}

    return _expand_datasets(config, members, "generated")


def plant_heliostat(config: dict, dataset: str) -> str:
    """A plant dataset's heliostat as the plant names it: its PAINT folder or its name in the CSV."""
    ds = config["datasets"][dataset]
    return ds.get("csv_heliostat") or ds["heliostat"]


def plant_groups(config: dict) -> dict[str, list[str]]:
    """{plant entry: its heliostats' datasets} of an expanded config (before leave-one-out folds)."""
    groups: dict[str, list[str]] = {}
    for name, ds in config["datasets"].items():
        if PLANT_KEY in ds and FOLD_KEY not in ds:
            groups.setdefault(ds[PLANT_KEY], []).append(name)
    return groups


def plant_table_path(config: dict) -> list[str]:
    """plant/heliostats.csv when the config has plant entries (expand_plants) and a diagnosis."""
    if not plant_groups(config) or "diagnosis" not in config:
        return []
    return [f"{results_dir(config)}/plant/heliostats.csv"]


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


def plant_settings(config: dict) -> dict:
    """Config `plant` with the schema's defaults filled in (helioflow.schema): how a plant's
    heliostats are fitted (`fit`) and batched (`group_size`), the plant fit (`shared`), the table's
    model and pointing limit, the flux maps (`flux`)."""
    from helioflow.schema import section_with_defaults

    return section_with_defaults(config, "plant")


def plant_shared_settings(config: dict) -> dict | None:
    """The plant fit's settings (config plant.shared, with the schema's defaults), None when the
    config has no plant entry or sets `plant.shared: false` (each heliostat fitted alone)."""
    if not _plant_fit_wanted(config) or not plant_groups(config):
        return None
    return plant_settings(config)["shared"]


def _plant_fit_wanted(config: dict) -> bool:
    """Whether a plant's heliostats are fitted with the plant fit (`plant.shared` is not false)."""
    return plant_settings(config)["shared"] is not False


def _shared_file(config: dict) -> str:
    return f"{results_dir(config)}/plant/shared.json"


def plant_shared_path(config: dict) -> list[str]:
    """plant/shared.json (rule plant_shared) when the plant fit runs (plant_shared_settings)."""
    return [_shared_file(config)] if plant_shared_settings(config) is not None else []


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


def shared_of(config: dict, dataset: str) -> dict | None:
    """{"path": plant/shared.json, "plant": its entry} for a heliostat of a plant whose shared effects
    the plant fit sets (rules train and diagnose take them from there: the key `shared` of their
    specs, absent for every other dataset), else None."""
    ds = config["datasets"][dataset]
    # a plant heliostat's dataset: its plant exists, so the fit runs where wanted (plant_shared_settings),
    # decided without going over every dataset (snakemake asks for every job)
    if PLANT_KEY not in ds or FOLD_KEY in ds or not _plant_fit_wanted(config):
        return None
    return {"path": _shared_file(config), "plant": ds[PLANT_KEY]}


def shared_inputs(config: dict, dataset: str) -> list[str]:
    """[plant/shared.json] for a dataset shared_of gives one, else []."""
    shared = shared_of(config, dataset)
    return [] if shared is None else [shared["path"]]


def plant_flux_settings(config: dict) -> dict | None:
    """The plant flux maps' settings (config plant.flux, with the schema's defaults), None when there
    is no plant table (plant_table_path) or `plant.flux: false`."""
    flux = plant_settings(config)["flux"]
    if not plant_table_path(config) or flux is False:
        return None
    return flux


def _paint_plants(config: dict) -> dict[str, list[str]]:
    """plant_groups of the PAINT plant entries: only a PAINT directory holds the whole field's geometry
    (an images plant's CSV and properties files hold its calibrated heliostats only), so only these
    get a flux map."""
    return {p: m for p, m in plant_groups(config).items() if config["datasets"][m[0]]["source"] == "paint"}


def plant_flux_paths(config: dict, kind: str = "png") -> list[str]:
    """plant/flux/<plant entry>.<kind> (kind h5, png or json) of every PAINT plant entry, when the maps
    are made."""
    if plant_flux_settings(config) is None:
        return []
    return [f"{results_dir(config)}/plant/flux/{plant}.{kind}" for plant in _paint_plants(config)]


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
            for plant, members in _paint_plants(config).items()}


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


def expand_config(config: dict) -> dict:
    """A validated config with its generated entries: the field's (expand_field), one dataset per
    heliostat of a plant entry (expand_plants) and the leave-one-out folds (expand_leave_one_out).
    What common.smk and the CLI work with."""
    return expand_leave_one_out(expand_plants(expand_field(config)))


def leave_one_out_groups(config: dict) -> dict[str, list[str]]:
    """{dataset with holdout leave_one_out: its fold datasets} of an expanded config."""
    groups: dict[str, list[str]] = {}
    for name, ds in config["datasets"].items():
        if FOLD_KEY in ds:
            groups.setdefault(ds[FOLD_KEY], []).append(name)
    return groups


def fold_datasets(config: dict) -> set[str]:
    """Every leave-one-out fold dataset of an expanded config (not the datasets they are folds of)."""
    return {f for group in leave_one_out_groups(config).values() for f in group}


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
