"""Physics models scored like networks: `raytrace` (the configured model physics, its "fit"
parameters fitted on the train split) and `drt` (differentiable raytracing: the heliostat's
surface, facet canting, tracking errors and slope error fitted too - the paper's outlook).

Both trace the design heliostat (ideal geometry from the heliostat file) onto the dataset's
target; training is the fit of `physics_fit.fit_effects` on the train split (absolute loss:
images divided by the dataset's maximum, as the metrics compare them), run once in `prepare`
(the shared loop then runs no steps). The fit's loss per trace is the training curve.

Real images normalised each to its own peak (PAINT, dataset attribute ``per_image_normalised``)
carry no comparable intensity between images: every image has its own unknown camera gain. Such a
dataset is fitted scale-free (loss "shape": each image divided by its own sum) and the model
predicts each image divided by its own peak, as the measured ones were.

drt fits slope error as well as the surface control points: control points describe the
large-scale shape, slope error the small-scale roughness below their resolution; both are
properties of the mirror that the calibration images measure.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field

import torch
from torch import Tensor

from helioflow.checks import check_ranges, check_types
from helioflow.data.surfaces import read_heliostat
from helioflow.errors import ConfigError
from helioflow.models.base import SpotModel, TrainingData
from helioflow.models.freedom import CHOICES, FREEDOMS, SELECT_MAX_IMAGES, FreedomChoice, choose_freedom
from helioflow.models.physics_fit import FitResult, FitSettings, Measurements, fit_effects, with_uncertainty
from helioflow.models.uncertainty import FitUncertainty, widened_by_refits
from helioflow.physics.effects import FIT, REGISTRY, check_effects
from helioflow.physics.heliostat import Heliostat
from helioflow.physics.scene import Scene, dataset_scene


@dataclass(frozen=True)
class PhysicsConfig:
    """Settings of a physics model.

    Attributes:
        effects: the model's effect list ({effect: {parameter: value or "fit"}}), from config
            `model.effects` (with the dataset's `model_effects` overrides).
        heliostat_path: the heliostat file whose design (ideal) geometry is traced.
        aim_point_m, target_normal, target_size_m: the target (m), from the dataset's attributes
            (aim_point_m: the target's centre, target_center_m).
        target_aim_m: the point the heliostat aims at when it is not the target's centre (PAINT:
            the tower file's `center` entry), from the dataset's attribute aim_point_m; None = the centre.
        dni_w_m2: direct normal irradiance (W/m^2), from the dataset's attributes.
        fit_steps: traces with gradient (L-BFGS evaluations) per fitting round for heliostat tensors.
        rounds: alternations of spread-scalar search and tensor descent.
        fit_images: train images the fit uses (evenly spread over the train split; all if fewer).
        cells_per_side: surface cells per facet side of the trace (fit and prediction).
        dataset_trace: the dataset's own trace settings ({"splat", "rays", ...}), from its
            attributes; the model predicts with kernels on at least the dataset's cells per side,
            and heliostat tensors are fitted on that trace, linearised (physics_fit module
            docstring); a model without tensors fits a dataset traced with bilinear rays with
            `fit_rays` rays per image.
        fit_rays: rays per image of a bilinear fit without heliostat tensors.
        coarse_blur_px: the first descents compare images blurred by a Gaussian of this std
            (pixels), then half of it, ..., then the sharp ones (physics_fit.blur_levels);
            0 = sharp only.
        per_image_normalised: the dataset's images are each divided by their own peak (from its
            attributes): fit by shape, predict peak-normalised images (module docstring).
        facet_hops: basin hops after the rounds of a surface fit on several facets
            (physics_fit module docstring); 0 = none.
        pinned_hops: pinned hops after the facet hops (physics_fit module docstring); 0 = none.
        seed: seeds the facet hops' random blocks.
        gauss_newton_steps: Gauss-Newton steps that end a fit with at most 64 free tensor
            entries (physics_fit module docstring); 0 = none.
    """

    effects: dict = field(default_factory=dict)
    heliostat_path: str = ""
    aim_point_m: tuple[float, float, float] = (0.0, 0.0, 20.0)
    target_normal: tuple[float, float, float] = (0.0, 1.0, 0.0)
    target_size_m: tuple[float, float] = (2.0, 2.0)
    target_aim_m: tuple[float, float, float] | None = None
    dni_w_m2: float = 1000.0
    fit_steps: int = 150
    rounds: int = 2
    fit_images: int = 32
    cells_per_side: int = 16
    dataset_trace: dict | None = None
    fit_rays: int = 100_000
    coarse_blur_px: float = 0.0
    per_image_normalised: bool = False
    facet_hops: int = 0
    pinned_hops: int = 0
    seed: int = 0
    gauss_newton_steps: int = 4

    def __post_init__(self):
        check_effects(self.effects, "model.effects", allow_fit=True)
        check_types(self)
        check_ranges(self, at_least_one=("fit_steps", "fit_images", "cells_per_side", "rounds", "fit_rays"),
                     counts=("facet_hops", "pinned_hops", "gauss_newton_steps", "seed"),
                     non_negative=("coarse_blur_px",),
                     at_most={"fit_steps": (100_000, "traces with gradient per round"),
                              "rounds": (100, "every round repeats the fit's stages"),
                              "fit_images": (10_000, "images per dataset"),
                              "cells_per_side": (512, "surface points per facet: cells_per_side squared"),
                              "fit_rays": (100_000_000, "rays per image in every step"),
                              "facet_hops": (1000, "every hop is a fit of its own"),
                              "pinned_hops": (1000, "every hop is a fit of its own"),
                              "gauss_newton_steps": (1000, "each step builds a Jacobian by finite differences")})


@dataclass(frozen=True)
class DrtConfig(PhysicsConfig):
    """Settings of drt: those of a physics model, and

    Attributes:
        freedom: what drt frees of the heliostat (models/freedom.py): auto (chosen by
            leave-one-out over at most freedom.SELECT_MAX_IMAGES training images, else full),
            design, tracking, canting or full.
    """

    freedom: str = "auto"

    def __post_init__(self):
        super().__post_init__()
        if self.freedom not in CHOICES:
            raise ConfigError(f"freedom = {self.freedom!r}: expected one of {', '.join(CHOICES)}")


def drt_effects(effects: dict, n_facets: int, freedom: str = "full") -> dict:
    """The drt effect list: the model's effects plus tracking (all parameters), surface, slope
    error and (for more than one facet) canting marked "fit" where the model does not set them;
    `freedom` (models/freedom.py FREEDOMS) frees less: design (the effects as they are), tracking
    (what the plant fit frees per heliostat, diagnosis/shared.py) or canting (tracking and canting)."""
    out = {e: dict(p or {}) for e, p in effects.items()}
    if freedom == "design":
        return out
    tracking = out.setdefault("tracking", {})
    for p in REGISTRY["tracking"].parameters:
        tracking.setdefault(p.name, FIT)
    if freedom == "full":
        out.setdefault("surface", {}).setdefault("control_heights_mm", FIT)
        out.setdefault("slope_error", {}).setdefault("sigma_mrad", FIT)
    if n_facets > 1 and freedom in ("canting", "full"):
        out.setdefault("canting", {}).setdefault("facet_tilts_mrad", FIT)
    return out


class RaytraceModel(SpotModel):
    """The configured physics model; its "fit" parameters fitted on the train split."""

    name = "raytrace"
    controllable = True
    uses_loop = False

    def __init__(self, config: PhysicsConfig, image_shape: tuple[int, int]):
        super().__init__()
        self.config = config
        self.image_shape = image_shape
        self.heliostat: Heliostat | None = None
        self.fitted = FitResult(config.effects, {})
        self.scale = 1.0
        self.curve: list[dict[str, float]] = []

    def effects_to_fit(self, heliostat: Heliostat, measured: Measurements) -> dict:
        """The effect list the fit frees (`measured`: the training images it is fitted to)."""
        return self.config.effects

    def scene(self, fitting: bool = False) -> Scene:
        """What the model traces (see physics.scene.dataset_scene)."""
        c = self.config
        attrs = {"target_center_m": c.aim_point_m, "target_normal": c.target_normal, "target_size_m": c.target_size_m,
                 "dni_w_m2": c.dni_w_m2, "trace": c.dataset_trace,
                 **({} if c.target_aim_m is None else {"aim_point_m": c.target_aim_m})}
        assert self.heliostat is not None, "a physics model's scene needs its heliostat (`prepare`)"
        return dataset_scene(self.heliostat, attrs, self.image_shape, c.cells_per_side, c.fit_rays, fitting)

    def prepare(self, data: TrainingData, checkpoint_path: str | os.PathLike | None = None) -> None:
        """Fit the model's parameters to (a spread subset of) the training images; a fit stopped
        midway resumes from `checkpoint_path` (physics_fit.FitCheckpoint)."""
        self.heliostat = read_heliostat(self.config.heliostat_path).ideal().to(self.device)
        self.scale = data.scale
        n = len(data)
        index = torch.linspace(0, n - 1, min(n, self.config.fit_images)).round().long()
        measured = Measurements(data.images[index], data.azimuth_deg[index], data.elevation_deg[index], data.scale)
        fitted = self.fit(self.effects_to_fit(self.heliostat, measured), measured, progress=True,
                          checkpoint=checkpoint_path)
        self.fitted = with_uncertainty(self.scene(), fitted, measured, self.fit_settings().loss)
        self.curve = [{"step": i, "loss": v} for i, v in enumerate(self.fitted.history)]

    def fit_settings(self) -> FitSettings:
        """The fit's settings (physics_fit.FitSettings) from the model's config."""
        c = self.config
        return FitSettings(steps=c.fit_steps, rounds=c.rounds, coarse_blur_px=c.coarse_blur_px,
                           loss="shape" if c.per_image_normalised else "absolute",
                           facet_hops=c.facet_hops, pinned_hops=c.pinned_hops, seed=c.seed,
                           gauss_newton_steps=c.gauss_newton_steps)

    def fit(self, effects: dict, measured: Measurements, start: FitResult | None = None, progress: bool = False,
            checkpoint: str | os.PathLike | None = None) -> FitResult:
        """`effects`' "fit" parameters fitted to `measured` (physics_fit.fit_effects; `start`: a
        nested start), without the covariance."""
        return fit_effects(self.scene(fitting=True), effects, measured, self.fit_settings(), progress=progress,
                           label=f"fit {self.name}", finish=self.scene(), checkpoint=checkpoint, start=start)

    def simulate(self, fitted: FitResult, azimuth_deg: Tensor, elevation_deg: Tensor) -> Tensor:
        """(N,) sun positions (deg) -> (N, H, W) images of a fit, in the fit's units."""
        return self.scene().simulate(fitted.effects, fitted.tensors, azimuth_deg.float().to(self.device),
                                     elevation_deg.float().to(self.device), seed=1)

    def to_device(self, device: torch.device) -> RaytraceModel:
        """Also moves the design heliostat and the fitted tensors (plain attributes, not buffers)."""
        super().to_device(device)
        if self.heliostat is not None:
            self.heliostat = self.heliostat.to(self.device, self.heliostat.facet_size.dtype)
        self.fitted.tensors = {k: v.to(self.device) for k, v in self.fitted.tensors.items()}
        return self

    def get_extra_state(self) -> dict:
        """The fit travels in the state dict: the heliostat, the effects, their tensors and uncertainty."""
        h = self.heliostat
        return {"heliostat": None if h is None else {k: v for k, v in vars(h).items()},
                "effects": self.fitted.effects, "tensors": self.fitted.tensors, "fitted": self.fitted.fitted,
                "scale": self.scale,
                "uncertainty": None if self.fitted.uncertainty is None else self.fitted.uncertainty.state()}

    def set_extra_state(self, state: dict) -> None:
        """Take back the fit `get_extra_state` wrote."""
        self.heliostat = None if state["heliostat"] is None else Heliostat(**state["heliostat"])
        uncertainty = state.get("uncertainty")  # None in a model written before uncertainties
        self.fitted = FitResult(state["effects"], state["tensors"], fitted=state["fitted"],
                                uncertainty=None if uncertainty is None else FitUncertainty.from_state(uncertainty))
        self.scale = state["scale"]
        self.to_device(self.device)

    def configure_optimizers(self) -> dict:
        """No optimizers: the fit happens in `prepare`."""
        return {}

    def training_step(self, batch, optimizers, generator) -> dict[str, float]:
        """Nothing to train (the fit happens in `prepare`): no losses."""
        return {}

    def predict(self, azimuth_deg: Tensor, elevation_deg: Tensor, generator: torch.Generator) -> Tensor:
        """(N,) sun positions (deg) -> (N, H, W) images divided by the training scale (each by its
        own peak first for a per-image normalised dataset)."""
        images = self.simulate(self.fitted, azimuth_deg, elevation_deg)
        if self.config.per_image_normalised:
            images = images / images.amax((-2, -1), keepdim=True).clamp_min(1e-30)
        return images / self.scale


