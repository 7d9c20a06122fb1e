"""What a physics model traces: a design heliostat, a target and an effect list, simulated as the
camera sees it (`Scene`), or linearised in the heliostat tensors at fixed sun positions
(`LinearisedScene`); and images as a loss compares them (`normalised`).

Heliostat tensors (what a fit moves): {"tracking": (5,) mrad, "canting": (F, 2) mrad,
"surface": (F, C, C) mm}. Canting enters without its mean and heights without each facet's
plane (`effective_tensors`), so that no effect can mimic another.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any, Literal, cast, overload

import torch
from torch import Tensor

from helioflow.physics.effects import FIT, TENSOR_EFFECTS, resolve
from helioflow.physics.heliostat import Heliostat
from helioflow.physics.linearised import LinearisedTrace, linearise
from helioflow.physics.raytrace import trace
from helioflow.physics.target import CAMERA_PIXEL_VARIANCE, TENT_VARIANCE, Target


@dataclass(frozen=True)
class Scene:
    """What a physics model traces.

    Attributes:
        heliostat: the design geometry (no errors), float32.
        target: the calibration target.
        dni: direct normal irradiance (W/m^2).
        splat, rays, cells_per_side: trace settings (see physics.raytrace.trace); a point sun
            without slope error has no beam-spread kernel and is traced with `rays` bilinear rays.
        neighbours: (K, 3) ENU pivots of the neighbouring heliostats (same design), where known
            (effect neighbour_shading); None: unknown.
    """

    heliostat: Heliostat
    target: Target
    dni: float
    splat: str = "kernel"
    rays: int = 200_000
    cells_per_side: int = 16
    neighbours: Tensor | None = None

    @overload
    def simulate(self, effects: dict, tensors: dict[str, Tensor], azimuth_deg: Tensor, elevation_deg: Tensor,
                 seed: int = 0, with_lost: Literal[False] = False, facets: Tensor | None = None,
                 mirror_weight: Tensor | None = None, projected: bool = False) -> Tensor: ...

    @overload
    def simulate(self, effects: dict, tensors: dict[str, Tensor], azimuth_deg: Tensor, elevation_deg: Tensor,
                 seed: int = 0, *, with_lost: Literal[True], facets: Tensor | None = None,
                 mirror_weight: Tensor | None = None, projected: bool = False) -> tuple[Tensor, Tensor]: ...

    @overload
    def simulate(self, effects: dict, tensors: dict[str, Tensor], azimuth_deg: Tensor, elevation_deg: Tensor,
                 seed: int = 0, with_lost: bool = False, facets: Tensor | None = None,
                 mirror_weight: Tensor | None = None, projected: bool = False) -> Tensor | tuple[Tensor, Tensor]: ...

    def simulate(self, effects: dict, tensors: dict[str, Tensor], azimuth_deg: Tensor, elevation_deg: Tensor,
                 seed: int = 0, with_lost: bool = False, facets: Tensor | None = None,
                 mirror_weight: Tensor | None = None, projected: bool = False) -> Tensor | tuple[Tensor, Tensor]:
        """(N,) sun positions (deg) -> (N, H, W) images (W/m^2) under `effects` (numbers only for
        scalars) with the heliostat tensors in `tensors` ({"tracking": (5,) mrad, "canting": (F, 2)
        mrad, "surface": (F, C, C) mm}, each optional; "fit" entries of `effects` are taken from
        them), differentiable in the tensors.

        with_lost: also return (N,) the flux that missed the image (reflected towards the target
        plane but landing beside the image), as the sum of the pixels it would fill (times the
        camera's gain): a shape comparison counts it as misplaced (see `normalised`).

        facets: (K,) long: trace only these facets (the tensors are still the whole heliostat's),
        with K / F of the rays; their images add up to the heliostat's.

        mirror_weight: (P,) weight of each surface point's power (physics.raytrace.trace; the whole
        heliostat's points, not with `facets`).

        projected: the tensors are already as the heliostat takes them (`effective_tensors`) and
        are traced as given: a change of one facet's entry then changes that facet alone (what a
        Jacobian per facet needs, models/uncertainty.py)."""
        physics = self._physics(effects)
        h = with_tensors(physics.heliostat, tensors if projected else effective_tensors(tensors))
        rays = self.rays
        if facets is not None:
            h, rays = h.facets(facets), max(1, self.rays * len(facets) // h.n_facets)
        azimuth, elevation = torch.deg2rad(azimuth_deg), torch.deg2rad(elevation_deg)
        traced = trace(h, self.target, azimuth, elevation, physics.optics, rays=rays,
                       splat=self._splat(physics.optics), cells_per_side=self.cells_per_side, seed=seed,
                       with_launched=with_lost, mirror_weight=mirror_weight)
        return photographed(physics, self.target, traced, with_lost)

    def _physics(self, effects: dict):
        """The effects (their "fit" entries dropped) resolved on the design heliostat."""
        scalars = {e: {k: v for k, v in (p or {}).items() if v != FIT} for e, p in effects.items()}
        return resolve(scalars, self.heliostat, self.dni, self.neighbours)

    def _splat(self, optics) -> str:
        """A point sun without slope error has no beam-spread kernel: it is traced with rays."""
        sharp = optics.sun.kind == "point" and optics.slope_error == 0.0
        return "bilinear" if sharp else self.splat


@dataclass(frozen=True)
class LinearisedScene:
    """A scene's trace at fixed sun positions, linearised in the heliostat tensors
    (physics.linearised): what a fit of heliostat tensors descends on. Same `simulate` as the
    scene's, at those sun positions only; noise-free (the kernel trace's expected image)."""

    scene: Scene
    trace: LinearisedTrace
    azimuth_deg: Tensor
    elevation_deg: Tensor

    @classmethod
    def of(cls, scene: Scene, effects: dict, tensors: dict[str, Tensor], azimuth_deg: Tensor,
           elevation_deg: Tensor) -> LinearisedScene:
        """`scene` linearised at `tensors` (raw fit tensors; see Scene.simulate) for the (N,) sun
        positions (deg)."""
        h = scene._physics(effects).heliostat
        trace_ = linearise(h, scene.target, torch.deg2rad(azimuth_deg), torch.deg2rad(elevation_deg),
                           scene.cells_per_side, effective_tensors(tensors))
        return cls(scene, trace_, azimuth_deg, elevation_deg)

    @property
    def heliostat(self) -> Heliostat:
        """The scene's heliostat."""
        return self.scene.heliostat

    @overload
    def simulate(self, effects: dict, tensors: dict[str, Tensor], azimuth_deg: Tensor, elevation_deg: Tensor,
                 seed: int = 0, with_lost: Literal[False] = False, facets: Tensor | None = None,
                 projected: bool = False) -> Tensor: ...

    @overload
    def simulate(self, effects: dict, tensors: dict[str, Tensor], azimuth_deg: Tensor, elevation_deg: Tensor,
                 seed: int = 0, *, with_lost: Literal[True], facets: Tensor | None = None,
                 projected: bool = False) -> tuple[Tensor, Tensor]: ...

    @overload
    def simulate(self, effects: dict, tensors: dict[str, Tensor], azimuth_deg: Tensor, elevation_deg: Tensor,
                 seed: int = 0, with_lost: bool = False, facets: Tensor | None = None,
                 projected: bool = False) -> Tensor | tuple[Tensor, Tensor]: ...

    def simulate(self, effects: dict, tensors: dict[str, Tensor], azimuth_deg: Tensor, elevation_deg: Tensor,
                 seed: int = 0, with_lost: bool = False, facets: Tensor | None = None,
                 projected: bool = False) -> Tensor | tuple[Tensor, Tensor]:
        """As Scene.simulate, at the sun positions the scene was linearised for (`seed` is unused)."""
        if not (torch.equal(azimuth_deg, self.azimuth_deg) and torch.equal(elevation_deg, self.elevation_deg)):
            raise ValueError("a linearised scene traces only the sun positions it was linearised for")
        physics = self.scene._physics(effects)
        effective = tensors if projected else effective_tensors(tensors)
        traced = self.trace.images(effective, physics.optics, facets, with_launched=with_lost)
        return photographed(physics, self.scene.target, traced, with_lost)


