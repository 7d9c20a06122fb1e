"""What every focal-spot model is: the interface the training loop and the evaluation use.

Images inside the models are normalised: divided by the maximum of the training dataset's
images (one scale for the whole dataset, stored with the model), so values lie in [0, ~1].
Sun positions enter in degrees and are encoded by :func:`sun_features`.
"""

from __future__ import annotations

import os
from abc import ABCMeta, abstractmethod
from dataclasses import dataclass

import torch
from torch import Tensor, nn


@dataclass
class TrainingData:
    """The train split of a dataset, normalised.

    Attributes:
        images: (N, H, W) float32 images divided by `scale`.
        azimuth_deg, elevation_deg: (N,) float32 sun positions (deg).
        scale: the dataset's maximum flux (W/m^2) that the images were divided by.
    """

    images: Tensor
    azimuth_deg: Tensor
    elevation_deg: Tensor
    scale: float

    def batch(self, index: Tensor) -> dict[str, Tensor]:
        """{'images': (B, H, W), 'azimuth_deg': (B,), 'elevation_deg': (B,)} for the given indices."""
        return {"images": self.images[index], "azimuth_deg": self.azimuth_deg[index],
                "elevation_deg": self.elevation_deg[index]}

    def __len__(self) -> int:
        return len(self.images)

    def to(self, device: torch.device) -> TrainingData:
        """The same data on `device`."""
        return TrainingData(self.images.to(device), self.azimuth_deg.to(device), self.elevation_deg.to(device),
                            self.scale)


def sun_features(azimuth_deg: Tensor, elevation_deg: Tensor) -> Tensor:
    """(N,) sun positions (deg) -> (N, 3) unit vectors towards the sun (ENU), the continuous
    encoding the conditioned networks use (no wrap-around at +-180 deg)."""
    az, el = torch.deg2rad(azimuth_deg), torch.deg2rad(elevation_deg)
    return torch.stack((torch.cos(el) * torch.sin(az), -torch.cos(el) * torch.cos(az), torch.sin(el)), dim=-1)


class SpotModel(nn.Module, metaclass=ABCMeta):
    """A model that predicts normalised focal-spot images from sun positions.

    Subclasses set `name` and `controllable`, store `image_shape` (H, W) and `config` (their
    config dataclass) in __init__(config, image_shape), and implement `configure_optimizers`,
    `training_step` and `predict`. A model that needs no gradient training (the nearest
    baseline) returns no optimizers and the loop runs no steps.
    """

    name: str = "model"
    controllable: bool = True
    uses_loop: bool = True  # False: `prepare` does all the fitting and the loop runs no steps
    curve: list[dict[str, float]] = []  # a model that fits itself in `prepare` puts its curve here
    image_shape: tuple[int, int]  # set by every subclass's __init__
    device = torch.device("cpu")  # where the model computes (`to_device`)

    def to_device(self, device: torch.device) -> SpotModel:
        """Move the model to `device` (its parameters, buffers and the tensors it keeps) and compute
        there from now on: `prepare` and `training_step` get data on it, `predict` takes sun
        positions on any device and returns images on it. Random draws stay on the CPU
        generators and move to the device (the same seed, the same numbers on every device)."""
        self.device = torch.device(device)
        return self.to(self.device)

    def prepare(self, data: TrainingData, checkpoint_path: str | os.PathLike | None = None) -> None:
        """Look at the training data once before training (e.g. keep it, or size the scene). A model
        that fits itself here keeps its resumable state in `checkpoint_path` (if given)."""

    @abstractmethod
    def configure_optimizers(self) -> dict[str, torch.optim.Optimizer]:
        """Named optimizers; their states are checkpointed by the training loop."""

    @abstractmethod
    def training_step(self, batch: dict[str, Tensor], optimizers: dict, generator: torch.Generator) -> dict[str, float]:
        """One optimisation step on a batch (does backward and optimizer steps itself).

        `generator` is seeded from (seed, step), so a resumed run repeats the same randomness.
        Returns the named losses of the step (floats) for the progress bar and the curve.
        """

    @abstractmethod
    def predict(self, azimuth_deg: Tensor, elevation_deg: Tensor, generator: torch.Generator) -> Tensor:
        """(N,) sun positions (deg) -> (N, H, W) normalised images. An unconditioned model
        ignores the positions and returns N samples. Called under torch.no_grad()."""
