"""Network names -> config dataclass and model class; model files; the `train` rule's function."""

from __future__ import annotations

import dataclasses
import importlib
import logging
import os
from pathlib import Path
from typing import TYPE_CHECKING, cast

import numpy as np
import torch

from helioflow.data.hdf5 import CalibrationDataset, read_dataset
from helioflow.device import resolve_device
from helioflow.errors import ConfigError, DataError
from helioflow.io import load_torch, save_torch_atomic
from helioflow.models.base import SpotModel, TrainingData
from helioflow.models.training import LoopConfig, train, write_curve

if TYPE_CHECKING:  # models.physical imports this module
    from helioflow.models.physical import RaytraceModel
    from helioflow.physics.heliostat import Heliostat

log = logging.getLogger(__name__)

# network -> (module, config class, model class); modules are imported when first used.
NETWORKS = {
    "nearest": ("helioflow.models.nearest", "NearestConfig", "Nearest"),
    "gan": ("helioflow.models.dcgan", "GanConfig", "DCGAN"),
    "cgan": ("helioflow.models.cgan", "CganConfig", "ConditionalGAN"),
    "nerf": ("helioflow.models.nerf", "NerfConfig", "SpotNeRF"),
    "raytrace": ("helioflow.models.physical", "PhysicsConfig", "RaytraceModel"),
    "drt": ("helioflow.models.physical", "DrtConfig", "DrtModel"),
}
LOOP_KEYS = ("steps", "batch_size", "checkpoint_every")
MODEL_FORMAT = "helioflow.model/1"


def network_classes(network: str) -> tuple[type, type[SpotModel]]:
    """(config dataclass, model class) of a network name."""
    if network not in NETWORKS:
        raise ConfigError(f"unknown network {network!r}; allowed: {', '.join(NETWORKS)}")
    module, config_name, model_name = NETWORKS[network]
    mod = importlib.import_module(module)
    return getattr(mod, config_name), getattr(mod, model_name)


def split_settings(network: str, settings: dict, seed: int, where: str | None = None) -> tuple[LoopConfig, object]:
    """A network's config section -> (loop settings, the network's config dataclass).

    An unknown key, or a value of the wrong type or out of range, raises one ConfigError naming the
    key (`where`.key, default networks.<network>.key), the value and what is allowed.
    """
    where = where or f"networks.{network}"
    config_cls, _ = network_classes(network)
    fields = {f.name for f in dataclasses.fields(config_cls)}
    for key in settings:
        if key not in fields and key not in LOOP_KEYS:
            allowed = ", ".join(sorted(fields | set(LOOP_KEYS)))
            raise ConfigError(f"{where}: unknown setting {key!r}; allowed: {allowed}")
    try:
        loop = LoopConfig(seed=seed, **{k: settings[k] for k in LOOP_KEYS if k in settings})
        config = config_cls(**{k: v for k, v in settings.items() if k in fields})
    except ConfigError as exc:
        raise ConfigError(f"{where}.{exc}") from None
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{where}: {exc}") from None
    return loop, config


def training_data(ds: CalibrationDataset, dataset_path, limit: int | None = None, seed: int = 0) -> TrainingData:
    """The train split of a dataset (read from `dataset_path`), normalised by its maximum.

    Args:
        limit: keep this many train images (a seeded random subset), for data-efficiency runs.
    """
    index = ds.indices("train")
    if limit is not None:
        if limit > len(index):
            raise DataError(f"{dataset_path}: {limit} training images asked for, the train split has {len(index)}")
        index = np.sort(np.random.default_rng(seed).choice(index, limit, replace=False))
    images = torch.as_tensor(ds.images[index])
    scale = float(images.max())
    return TrainingData(images / scale, torch.as_tensor(ds.azimuth_deg[index], dtype=torch.float32),
                        torch.as_tensor(ds.elevation_deg[index], dtype=torch.float32), scale)


# config fields a network may take from the dataset's attributes when its settings leave them unset
GEOMETRY_ATTRIBUTES = {"heliostat_position_m": "heliostat_position_m", "aim_point_m": "target_center_m",
                       "target_aim_m": "aim_point_m",
                       "target_normal": "target_normal", "mount": "heliostat_mount",
                       "canting_focal_distance_m": "canting_focal_distance_m", "target_size_m": "target_size_m",
                       "dni_w_m2": "dni_w_m2", "dataset_trace": "trace",
                       "per_image_normalised": "per_image_normalised"}


