"""The tracer linearised in the heliostat's errors: a fast, noise-free stand-in for fitting them.

Where a surface cell's central ray meets the target is, to first order, linear in the heliostat's
error tensors: tracking errors (mrad) turn the whole mirror, a facet's canting tilts (mrad) turn its
cells, its control heights (mm) move each cell along its normal and tilt it through the B-spline's
height and slopes there. At the sizes calibration measures (mrad, tenths of a millimetre) the first
order is exact to well below a hundredth of a pixel for a hit displaced by pixels; what makes a
spot nonlinear in the errors is only how those hits pile up into pixels. So `linearise` traces the
hits and their derivatives once, for fixed sun positions, and `LinearisedTrace.images` rebuilds
the kernel trace's images from them: hits moved along the derivatives, deposited bilinearly and
convolved with the beam-spread footprint of each image's mean ray (one convolution per image;
the kernel trace adds the footprint's first-order change across the heliostat, three more
convolutions, which a fit's many descent steps would pay: the fit's polish, a Gauss-Newton search
on the exact trace, finds the optimum with it).

The derivatives are small: by the 5 tracking errors, by the facet's own 2 canting tilts, and by the
cell's own height and two slopes, which the control heights set through the B-spline basis
(heliostat.deformation). An image then costs a deposit and an FFT instead of a trace; the sun shape,
slope error, camera and scalar losses can change between calls (they act after the hits).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import torch
from torch import Tensor

from helioflow.physics.geometry import normalize, sun_vector
from helioflow.physics.heliostat import Heliostat, deformation, facet_frames, sample_surface
from helioflow.physics.raytrace import (
    MirrorPoints,
    Optics,
    _project,
    central_hits,
    mirror_points,
    padded_canvas,
    splat_footprints,
)
from helioflow.physics.sun import SunShape
from helioflow.physics.target import Target

FD_STEP = 0.05  # central-difference step of the derivatives (mrad, mrad, mm); the hits are linear


@dataclass(frozen=True)
class LinearisedTrace:
    """Hits of a heliostat's cells on a target for fixed sun positions, linear in its errors.

    Attributes:
        hits: (S, F, P, 2) column and row (padded pixel coordinates of the padded canvas, see
            raytrace.padded_canvas) of each facet's P cells' central rays at the linearisation
            point, S sun positions.
        derivatives: their derivatives by the error tensors that are fitted (the keys of `at`):
            "tracking" (S, F, P, 2, 5) by the tracking errors (pixels per mrad), "canting"
            (S, F, P, 2, 2) by the facet's own canting tilts (pixels per mrad), "surface"
            (S, F, P, 2, 3) by the cell's own height (pixels per mm) and slopes along the facet's
            right and up axes (pixels per mm/m).
        facet_size: (F, 2) facet width and height (m), for the B-spline slopes.
        cells_per_side: cells per facet side (P = cells_per_side^2).
        power: (S, F, P) power each cell reflects towards the target per unit DNI, reflectivity and
            transmittance (W per W/m^2), 0 for cells facing away.
        unit, path: (S, 3) the power-weighted mean ray on the target's (normal, right, up) and (S,)
            its length (m): where each image's footprint is evaluated.
        distance: the heliostat-target distance (m) a transmittance is evaluated at.
        points: the cells as a mirror mask sees them at the linearisation point (shapes (S, F * P, 3)).
        at: the effective error tensors ({"tracking": (5,), "canting": (F, 2), "surface":
            (F, C, C)}, mrad and mm) the hits were traced at.
        target: the target the images lie on.
    """

    hits: Tensor
    derivatives: dict[str, Tensor]
    facet_size: Tensor
    cells_per_side: int
    power: Tensor
    unit: Tensor
    path: Tensor
    distance: float
    at: dict
    target: Target
    points: MirrorPoints

    def images(self, tensors: dict[str, Tensor], optics: Optics, facets: Tensor | None = None,
               with_launched: bool = False) -> Tensor | tuple[Tensor, Tensor]:
        """(S, H, W) flux (W/m^2) with the heliostat's errors at `tensors` (the effective values:
        canting without its mean, heights without planes; a missing entry stays at the
        linearisation point), differentiable in them; with_launched, also the (S,) power (W)
        reflected towards the target plane. facets: (K,) long: only these facets' flux. A tensor may
        carry a leading sun-position axis, (S, ...): each image its own errors (what a per-image
        derivative by autograd needs, uncertainty.predicted_spread)."""
        index = slice(None) if facets is None else facets
        moved = self.hits[:, index]
        for key, derivative in self.derivatives.items():
            if key not in tensors:
                continue
            change = tensors[key] - self.at[key]
            each = "s" if change.dim() > self.at[key].dim() else ""  # one value per sun position
            if key == "tracking":
                moved = moved + torch.einsum(f"sfpdk,{each}k->sfpd", derivative[:, index], change)
            elif key == "canting":
                moved = moved + torch.einsum(f"sfpdk,{each}fk->sfpd", derivative[:, index], change[..., index, :])
            else:
                local = torch.stack(deformation(change[..., index, :, :], self.facet_size[index],
                                                self.cells_per_side), -1)
                moved = moved + torch.einsum(f"sfpdk,{each}fpk->sfpd", derivative[:, index], local.flatten(-3, -2))
        n_sun = moved.shape[0]
        factor: float | Tensor = optics.dni * optics.reflectivity
        if optics.transmittance is not None:
            factor = factor * optics.transmittance(torch.tensor(self.distance, dtype=moved.dtype, device=moved.device))
        power = self.power * factor
        if optics.mirror_mask is not None:
            weight = optics.mirror_mask(self.points).to(power)
            power = power * torch.broadcast_to(weight, (n_sun, weight.shape[-1])).reshape(power.shape)
        power = power[:, index].reshape(n_sun, -1)
        moved = moved.reshape(n_sun, -1, 2)
        flux = splat_footprints(moved[..., 0], moved[..., 1], power, self.target, optics, (self.unit, self.path)) \
            / self.target.pixel_area
        return (flux, power.sum(-1)) if with_launched else flux


def mean_ray(unit: Tensor, path: Tensor, power: Tensor) -> tuple[Tensor, Tensor]:
    """The power-weighted mean ray of each image: unit (S, P, 3) central-ray directions on the
    target's (normal, right, up), path (S, P) lengths (m) and power (S, P) (W) -> (S, 3) unit
    directions, (S,) paths. An image without power (all its points masked or facing away) gets its
    points' plain mean."""
    weight = torch.where(power.sum(-1, keepdim=True) > 0.0, power, torch.ones_like(power))
    weight = weight / weight.sum(-1, keepdim=True)
    return normalize((weight[..., None] * unit).sum(1)), (weight * path).sum(-1)