def photographed(physics, target: Target, traced: Tensor | tuple[Tensor, Tensor],
                 with_lost: bool) -> Tensor | tuple[Tensor, Tensor]:
    """A trace's flux (N, H, W) W/m^2 (and, with_lost, the (N,) power launched towards the target
    plane, W) as the camera sees it: images, and with_lost the flux that missed them (see
    Scene.simulate)."""
    # `traced` is (flux, launched) with_lost, the flux alone without
    flux, launched = cast(tuple[Tensor, Tensor], traced) if with_lost else (cast(Tensor, traced), None)
    images = physics.camera.apply(flux) if physics.camera is not None else flux
    if launched is None:
        return images
    gain = physics.camera.gain if physics.camera is not None else 1.0
    return images, (launched / target.pixel_area - flux.sum((-2, -1))).clamp_min(0.0) * gain


def with_tensors(heliostat: Heliostat, effective: dict[str, Tensor]) -> Heliostat:
    """The heliostat with the fit tensors as it takes them (`effective_tensors`: tracking (5,) mrad,
    canting (F, 2) mrad, surface (F, C, C) mm) in place of its own tracking, canting and heights."""
    fields: dict[str, Any] = {TENSOR_EFFECTS[k].field: v * 1e-3 for k, v in effective.items()}
    return replace(heliostat, **fields)