class DrtModel(RaytraceModel):
    """Differentiable raytracing: the heliostat's surface, canting, tracking and slope error
    fitted with the model's effects (see `drt_effects`), as far as the images determine them
    (config `freedom`, models/freedom.py)."""

    name = "drt"
    config: DrtConfig

    def __init__(self, config: DrtConfig, image_shape: tuple[int, int]):
        super().__init__(config, image_shape)
        self.freedom: FreedomChoice | None = None

    def prepare(self, data: TrainingData, checkpoint_path: str | os.PathLike | None = None) -> None:
        """The fit of RaytraceModel.prepare at the freedom `effects_to_fit` takes; where that was chosen
        by leave-one-out, every sigma at least the jackknife's over the chosen level's refits
        (uncertainty.widened_by_refits)."""
        super().prepare(data, checkpoint_path)
        refits = [] if self.freedom is None else self.freedom.refits.get(self.freedom.chosen, [])
        if self.fitted.uncertainty is not None:
            self.fitted.uncertainty = widened_by_refits(self.fitted.uncertainty, refits)

    def effects_to_fit(self, heliostat: Heliostat, measured: Measurements) -> dict:
        """The drt effect list at the configured freedom, or at the one `choose_freedom` picks."""
        facets = heliostat.n_facets
        levels = {k: drt_effects(self.config.effects, facets, freedom=k) for k in FREEDOMS
                  if k != "canting" or facets > 1}  # one facet: its tilt is tracking
        n = len(measured.images)
        if self.config.freedom != "auto":
            self.freedom = FreedomChoice(self.config.freedom, "set in the config (freedom)")
        elif n > SELECT_MAX_IMAGES:
            self.freedom = FreedomChoice("full", f"{n} training images, more than the {SELECT_MAX_IMAGES} up to which "
                                                 "the freedom is chosen by leave-one-out: everything fitted")
        else:
            self.freedom = choose_freedom(levels, measured, lambda e, m, start: self.fit(e, m, start), self.simulate)
        return levels[self.freedom.chosen]

    def get_extra_state(self) -> dict:
        """The fit and the freedom chosen."""
        return {**super().get_extra_state(), "freedom": None if self.freedom is None else self.freedom.as_json()}

    def set_extra_state(self, state: dict) -> None:
        """Take back the fit and the freedom `get_extra_state` wrote."""
        super().set_extra_state(state)
        freedom = state.get("freedom")  # None in a model written before the freedom was chosen
        self.freedom = None if freedom is None else FreedomChoice.from_json(freedom)