def dataset_geometry(network: str, attrs: dict) -> dict:
    """The scene geometry a network's config declares (e.g. the NeRF's heliostat position, aim
    point, target normal, mount and canting distance), taken from a dataset's attributes."""
    config_cls, _ = network_classes(network)
    fields = {f.name for f in dataclasses.fields(config_cls)}
    return {k: tuple(attrs[a]) if isinstance(attrs[a], list) else attrs[a]
            for k, a in GEOMETRY_ATTRIBUTES.items() if k in fields and a in attrs}


def train_network(network: str, settings: dict, dataset_path: str | os.PathLike, model_path: str | os.PathLike,
                  curve_csv: str | os.PathLike, curve_png: str | os.PathLike, seed: int,
                  train_images: int | None = None, progress: bool = True,
                  device: str | torch.device = "cpu") -> SpotModel:
    """The `train` rule: fit one network on a dataset's train split and write the model file.

    The checkpoints `<model_path>.ckpt` (the training loop's) and `<model_path>.fit.ckpt` (the fit of
    a physics model, after each stage) let an interrupted run resume; they are removed once the model
    file is written. The model trains on `device` (cpu | cuda | auto); its file loads on any device.
    """
    ds = read_dataset(dataset_path)
    loop, config = split_settings(network, {**dataset_geometry(network, ds.attrs), **settings}, seed)
    device = resolve_device(device)
    data = training_data(ds, dataset_path, train_images, seed).to(device)
    torch.manual_seed(seed)
    _, model_cls = network_classes(network)
    model = model_cls(config, tuple(data.images.shape[1:])).to_device(device)
    fit_checkpoint = Path(str(model_path) + ".fit.ckpt")
    model.prepare(data, fit_checkpoint)
    checkpoint = Path(str(model_path) + ".ckpt")
    steps = loop.steps if model.uses_loop else 0
    curve = train(model, data, loop, checkpoint, progress=progress) if steps else model.curve
    save_model(model_path, model, network, config, data.scale, {"dataset": str(dataset_path), "train_images": len(data),
                                                               "steps": steps, "seed": seed})
    write_curve(curve, curve_csv, curve_png, f"{network} on {Path(dataset_path).stem}")
    checkpoint.unlink(missing_ok=True)
    fit_checkpoint.unlink(missing_ok=True)
    log.info("wrote %s (%d training images, %d steps)", model_path, len(data), steps)
    return model


def save_model(path, model: SpotModel, network: str, config, scale: float, meta: dict) -> None:
    """Atomically write a model file: network name, config, weights, image scale, metadata."""
    save_torch_atomic(path, {"format": MODEL_FORMAT, "network": network, "config": dataclasses.asdict(config),
                             "image_shape": tuple(model.image_shape), "state": model.state_dict(), "scale": scale,
                             "meta": meta})


def load_model(path: str | os.PathLike, device: str | torch.device = "cpu") -> tuple[SpotModel, dict]:
    """(model in eval mode on `device` (cpu | cuda | auto), file info) from a model file; DataError
    names the file when it is not one."""
    info = load_torch(path, "a helioflow model file")
    if info.get("format") != MODEL_FORMAT:
        raise DataError(f"{path}: not a helioflow model file (expected format {MODEL_FORMAT})")
    config_cls, model_cls = network_classes(info["network"])
    model = model_cls(config_cls(**info["config"]), tuple(info["image_shape"]))
    model.load_state_dict(info["state"])
    model.to_device(resolve_device(device)).eval()
    return model, info


def load_fitted_model(path: str | os.PathLike, needed_by: str) -> tuple[RaytraceModel, Heliostat, dict]:
    """(physics model, its heliostat, file info) from a model file (load_model, on the CPU); DataError
    naming the file and what needs the fit (`needed_by`: "the plant table") when the file holds a
    network, or a physics model without a heliostat."""
    model, info = load_model(path)
    heliostat = getattr(model, "heliostat", None)
    if getattr(model, "fitted", None) is None or heliostat is None:
        raise DataError(f"{path}: a {info['network']} model has no fitted heliostat; {needed_by} needs a physics "
                        "model (plant.model: drt or raytrace)")
    return cast("RaytraceModel", model), heliostat, info