def effective_tensors(tensors: dict[str, Tensor]) -> dict[str, Tensor]:
    """Fit tensors as the heliostat takes them (each tensor effect's `effective`: canting without
    its mean, heights without planes)."""
    return {k: TENSOR_EFFECTS[k].effective(v) for k, v in tensors.items()}


def dataset_scene(heliostat: Heliostat, attrs: dict, image_shape: tuple[int, int], cells_per_side: int,
                  fit_rays: int, fitting: bool) -> Scene:
    """The scene of a dataset (its attributes: target_center_m, target_normal, target_size_m,
    dni_w_m2, trace, aim_point_m where the heliostat aims elsewhere than the target centre, and
    neighbours_enu_m where the neighbours' positions are known).

    Fitting a dataset traced with bilinear rays: `fit_rays` bilinear rays per image on
    `cells_per_side` cells (faster than kernels for many facets). Otherwise, and for predictions,
    kernel splatting (the noise-free expected image) on the dataset's own cells per side, at least
    `cells_per_side`: coarser cells than the measurements' leave a lattice ripple in the spot, and
    a fit then widens the slope error to cover it. A sharp model (point sun, no slope error: no
    kernel) is traced with bilinear rays instead (Scene.simulate): the dataset's own when predicting.
    The target averages over pixels as the dataset's images do (`images_pixel_variance`).
    """
    device = heliostat.facet_size.device
    aim = attrs.get("aim_point_m")
    trace_settings = attrs.get("trace") or {}
    target = Target(torch.tensor(attrs["target_center_m"], dtype=torch.float32, device=device),
                    torch.tensor(attrs["target_normal"], dtype=torch.float32, device=device),
                    float(attrs["target_size_m"][0]), float(attrs["target_size_m"][1]),
                    (int(image_shape[0]), int(image_shape[1])),
                    None if aim is None else torch.tensor(aim, dtype=torch.float32, device=device),
                    images_pixel_variance(trace_settings))
    dni = float(attrs["dni_w_m2"])
    known = attrs.get("neighbours_enu_m")
    neighbours = None if known is None else torch.tensor(known, dtype=torch.float32, device=device).reshape(-1, 3)
    if fitting and trace_settings.get("splat") == "bilinear":
        return Scene(heliostat, target, dni, splat="bilinear", rays=fit_rays, cells_per_side=cells_per_side,
                     neighbours=neighbours)
    cells = max(cells_per_side, int(trace_settings.get("cells_per_side") or cells_per_side))
    rays = fit_rays if fitting else int(trace_settings.get("rays") or fit_rays)
    return Scene(heliostat, target, dni, rays=rays, cells_per_side=cells, neighbours=neighbours)


def images_pixel_variance(trace_settings: dict) -> float | None:
    """The pixel filter (pixel^2 per axis, see Target.pixel_variance) of a dataset's images, from its
    trace settings: a camera's pixel average for images helioflow did not trace (imported: no
    settings), the tent of the bilinear Monte Carlo, None for the kernel splat's own images."""
    splat = trace_settings.get("splat")
    if splat is None:
        return CAMERA_PIXEL_VARIANCE
    return TENT_VARIANCE if splat == "bilinear" else None


def normalised(images: Tensor, loss: str, scale: float, lost: Tensor | None = None) -> Tensor:
    """Images as a loss compares them: divided by `scale` ("absolute") or by their own sum times
    the pixel count ("shape", mean value 1). `lost` (N,), for a prediction: flux that missed the
    image (Scene.simulate), added to the sum, so that a model cannot match a spot's shape by
    throwing the flux it cannot place off the image."""
    if loss == "absolute":
        return images / scale
    n = images.shape[-1] * images.shape[-2]
    total = images.sum((-2, -1), keepdim=True)
    if lost is not None:
        total = total + lost[:, None, None]
    return images / total.clamp_min(1e-30) * n


def misplaced_flux(pred: Tensor, meas: Tensor, lost: Tensor | None = None) -> Tensor:
    """(N, H, W) predicted and measured images -> (N,) misplaced flux fraction: half the L1
    distance between the two images each divided by its own sum, so 0 for the same shape at any
    scale and 1 for spots that do not overlap. `lost` (N,): predicted flux that missed the image
    (physics.scene.Scene.simulate), misplaced too. The diagnosis' error measure."""
    p = normalised(pred.double(), "shape", 1.0, None if lost is None else lost.double())
    m = normalised(meas.double(), "shape", 1.0)
    return 0.5 * (p - m).abs().mean((-2, -1))
