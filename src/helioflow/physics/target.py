"""Target planes (calibration target, receiver) and the camera that photographs them."""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from .geometry import normalize, plane_axes


@dataclass(frozen=True)
class Target:
    """A flat rectangular target seen by a camera as an image of `resolution` pixels.

    Attributes:
        center: (3,) ENU centre (m).
        normal: (3,) unit normal, pointing towards the heliostats.
        width, height: extent along the target's right and up axes (m).
        resolution: (rows, columns); rows run down from the top edge, columns to the right
            as seen from the field (see geometry.plane_axes).
    """

    center: Tensor
    normal: Tensor
    width: float
    height: float
    resolution: tuple[int, int] = (64, 64)

    @staticmethod
    def facing(center, towards, width: float, height: float, resolution=(64, 64), dtype=torch.float32) -> "Target":
        """A target at `center` whose normal points horizontally... or in any direction: at `towards`."""
        c = torch.as_tensor(center, dtype=dtype)
        return Target(c, normalize(torch.as_tensor(towards, dtype=dtype) - c), width, height, tuple(resolution))

    def axes(self) -> tuple[Tensor, Tensor]:
        """(3,) unit vectors along image columns (right) and up."""
        return plane_axes(self.normal)

    @property
    def pixel_size(self) -> tuple[float, float]:
        """(width, height) of one pixel (m)."""
        rows, cols = self.resolution
        return self.width / cols, self.height / rows

    @property
    def pixel_area(self) -> float:
        pw, ph = self.pixel_size
        return pw * ph

    def pixel_centres(self, dtype=torch.float32, device=None) -> tuple[Tensor, Tensor]:
        """Pixel centres in target coordinates: u (W,) along right, v (H,) along up, top row first (m)."""
        rows, cols = self.resolution
        pw, ph = self.pixel_size
        u = (torch.arange(cols, dtype=dtype, device=device) + 0.5) * pw - self.width / 2
        v = self.height / 2 - (torch.arange(rows, dtype=dtype, device=device) + 0.5) * ph
        return u, v

    def to_plane(self, points: Tensor) -> Tensor:
        """(..., 3) ENU points -> (..., 2) target coordinates (u right, v up) in m."""
        right, up = self.axes()
        d = points - self.center
        return torch.stack(((d * right).sum(-1), (d * up).sum(-1)), dim=-1)


def centroid(images: Tensor, target: Target) -> Tensor:
    """(N, H, W) flux -> (N, 2) flux-weighted centroid (u, v) in target coordinates (m)."""
    u, v = target.pixel_centres(images.dtype, images.device)
    total = images.sum((-2, -1)).clamp_min(1e-30)
    return torch.stack(((images.sum(-2) * u).sum(-1) / total, (images.sum(-1) * v).sum(-1) / total), dim=-1)
