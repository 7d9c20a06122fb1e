"""Config expansion: the entries a config generates (a field's heliostats, leave-one-out folds, a
plant's heliostats), each marked with the entry it came from, and the queries that group them back.
"""

from __future__ import annotations

import copy
import re
from pathlib import Path

from helioflow.errors import ConfigError, DataError
from helioflow.workflow.field import expand_field

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
