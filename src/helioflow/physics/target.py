"""Target planes (calibration target, receiver) and the camera that photographs them."""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from helioflow.physics.geometry import normalize, plane_axes

CAMERA_PIXEL_VARIANCE = 1 / 12  # pixel^2 per axis: a camera pixel integrates the flux over its square (a box)
TENT_VARIANCE = 1 / 6  # pixel^2 per axis: a bilinear deposit, averaged over where hits fall in a pixel


@dataclass(frozen=True)
class Target:
    """A flat rectangular target seen by a camera as an image of `resolution` pixels.

    Attributes:
        center: (3,) ENU centre (m).
        normal: (3,) unit normal, pointing towards the heliostats.
        width, height: extent along the target's right and up axes (m).
        resolution: (rows, columns); rows run down from the top edge, columns to the right
            as seen from the field (see geometry.plane_axes).
        aim: (3,) ENU point the heliostats aim at (m), when it is not the centre (PAINT: the
            tower file's `center` entry, off the middle of the target's corners); None = center.
        pixel_variance: variance (pixel^2 per axis) of the filter by which the images average the
            flux over pixels: CAMERA_PIXEL_VARIANCE for a camera (each pixel integrates its square),
            TENT_VARIANCE for images helioflow's bilinear Monte Carlo traced; None = whatever the
            tracer's splat gives (images of the kernel splat itself, receivers' flux maps).
    """

    center: Tensor
    normal: Tensor
    width: float
    height: float
    resolution: tuple[int, int] = (64, 64)
    aim: Tensor | None = None
    pixel_variance: float | None = None

    @property
    def aim_point(self) -> Tensor:
        """(3,) ENU point the heliostats aim at (m): `aim`, or the centre."""
        return self.center if self.aim is None else self.aim

    @staticmethod
    def facing(center, towards, width: float, height: float, resolution=(64, 64), dtype=torch.float32) -> Target:
        """A target at `center` (3,) m whose normal points at the ENU point `towards` (3,) m."""
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
        """The area of one pixel (m^2)."""
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

    def centroid(self, images: Tensor) -> Tensor:
        """(N, H, W) flux -> (N, 2) flux-weighted centroid (u, v) in target coordinates (m)."""
        row_col = pixel_centroid(images)
        pw, ph = self.pixel_size
        return torch.stack(((row_col[..., 1] + 0.5) * pw - self.width / 2,
                            self.height / 2 - (row_col[..., 0] + 0.5) * ph), dim=-1)


def pixel_centroid(images: Tensor) -> Tensor:
    """(..., H, W) flux -> (..., 2) flux-weighted centroid (row, col) in pixels from the centre of
    pixel (0, 0); negative values count as 0, an image without positive flux has none (NaN).
    The one centroid of helioflow: scoring's metric (scoring.metrics.centroid_px) and
    `Target.centroid` use it."""
    flux = images.clamp_min(0.0)
    total = flux.sum((-2, -1))
    rows = torch.arange(images.shape[-2], dtype=images.dtype, device=images.device)
    cols = torch.arange(images.shape[-1], dtype=images.dtype, device=images.device)
    centre = torch.stack(((flux.sum(-1) * rows).sum(-1), (flux.sum(-2) * cols).sum(-1)), dim=-1) / total[..., None]
    return torch.where(total[..., None] > 0, centre, torch.nan)


@dataclass(frozen=True)
class Camera:
    """The calibration camera: what turns the flux on the target into the measured image.

    image = gain * blur(flux) + background + noise, clipped at 0.

    Attributes:
        gain: multiplies the flux (1).
        background: constant added to every pixel (W/m^2 equivalent).
        blur_px: std of an isotropic Gaussian blur (pixels); 0 = sharp.
        noise: std of additive Gaussian noise as a fraction of each image's peak; 0 = none.
        seed: seed of the noise.
    """

    gain: float = 1.0
    background: float = 0.0
    blur_px: float = 0.0
    noise: float = 0.0
    seed: int = 0

    def apply(self, flux: Tensor) -> Tensor:
        """(N, H, W) flux (W/m^2) -> (N, H, W) measured images (same unit), differentiable in the flux."""
        image = gaussian_blur(flux, self.blur_px) * self.gain + self.background
        if self.noise > 0:
            generator = torch.Generator().manual_seed(self.seed)
            peak = image.amax((-2, -1), keepdim=True)
            noise = torch.randn(image.shape, generator=generator, dtype=image.dtype).to(image.device)
            image = image + self.noise * peak * noise
        return image.clamp_min(0.0)


def gaussian_blur(images: Tensor, sigma_px: float) -> Tensor:
    """(N, H, W) images blurred by a separable Gaussian of std sigma_px pixels (zero padding)."""
    if sigma_px <= 0:
        return images
    radius = max(1, int(3 * sigma_px + 0.5))
    x = torch.arange(-radius, radius + 1, dtype=images.dtype, device=images.device)
    k = torch.exp(-0.5 * (x / sigma_px) ** 2)
    k = k / k.sum()
    out = torch.nn.functional.conv2d(images[:, None], k.view(1, 1, 1, -1), padding=(0, radius))
    return torch.nn.functional.conv2d(out, k.view(1, 1, -1, 1), padding=(radius, 0))[:, 0]