def linearise(heliostat: Heliostat, target: Target, azimuth: Tensor, elevation: Tensor, cells_per_side: int,
              at: dict[str, Tensor]) -> LinearisedTrace:
    """Trace the hits of `heliostat` at the (S,) sun positions (rad), its error fields replaced by
    the tensors in `at` (any of "tracking" (5,) mrad, "canting" (F, 2) mrad, "surface" (F, C, C)
    mm, effective values), and their derivatives by those tensors: central differences in float64
    on the CPU (returned in the heliostat's dtype and device), two traces per direction (every
    facet's entry, or every cell's height or slope, is stepped at once: a cell's hit moves only
    with its own facet's entries and its own surface)."""
    h = heliostat.to("cpu", torch.float64)
    at = {k: v.detach().to("cpu", torch.float64) for k, v in at.items()}
    base = {"tracking": h.tracking_error * 1e3, "canting": h.canting_error * 1e3, "surface": h.control_heights * 1e3}
    base.update(at)
    t64 = replace(target, center=target.center.to("cpu", torch.float64), normal=target.normal.to("cpu", torch.float64),
                  aim=target.aim_point.to("cpu", torch.float64))
    canvas = padded_canvas(t64)
    sun = sun_vector(azimuth.to("cpu", torch.float64), elevation.to("cpu", torch.float64))
    n_facets, g = h.n_facets, cells_per_side

    def traced(values: dict, local: int | None = None, step: float = 0.0) -> tuple[Tensor, ...]:
        """Hits (S, F, P, 2), power (S, F, P), central-ray directions (S, F * P, 3) and lengths
        (S, F * P) with the errors at `values`; `local` 0, 1, 2: every cell moved along its normal
        by `step` mm, or its slope along the facet's right or up axis raised by `step` mm/m."""
        moved = replace(h, tracking_error=values["tracking"] * 1e-3, canting_error=values["canting"] * 1e-3,
                        control_heights=values["surface"] * 1e-3)
        samples = sample_surface(moved, g)
        if local is not None:
            frames = facet_frames(moved.facet_normal, moved.canting_error)  # (F, 3, 3): right, up, normal
            axes = frames.repeat_interleave(g * g, dim=0)  # (F * P, 3, 3)
            if local == 0:
                samples = replace(samples, points=samples.points + step * 1e-3 * axes[:, :, 2])
            else:
                samples = replace(samples, normals=normalize(samples.normals - step * 1e-3 * axes[:, :, local - 1]))
        optics = Optics(sun=SunShape("point"), dni=1.0)  # _project reads no sun shape
        rays = _project(moved, samples, sun, t64, t64.aim_point, optics)
        col, row, power, unit, path = central_hits(rays, canvas)
        shape = (len(sun), n_facets, -1)
        return torch.stack((col, row), -1).reshape(*shape, 2), power.reshape(shape), unit, path

    hits, power, unit, path = traced(base)
    mean_unit, mean_path = mean_ray(unit, path, power.reshape(len(sun), -1))

    def derivative(key: str, entry: int) -> Tensor:
        moved = []
        for sign in (1.0, -1.0):
            values = {k: v.clone() for k, v in base.items()}
            if key == "tracking":
                values[key][entry] += sign * FD_STEP
            elif key == "canting":
                values[key][:, entry] += sign * FD_STEP
            moved.append(traced(values, entry if key == "surface" else None, sign * FD_STEP)[0])
        return (moved[0] - moved[1]) / (2 * FD_STEP)

    counts = {"tracking": 5, "canting": 2, "surface": 3}
    dtype, device = heliostat.facet_size.dtype, heliostat.facet_size.device

    def back(x: Tensor) -> Tensor:  # to the heliostat's dtype and device
        return x.to(device=device, dtype=dtype)

    derivatives = {k: back(torch.stack([derivative(k, i) for i in range(counts[k])], -1)) for k in at}
    moved = replace(h, tracking_error=base["tracking"] * 1e-3, canting_error=base["canting"] * 1e-3,
                    control_heights=base["surface"] * 1e-3)
    points = mirror_points(moved, sample_surface(moved, g), sun, t64.aim_point)[0]
    points = MirrorPoints(*(back(x) for x in (points.local, points.world, points.to_sun, points.reflected,
                                                points.aim, points.sun)))
    return LinearisedTrace(back(hits), derivatives, back(h.facet_size), g, back(power), back(mean_unit),
                           back(mean_path), float((target.center - heliostat.position).norm()),
                           {k: back(v) for k, v in at.items()}, target, points)
