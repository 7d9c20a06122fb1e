"""The tiny field the field tests compose: its config and its measured heliostats' models; Gaussian
spots on a receiver grid for the aim tests."""

from collections.abc import Callable
from pathlib import Path

import torch
import yaml

from helioflow.config import validate_config
from helioflow.data.surfaces import HeliostatSpec, true_heliostat, write_heliostat
from helioflow.data.synthetic import trace_dataset
from helioflow.models.registry import train_network
from helioflow.workflow import (
    PHYSICS_MODELS,
    compose_field_inputs,
    expand_field,
    field_measured,
    trace_params,
    train_params,
)

WORKFLOW = Path(__file__).resolve().parents[1] / "workflow"
PIXEL = (0.05, 0.05)  # the aim tests' receiver pixel (m)


def gaussians(centres_px: list[tuple[float, float]], sigma_px: float, peak: float, size: int = 128) -> torch.Tensor:
    """(N, size, size) Gaussian spots (W/m^2) at (row, column) offsets from the grid centre (px)."""
    y, x = torch.meshgrid(*(torch.arange(size, dtype=torch.float64) - size / 2 + 0.5,) * 2, indexing="ij")
    return torch.stack([peak * torch.exp(-((x - c) ** 2 + (y - r) ** 2) / (2 * sigma_px**2)) for r, c in centres_px])


def tiny_field(edit: Callable[[dict], None] | None = None) -> dict:
    """The tiny field's config, expanded; `edit` changes the raw config first."""
    config = yaml.safe_load((WORKFLOW / "tiny_config.yaml").read_text())
    config.update(yaml.safe_load((WORKFLOW / "tiny_field.yaml").read_text()))
    if edit is not None:
        edit(config)
    return expand_field(validate_config(config))


def build(config: dict, root: Path, network: str = "nearest", settings: dict | None = None
          ) -> tuple[list[str], list[str]]:
    """Surfaces, calibration datasets and models (`network`: the config's field.network; a physics
    model with `settings` over its train_params) of the measured heliostats under root, as the
    surfaces, trace and train rules make them; (model paths, dataset paths)."""
    models, datasets = [], []
    for name, model, dataset in zip(field_measured(config), *compose_field_inputs(config).values()):
        model, dataset = root / model, root / dataset
        surface = root / f"surfaces/{name}.h5"
        surface.parent.mkdir(parents=True, exist_ok=True)
        spec = HeliostatSpec.from_config(name, config["heliostats"][name])
        write_heliostat(surface, true_heliostat(spec), spec)
        trace_dataset(trace_params(config, name), surface, dataset)
        own = {}
        if network in PHYSICS_MODELS:
            own = {**train_params(config, name, network)["settings"], **(settings or {})}
            own["heliostat_path"] = str(surface)
        train_network(
            network, own, dataset, model, root / f"{name}.csv", root / f"{name}.png", seed=0, progress=False
        )
        models.append(str(model))
        datasets.append(str(dataset))
    return models, datasets
