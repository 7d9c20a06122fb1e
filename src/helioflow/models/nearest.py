"""`nearest`: the training image whose sun position is closest — what learning nothing scores."""

from __future__ import annotations

import os
from dataclasses import dataclass

import torch
from torch import Tensor

from helioflow.models.base import SpotModel, TrainingData, sun_features


@dataclass(frozen=True)
class NearestConfig:
    """No settings: the prediction for a sun position is the training image with the smallest
    angle between its sun direction and the requested one."""


class Nearest(SpotModel):
    """The baseline that learns nothing: the training image of the closest sun direction."""

    name = "nearest"
    controllable = True
    uses_loop = False

    def __init__(self, config: NearestConfig, image_shape: tuple[int, int]):
        super().__init__()
        self.config = config
        self.image_shape = image_shape
        self.images = torch.zeros(0, *image_shape)  # (N, H, W) normalised training images
        self.directions = torch.zeros(0, 3)  # (N, 3) their sun directions

    def prepare(self, data: TrainingData, checkpoint_path: str | os.PathLike | None = None) -> None:
        """Keep the training images (N, H, W) and their sun directions (N, 3)."""
        self.images = data.images.clone()
        self.directions = sun_features(data.azimuth_deg, data.elevation_deg)

    def get_extra_state(self) -> dict:
        """The kept training data travels in the state dict (its size depends on the data)."""
        return {"images": self.images, "directions": self.directions}

    def set_extra_state(self, state: dict) -> None:
        """Take back the kept training data `get_extra_state` wrote."""
        self.images, self.directions = state["images"].to(self.device), state["directions"].to(self.device)

    def to_device(self, device: torch.device) -> Nearest:
        """Move the model and its kept training data to `device`."""
        super().to_device(device)
        self.images, self.directions = self.images.to(self.device), self.directions.to(self.device)
        return self

    def configure_optimizers(self) -> dict:
        """No optimizers: nothing is trained."""
        return {}

    def training_step(self, batch, optimizers, generator) -> dict[str, float]:
        """Nothing to train: no losses."""
        return {}

    def predict(self, azimuth_deg: Tensor, elevation_deg: Tensor, generator: torch.Generator) -> Tensor:
        """(N,) sun positions (deg) -> (N, H, W) the training images of the closest sun directions."""
        cosines = sun_features(azimuth_deg.to(self.device), elevation_deg.to(self.device)) @ self.directions.T  # (N, M)
        return self.images[cosines.argmax(dim=1)]
