"""`nerf`: the focal spot as a view of a static scene, rendered like a NeRF.

After Pargmann et al., "Towards a Neural Network Based Flux Density Prediction – Using Generative
Models to Enhance CSP Raytracing" (AIP Conf. Proc. 2815): the sun position plays the part of the
viewing direction, the focal-spot image lies on a virtual sphere around the heliostat, a
coordinate transform keeps the scene static, an MLP with positional encoding predicts density
and intensity at points of the scene, and volume rendering along camera rays forms the image.
This module works that idea out with the project's geometry (docs/physics.md).

Geometry
--------
Frames. World: ENU. Heliostat frame H: (mirror right, mirror up, mirror normal) = (x, y, z),
origin at the pivot (the mirror centre). R(s): H -> ENU for the sun direction s, from the mount's
kinematics (helioflow.physics.heliostat, ideal joint angles, no tracking errors).

Beam. b = (aim point - heliostat) / L, L the slant range: the direction in which the heliostat
sends the sun's central ray. It does not change with the sun, because the controller turns the
mirror normal to the bisector n = (s + b) / |s + b| of sun and aim direction.

Half angle. Because n bisects s and the fixed b, a sun that moves by an angle a along a great
circle through b turns the normal by exactly a / 2 along the same circle (in general by about
a / 2): the heliostat, and everything fixed to it, turns by half the sun's angle.

Static scene. Instead of the heliostat turning in front of a fixed target, hold the heliostat
still and turn the world around it by R(s)^T. In H the mirror - its facets, canting, deformation -
never moves; the sun position only chooses from where it is seen:

    camera (viewing) direction  d(s) = R(s)^T b              (unit vector in H, d_z = cos(incidence))
    sun direction in H          s_H  = R(s)^T s = 2 d_z z - d   (the mirror image of d in the normal z)

so d and s_H determine each other: the sun position is the viewing direction (reflected in the
mirror normal). The angle of incidence, d's angle from z, is half the angle between s and b, so
as the sun crosses the sky the camera moves over the unit sphere of H by about half the sun's
angle.

Virtual sphere and camera. Seen from H, the target centre sits at L d(s), on the sphere of radius
L around the mirror: the virtual sphere. The focal-spot image lies on that sphere at the viewing
direction, on the target plane (fixed in the world, tilted against b by the angle between beam
and target normal). The camera is the target looking back at the mirror: an orthographic camera
whose rays run along the beam. Pixel (i, j) at target point p_ij is the line through p_ij
parallel to b; relative to the heliostat it is {q_ij + t b}, q_ij = (p_ij - aim) with its
component along b removed, and in H it is {R^T q_ij + t d}. Why orthographic along the beam: a
flat mirror reflects the sun's central rays into a parallel beam along b, so the pixel is lit by
the mirror point its backward ray meets - the camera sees the mirror where the mirror lights the
target. The flux a mirror point sends (reflectivity, cosine of incidence through the foreshortened
area, the spread by sun shape, slope errors and surface deformation) is what the field learns.
Lengths are in window widths (image width = 1), so the model needs no window size; the only
geometry it takes from its config is the heliostat position, aim point, target normal and mount
(defaults: the project's default datasets) and, for focusing heliostats, the canting distance.

Scene slab and samples. The mirror lies in the plane z = 0 of H. The scene is the slab
|z| <= `slab` around it, and each ray is sampled where it crosses `samples` equally spaced planes
z_k: t_k = (z_k - o_z) / d_z for the ray origin o = R^T q, spacing dt = 2 slab / (samples d_z).
No samples fall into empty space, and at oblique incidence they spread over the mirror as the
ray does. The scene point x = o + t_k d (scaled by `scene_scale`) is the MLP's input.

Focusing (the one physics term beyond the paper). Rays of a canted (focusing) heliostat converge
instead of running parallel. A mirror point whose normal is tilted from z by the small in-plane
vector e sends its light off the central ray by 2 L (d_z e - (d.e) z); followed back along d onto
the mirror plane that is the displacement A(d) 2 L e with

    A(d) = d_z I + d_xy d_xy^T / d_z        (2x2; stretches tangential deflections by 1/d_z and
                                             shrinks sagittal ones by d_z: astigmatism)

On-axis canting at focal distance f tilts the normal at r by e = -r / (2 f), so the ray that meets
the mirror plane at m comes from the mirror point r = M m, M = (I - k A(d))^-1, k = L / f, and the
flux is concentrated by det M. The renderer samples the static scene at (M x_xy, z) and scales
the flux by det M: the heliostat acts as a view-dependent, astigmatic magnifier. Without
`canting_focal_distance_m` (flat or unfocused mirrors) M = I. On semi_sphere (canted at 200 m,
k = 0.316) this is worth about +2.5 dB; learning k by gradient descent from k = 0 does not work
(the field adapts first and k stays near 0.04), so it is a config value from the heliostat design.

Field and rendering
-------------------
Positional encoding gamma(p) = (p, sin(2^i pi p), cos(2^i pi p)), i < L, per coordinate. The
trunk (`depth` ReLU layers of `width`) reads gamma(x) - and gamma(s_H) with `condition` - and
gives the density sigma = softplus(.) and a feature; a head reads the feature and gamma(s_H)
(`view_frequencies` octaves) and gives the intensity c = softplus(.). The image is

    emission (default)         I = sum_k sigma_k c_k dt_k * det M      flux adds up: the beams of
                                                                       overlapping facets add,
                                                                       nothing blocks the beam
    emission-absorption (NeRF) I = sum_k T_k (1 - exp(-sigma_k dt_k)) c_k * det M,
                               T_k = prod_{j<k} exp(-sigma_j dt_j)

Departures from the paper's formulation and why (`condition=False, emission=False` and no
canting distance give the paper's): the density also sees the sun direction (`condition`), because
the spot is not a static scene - deflections by deformation and canting scale with the incidence
angle (A(d) above), so caustics move and facet images stretch with the sun; additive emission,
because flux is additive; and the focusing map. PSNR (dB; train / interpolation / extrapolation,
images over the dataset maximum, seed 0, 2-core CPU, torch 2.13):

    semi_sphere, 1000-2000 steps, 16 samples, lr 5e-3      train   interp  extrap
      paper formulation (2000 steps, tracking learned)     31.75   31.10   26.90
      + density sees the sun direction                     31.95   31.65   28.12
      + additive emission                                  32.33   32.13   28.28
      + focusing map (canting 200 m, k = 0.316)            35.03   34.62   30.88
    defaults, 8000 steps, batch 16 (2 threads)
      semi_sphere (canting_focal_distance_m=200), 171 s    42.77   41.89   34.08
      sanity_check, 163 s                                  62.18   62.04   51.17
    nearest training image
      semi_sphere                                          -       35.93   27.16
      sanity_check                                         -       67.27   40.85

The sanity_check scan is so dense (0.4 deg steps) that its nearest image is almost exact; the
NeRF's 62 dB is still climbing at the end of the budget (58 dB at 4500 steps). Tried and dropped:
tri-plane feature grids instead of the frequency encoding (faster to fit, 5 dB worse
extrapolation on sanity_check); learning the five tracking errors jointly (they are not
identifiable against the scene and drifted to 10-20 mrad without a gain); learning k from 0;
thinner slabs; 4 view octaves (4 dB worse); width 96 (no gain at equal time).

Training renders `rays` random pixels of the batch's images (drawn with the step's generator),
loss MSE on normalised images; Adam with a linear warm-up over `warmup_steps` and an exponential
decay from `lr` to `lr_final` over `decay_steps` (set it to the loop's steps). The schedule reads
the step count from a buffer saved with the model, so a resumed run continues it exactly.
`predict` renders all pixels in chunks of `chunk` rays.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from helioflow.checks import check_ranges, check_types
from helioflow.errors import ConfigError
from helioflow.models.base import SpotModel, sun_features
from helioflow.physics.geometry import normalize, plane_axes
from helioflow.physics.heliostat import MOUNTS, REST_FRAME, ideal_joint_angles, joint_rotation


@dataclass(frozen=True)
class NerfConfig:
    """Settings of the spot NeRF (the training loop's steps and batch size are separate).

    Attributes:
        frequencies: positional-encoding octaves L of the scene point (highest 2^(L-1) pi).
        view_frequencies: octaves of the sun direction in the heliostat frame.
        width: hidden units per layer.
        depth: hidden layers of the trunk (the intensity head adds one of width / 2).
        samples: samples per ray, one on each of that many planes through the scene slab.
        rays: pixels (rays) rendered per training step, drawn from the batch's images.
        slab: half-thickness of the scene slab around the mirror plane, in window widths.
        scene_scale: window widths -> units of the encoding's input.
        condition: the density also sees the sun direction (False: only the intensity, as in
            the paper and NeRF).
        emission: additive emission rendering (False: NeRF's emission-absorption).
        lr: peak Adam learning rate.
        lr_final: learning rate reached after decay_steps (exponential decay), then kept.
        warmup_steps: linear warm-up of the learning rate from lr / warmup_steps.
        decay_steps: length of the decay; set it to the loop's steps.
        chunk: rays rendered at once by predict (bounds memory).
        mount: the heliostat's mount type (helioflow.physics.heliostat.MOUNTS).
        heliostat_position_m: ENU position of the heliostat's pivot (m).
        aim_point_m: ENU aim point, the target centre (m).
        target_normal: ENU normal of the target plane, towards the field.
        canting_focal_distance_m: on-axis canting distance of a focusing heliostat (m); None for
            flat or unfocused mirrors (no focusing map).
    """

    frequencies: int = 8
    view_frequencies: int = 2
    width: int = 64
    depth: int = 3
    samples: int = 8
    rays: int = 2048
    slab: float = 0.1
    scene_scale: float = 1.5
    condition: bool = True
    emission: bool = True
    lr: float = 1e-2
    lr_final: float = 2e-4
    warmup_steps: int = 100
    decay_steps: int = 8000
    chunk: int = 8192
    mount: str = "az_el"
    heliostat_position_m: tuple[float, float, float] = (0.0, 60.0, 0.0)
    aim_point_m: tuple[float, float, float] = (0.0, 0.0, 20.0)
    target_normal: tuple[float, float, float] = (0.0, 1.0, 0.0)
    canting_focal_distance_m: float | None = None

    def __post_init__(self) -> None:
        check_types(self)
        check_ranges(self, at_least_one=("width", "depth", "samples", "rays", "chunk", "warmup_steps", "decay_steps"),
                     counts=("frequencies", "view_frequencies"), positive=("slab", "scene_scale", "lr", "lr_final"),
                     at_most={"width": (4096, "weights per layer grow as width squared"),
                              "depth": (64, "layers evaluated per sample"), "samples": (1024, "samples per ray"),
                              "rays": (1_000_000, "rays x samples points evaluated per step"),
                              "chunk": (1_000_000, "rays x samples points held in memory at once"),
                              "frequencies": (32, "float32 resolves no finer octaves"),
                              "view_frequencies": (32, "float32 resolves no finer octaves")})
        if self.mount not in MOUNTS:
            raise ConfigError(f"mount = {self.mount!r}: expected one of {', '.join(MOUNTS)}")
        for key in ("heliostat_position_m", "aim_point_m", "target_normal"):
            if len(getattr(self, key)) != 3:
                raise ConfigError(f"{key} = {getattr(self, key)}: expected three numbers (ENU)")
        if self.canting_focal_distance_m is not None and not float(self.canting_focal_distance_m) > 0:
            raise ConfigError(f"canting_focal_distance_m = {self.canting_focal_distance_m}: "
                              "expected a distance > 0 (m) or null for flat mirrors")


# ---------------------------------------------------------------------------------------------
# geometry


def beam_direction(heliostat_position: Tensor, aim_point: Tensor) -> Tensor:
    """(3,) unit vector from the heliostat to the aim point: the direction of the reflected beam."""
    return normalize(aim_point - heliostat_position)


def mirror_normal(sun: Tensor, beam: Tensor) -> Tensor:
    """(..., 3) ideal mirror normals: the bisectors of the sun directions and the beam direction."""
    return normalize(sun + beam)


def heliostat_rotation(mount: str, sun: Tensor, beam: Tensor) -> Tensor:
    """(S, 3) sun directions -> (S, 3, 3) rotations R from the heliostat frame to ENU (columns:
    mirror right, up, normal), through the mount's ideal kinematics."""
    angle1, angle2 = ideal_joint_angles(mount, mirror_normal(sun, beam))
    no_errors = torch.zeros(5, dtype=sun.dtype, device=sun.device)
    rest = REST_FRAME.to(dtype=sun.dtype, device=sun.device)
    return joint_rotation(mount, angle1, angle2, no_errors) @ rest


def camera_direction(rotation: Tensor, beam: Tensor) -> Tensor:
    """(S, 3) viewing directions d = R^T b in the heliostat frame: where the camera (the target)
    sits on the virtual sphere around the static mirror, as a unit vector."""
    return beam @ rotation


def focusing_map(direction: Tensor, k: float) -> tuple[Tensor, Tensor]:
    """The mirror-plane map of a focusing heliostat for viewing directions d (S, 3) and
    k = slant range / canting distance: (M (S, 2, 2), det M (S,)), M = (I - k A(d))^-1,
    A(d) = d_z I + d_xy d_xy^T / d_z."""
    dxy, dz = direction[:, :2], direction[:, 2:3, None]
    eye = torch.eye(2, dtype=direction.dtype, device=direction.device)
    a = dz * eye + dxy[:, :, None] * dxy[:, None, :] / dz
    m = torch.linalg.inv(eye - k * a)
    return m, torch.linalg.det(m)


def encode(x: Tensor, frequencies: int) -> Tensor:
    """(..., C) -> (..., C (1 + 2 L)): x, sin(2^i pi x), cos(2^i pi x) for i < L."""
    if frequencies == 0:
        return x
    scales = math.pi * 2.0 ** torch.arange(frequencies, dtype=x.dtype, device=x.device)
    xs = (x[..., None, :] * scales[:, None]).flatten(-2)
    return torch.cat((x, torch.sin(xs), torch.cos(xs)), dim=-1)


# ---------------------------------------------------------------------------------------------
# the network


class RadianceField(nn.Module):
    """(points (..., 3), sun directions in H (..., 3)) -> (density, intensity), both (...) >= 0."""

    def __init__(self, config: NerfConfig):
        super().__init__()
        self.frequencies, self.view_frequencies = config.frequencies, config.view_frequencies
        self.condition = config.condition
        n_view = 3 * (1 + 2 * config.view_frequencies)
        n_in = 3 * (1 + 2 * config.frequencies) + (n_view if config.condition else 0)
        layers: list[nn.Module] = []
        for _ in range(config.depth):
            layers += [nn.Linear(n_in, config.width), nn.ReLU()]
            n_in = config.width
        self.trunk = nn.Sequential(*layers)
        self.density = nn.Linear(config.width, 1)
        half = max(config.width // 2, 1)
        self.head = nn.Sequential(nn.Linear(config.width + n_view, half), nn.ReLU(), nn.Linear(half, 1))

    def forward(self, x: Tensor, view: Tensor) -> tuple[Tensor, Tensor]:
        """(points (..., 3), sun directions (..., 3)) -> (density, intensity), both (...) >= 0."""
        point = encode(x, self.frequencies)
        v = encode(view, self.view_frequencies).expand(*point.shape[:-1], -1)
        h = self.trunk(torch.cat((point, v), -1) if self.condition else point)
        sigma = F.softplus(self.density(h).squeeze(-1))
        intensity = F.softplus(self.head(torch.cat((h, v), -1)).squeeze(-1))
        return sigma, intensity


class SpotNeRF(SpotModel):
    """Focal spots rendered from a static scene in the heliostat frame (see the module docstring)."""

    name = "nerf"
    controllable = True
    beam: Tensor  # buffers (register_buffer in __init__)
    ray_offsets: Tensor
    levels: Tensor
    steps_done: Tensor

    def __init__(self, config: NerfConfig, image_shape: tuple[int, int]):
        super().__init__()
        self.config = config
        self.image_shape = (int(image_shape[0]), int(image_shape[1]))
        f64 = torch.float64
        heliostat = torch.tensor(config.heliostat_position_m, dtype=f64)
        aim = torch.tensor(config.aim_point_m, dtype=f64)
        beam = beam_direction(heliostat, aim)
        right, up = plane_axes(normalize(torch.tensor(config.target_normal, dtype=f64)))
        rows, cols = self.image_shape
        # pixel centres on the target, in window widths (square pixels), then perpendicular to the beam
        u = (torch.arange(cols, dtype=f64) + 0.5) / cols - 0.5
        v = (0.5 - (torch.arange(rows, dtype=f64) + 0.5) / rows) * rows / cols
        offset = u[None, :, None] * right + v[:, None, None] * up  # (H, W, 3)
        offset = offset - (offset @ beam)[..., None] * beam
        levels = ((torch.arange(config.samples, dtype=f64) + 0.5) / config.samples * 2 - 1) * config.slab
        self.register_buffer("beam", beam.float(), persistent=False)
        self.register_buffer("ray_offsets", offset.reshape(-1, 3).float(), persistent=False)
        self.register_buffer("levels", levels.float(), persistent=False)
        self.register_buffer("steps_done", torch.zeros((), dtype=torch.long))
        slant = float((aim - heliostat).norm())
        f = config.canting_focal_distance_m
        self.focus = 0.0 if f is None else slant / float(f)  # k = L / f of the focusing map
        self.field = RadianceField(config)

    # geometry per image --------------------------------------------------------------------

    def views(self, azimuth_deg: Tensor, elevation_deg: Tensor) -> dict[str, Tensor]:
        """Per sun position: rotation R (N, 3, 3), viewing direction d (N, 3), sun direction in
        the heliostat frame (N, 3), focusing map M (N, 2, 2) and its determinant (N,)."""
        sun = sun_features(azimuth_deg.float().to(self.device), elevation_deg.float().to(self.device))
        rotation = heliostat_rotation(self.config.mount, sun, self.beam)
        direction = camera_direction(rotation, self.beam)
        sun_h = (sun[:, None, :] @ rotation)[:, 0]
        if self.focus:
            warp, gain = focusing_map(direction, self.focus)
        else:
            warp = torch.eye(2, device=sun.device).expand(len(sun), 2, 2)
            gain = torch.ones(len(sun), device=sun.device)
        return {"rotation": rotation, "direction": direction, "sun": sun_h, "warp": warp, "gain": gain}

    def render(self, views: dict[str, Tensor], image_index: Tensor, pixel_index: Tensor) -> Tensor:
        """(R,) image indices into `views` and pixel indices (row-major) -> (R,) normalised flux."""
        c = self.config
        direction = views["direction"][image_index]  # (R, 3)
        origin = (self.ray_offsets[pixel_index][:, None, :] @ views["rotation"][image_index])[:, 0]  # (R, 3)
        cos_i = direction[:, 2:3]
        t = (self.levels - origin[:, 2:3]) / cos_i  # (R, S): where the ray crosses each plane
        x = origin[:, None, :] + t[..., None] * direction[:, None, :]  # (R, S, 3) in the heliostat frame
        if self.focus:
            xy = x[..., :2] @ views["warp"][image_index].transpose(1, 2)
            x = torch.cat((xy, x[..., 2:]), -1)
        dt = (2 * c.slab / c.samples) / cos_i  # (R, 1)
        sigma, intensity = self.field(x * c.scene_scale, views["sun"][image_index][:, None, :])
        if c.emission:
            flux = (sigma * dt * intensity).sum(-1)
        else:
            alpha = 1 - torch.exp(-sigma * dt)
            optical_depth = torch.cat((torch.zeros_like(sigma[:, :1]), sigma[:, :-1] * dt), 1).cumsum(1)
            transmitted = torch.exp(-optical_depth)
            flux = (transmitted * alpha * intensity).sum(-1)
        return flux * views["gain"][image_index]

    # SpotModel interface ---------------------------------------------------------------------

    def configure_optimizers(self) -> dict[str, torch.optim.Optimizer]:
        """One Adam over the radiance field's parameters."""
        return {"nerf": torch.optim.Adam(self.field.parameters(), lr=self.config.lr)}

    def learning_rate(self, step: int) -> float:
        """Warm-up, then exponential decay from lr to lr_final over decay_steps."""
        c = self.config
        warm = min((step + 1) / c.warmup_steps, 1.0)
        return warm * c.lr * (c.lr_final / c.lr) ** min(step / c.decay_steps, 1.0)

    def training_step(self, batch: dict[str, Tensor], optimizers: dict,
                      generator: torch.Generator) -> dict[str, float]:
        """One step on `rays` random pixels of the batch: their rendered flux against the images (MSE)."""
        images = batch["images"]
        n_images, n_pixels = images.shape[0], images.shape[1] * images.shape[2]
        flat = torch.randint(0, n_images * n_pixels, (self.config.rays,), generator=generator).to(self.device)
        image_index, pixel_index = flat // n_pixels, flat % n_pixels
        optimizer = optimizers["nerf"]
        for group in optimizer.param_groups:
            group["lr"] = self.learning_rate(int(self.steps_done))
        views = self.views(batch["azimuth_deg"], batch["elevation_deg"])
        target = images.reshape(n_images, n_pixels)[image_index, pixel_index]
        loss = F.mse_loss(self.render(views, image_index, pixel_index), target)
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        optimizer.step()
        self.steps_done += 1
        return {"loss": float(loss.detach())}

    def predict(self, azimuth_deg: Tensor, elevation_deg: Tensor,
                generator: torch.Generator | None = None) -> Tensor:
        """(N,) sun positions (deg) -> (N, H, W) rendered images, in chunks of `chunk` pixels."""
        rows, cols = self.image_shape
        n_pixels = rows * cols
        with torch.no_grad():
            views = self.views(azimuth_deg, elevation_deg)
            total = len(azimuth_deg) * n_pixels
            out = torch.empty(total, device=self.device)
            for start in range(0, total, self.config.chunk):
                flat = torch.arange(start, min(start + self.config.chunk, total), device=self.device)
                out[flat] = self.render(views, flat // n_pixels, flat % n_pixels)
        return out.reshape(len(azimuth_deg), rows, cols)
