"""Heliostat geometry: facets, canting, B-spline surface deformation, two-axis kinematics.

Heliostat frame: (right, up, normal) of the mirror at rest, metres, origin at the concentrator
centre, which is also the pivot. At rest both mount types face south, so the heliostat frame maps
to ENU as right -> east, up -> up, normal -> south.

Kinematics: the controller computes ideal joint angles that aim the mirror normal at the bisector
of the sun and the aim point (the concentrator centre reflects the sun onto the aim point); the
real heliostat applies those angles through its error model — joint offsets, a tilted pedestal
and non-orthogonal axes — so an ideal heliostat (all errors zero) hits the aim point exactly.

Mount types (rotation applied to the rest frame, first joint outermost):
  az_el    first joint about the vertical (azimuth), second about the rotated east axis (elevation);
  juelich  first joint about the east axis, second about the mirror's rotated up axis (the
           Jülich heliostats of PAINT, as in ARTIST's rigid-body kinematics).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import torch
from torch import Tensor

from helioflow.physics.geometry import normalize, rotation_about_axis

MOUNTS = ("az_el", "juelich")
TRACKING_PARAMETERS = (
    "axis1_offset",  # offset of the first joint angle (rad)
    "axis2_offset",  # offset of the second joint angle (rad)
    "pedestal_tilt_east",  # tilt of the pedestal towards east: rotation about north (rad)
    "pedestal_tilt_north",  # tilt of the pedestal towards north: rotation about -east (rad)
    "non_orthogonality",  # tilt of the second axis about first x second (rad)
)
REST_FRAME = torch.tensor([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]], dtype=torch.float64)
"""(3, 3) columns = heliostat right, up, normal in ENU at rest: east, up, south."""
_E = torch.eye(3, dtype=torch.float64)
_JOINT_AXES = {"az_el": (_E[2], _E[0]), "juelich": (_E[0], _E[2])}


@dataclass
class Heliostat:
    """One heliostat's geometry; tensors may require grad for fitting.

    Attributes:
        position: (3,) ENU position of the concentrator centre / pivot (m).
        mount: one of MOUNTS.
        facet_translation: (F, 3) facet centres in the heliostat frame (m).
        facet_size: (F, 2) facet width and height (m).
        facet_normal: (F, 3) ideal (canted) unit facet normals in the heliostat frame.
        facet_focal_length: focal length of each facet's paraboloid (m); None = flat facets.
        control_heights: (F, C, C) B-spline control-point heights of the surface deformation (m).
        canting_error: (F, 2) facet tilt errors about the facet's right and up axes (rad).
        tracking_error: (5,) kinematic errors in the order of TRACKING_PARAMETERS (rad).
    """

    position: Tensor
    mount: str
    facet_translation: Tensor
    facet_size: Tensor
    facet_normal: Tensor
    facet_focal_length: float | None
    control_heights: Tensor
    canting_error: Tensor
    tracking_error: Tensor

    @property
    def n_facets(self) -> int:
        """The number of facets."""
        return self.facet_translation.shape[0]

    def ideal(self) -> Heliostat:
        """The same heliostat with no deformation, canting or tracking error."""
        return replace(
            self,
            control_heights=torch.zeros_like(self.control_heights),
            canting_error=torch.zeros_like(self.canting_error),
            tracking_error=torch.zeros_like(self.tracking_error),
        )

    def facets(self, index: Tensor) -> Heliostat:
        """The heliostat with only the facets in `index` ((K,) long), on the same mount: their
        flux alone (a heliostat's facets neither shade nor block each other in this model)."""
        per_facet = ("facet_translation", "facet_size", "facet_normal", "control_heights", "canting_error")
        return replace(self, **{k: getattr(self, k)[index] for k in per_facet})

    def to(self, device, dtype=torch.float32) -> Heliostat:
        """The same heliostat with its tensors on `device` in `dtype`."""
        fields: dict[str, Any] = {k: v.to(device=device, dtype=dtype) for k, v in vars(self).items()
                                  if isinstance(v, Tensor)}
        return replace(self, **fields)


def facet_layout(rows: int, cols: int, width: float, height: float, gap: float) -> tuple[np.ndarray, np.ndarray]:
    """Rectangular grid of equal facets, centred on the heliostat centre.

    Returns:
        translation (F, 3) facet centres (right, up, 0) in m, row-major from the top-left;
        size (F, 2) width, height in m.
    """
    xs = (np.arange(cols) - (cols - 1) / 2.0) * (width + gap)
    ys = ((rows - 1) / 2.0 - np.arange(rows)) * (height + gap)
    y, x = np.meshgrid(ys, xs, indexing="ij")
    translation = np.stack((x.ravel(), y.ravel(), np.zeros(x.size)), axis=-1)
    return translation, np.tile([width, height], (rows * cols, 1))


def on_axis_canting(translation: np.ndarray, focal_distance: float | None) -> np.ndarray:
    """(F, 3) unit facet normals canted on-axis: each facet's normal points at the point 2 f on
    the heliostat's optical axis, as the paraboloid of focal length f does at the facet centres
    (the centres stay in the plane z = 0; the paraboloid's sag, millimetres, is neglected).
    None gives parallel (flat) facets."""
    if focal_distance is None:
        return np.tile([0.0, 0.0, 1.0], (len(translation), 1))
    n = np.array([0.0, 0.0, 2.0 * focal_distance]) - translation * np.array([1.0, 1.0, 0.0])
    return n / np.linalg.norm(n, axis=-1, keepdims=True)


def canting_focal_distance(heliostat: Heliostat, tolerance_rad: float = 1e-6) -> float | None:
    """The on-axis canting distance f (m) that best explains the facet normals, or None for
    parallel facets: least squares over facets of tilt (n_x, n_y) / n_z = -r / (2 f) (see
    on_axis_canting), r the facet centre (m) in the heliostat frame."""
    r = heliostat.facet_translation[:, :2].double()
    n = heliostat.facet_normal.double()
    tilt = n[:, :2] / n[:, 2:3]
    if float(tilt.abs().max()) < tolerance_rad or float((r * r).sum()) == 0.0:
        return None
    inverse = -2.0 * float((tilt * r).sum()) / float((r * r).sum())  # 1 / f
    return None if abs(inverse) < tolerance_rad else 1.0 / inverse


def ideal_heliostat(
    rows: int = 1,
    cols: int = 1,
    width: float = 1.0,
    height: float = 1.0,
    gap: float = 0.0,
    position=(0.0, 0.0, 0.0),
    mount: str = "az_el",
    canting_focal_distance: float | None = None,
    facet_focal_length: float | None = None,
    control_points: int = 6,
    dtype=torch.float64,
) -> Heliostat:
    """A heliostat of rows x cols equal facets (m) at an ENU `position`, with no errors.

    canting_focal_distance: on-axis canting distance (m), None = parallel facets;
    facet_focal_length: paraboloid facets (m), None = flat; control_points: B-spline grid per side.
    """
    translation, size = facet_layout(rows, cols, width, height, gap)
    n = len(translation)
    def t(a) -> Tensor:
        return torch.as_tensor(a, dtype=dtype)

    return Heliostat(
        position=t(position),
        mount=mount,
        facet_translation=t(translation),
        facet_size=t(size),
        facet_normal=t(on_axis_canting(translation, canting_focal_distance)),
        facet_focal_length=facet_focal_length,
        control_heights=torch.zeros(n, control_points, control_points, dtype=dtype),
        canting_error=torch.zeros(n, 2, dtype=dtype),
        tracking_error=torch.zeros(len(TRACKING_PARAMETERS), dtype=dtype),
    )


def facet_frames(facet_normal: Tensor, canting_error: Tensor) -> Tensor:
    """(F, 3, 3) facet frames in the heliostat frame: columns = facet right, up, normal.

    The canted normal is tilted by the canting errors (rad) about the facet's right axis
    (canting_error[:, 0], moves the normal up) and up axis (canting_error[:, 1], moves it right).
    """
    up = torch.zeros_like(facet_normal)
    up[:, 1] = 1.0
    right = normalize(torch.cross(up, facet_normal, dim=-1))
    up = torch.cross(facet_normal, right, dim=-1)
    tilt_up, tilt_right = canting_error[:, 0:1], canting_error[:, 1:2]
    normal = normalize(facet_normal + tilt_up * up + tilt_right * right)
    right = normalize(right - (right * normal).sum(-1, keepdim=True) * normal)
    up = torch.cross(normal, right, dim=-1)
    return torch.stack((right, up, normal), dim=-1)


def bspline_basis(x: np.ndarray, n_control: int, degree: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """Clamped uniform B-spline basis on [0, 1] and its derivative (Cox-de Boor).

    Args:
        x: (G,) parameter values in [0, 1].
        n_control: number of control points C (> degree).

    Returns:
        basis (G, C) and d basis / dx (G, C).
    """
    inner = np.linspace(0.0, 1.0, n_control - degree + 1)
    knots = np.concatenate((np.zeros(degree), inner, np.ones(degree)))
    x = np.clip(x, 0.0, 1.0 - 1e-12)

    def basis(p: int) -> np.ndarray:
        b = ((knots[None, :-1] <= x[:, None]) & (x[:, None] < knots[None, 1:])).astype(float)
        for k in range(1, p + 1):
            left_den = knots[k:-1] - knots[: -k - 1]
            right_den = knots[k + 1 :] - knots[1:-k]
            left = np.divide(x[:, None] - knots[None, : -k - 1], left_den, out=np.zeros((len(x), len(left_den))),
                             where=left_den > 0)
            right = np.divide(knots[None, k + 1 :] - x[:, None], right_den, out=np.zeros((len(x), len(right_den))),
                              where=right_den > 0)
            b = left * b[:, :-1] + right * b[:, 1:]
        return b

    lower = basis(degree - 1)
    den1 = knots[degree : degree + n_control] - knots[:n_control]
    den2 = knots[degree + 1 : degree + 1 + n_control] - knots[1 : n_control + 1]
    t1 = np.divide(degree * lower[:, :n_control], den1, out=np.zeros_like(lower[:, :n_control]), where=den1 > 0)
    t2 = np.divide(degree * lower[:, 1 : n_control + 1], den2, out=np.zeros_like(lower[:, :n_control]),
                   where=den2 > 0)
    return basis(degree), t1 - t2


def without_planes(heights: Tensor) -> Tensor:
    """(F, C, C) control heights without the part that moves a facet as a whole: the orthogonal
    projection (in control-height space) onto heights whose surface has zero mean height and zero
    mean slope along both facet axes. What is left is shape: a facet's mean tilt is its canting
    error and its mean height moves nothing, so the surface effect is defined without them."""
    c = heights.shape[-1]
    b, db = (torch.as_tensor(a, dtype=heights.dtype, device=heights.device)
             for a in bspline_basis((np.arange(512) + 0.5) / 512, c))
    mean, slope = b.mean(0), db.mean(0)  # (C,) integrals over [0, 1] of the basis and its derivative
    functionals = torch.stack((torch.outer(mean, mean), torch.outer(mean, slope), torch.outer(slope, mean)))
    a = functionals.reshape(3, -1)  # (3, C*C): mean height, mean slope along each axis
    projector = torch.eye(c * c, dtype=heights.dtype, device=heights.device) - a.T @ torch.linalg.solve(a @ a.T, a)
    flat = heights.reshape(heights.shape[0], -1)
    return (flat @ projector.T).reshape(heights.shape)


@dataclass
class SurfaceSamples:
    """Equal-area samples of the mirror surface, in the heliostat frame.

    Attributes:
        points: (P, 3) cell centres on the (curved, deformed) facet surfaces (m).
        normals: (P, 3) unit surface normals at the points.
        half_extent: (P, 2, 3) half of the cell's edge vectors along facet right and up (m),
            for jittering ray origins uniformly over the cell.
        area: (P,) cell areas (m^2).
        owner: (P,) index of the heliostat each point belongs to (all 0 for one heliostat).
    """

    points: Tensor
    normals: Tensor
    half_extent: Tensor
    area: Tensor
    owner: Tensor


def sample_surface(heliostat: Heliostat, cells_per_side: int) -> SurfaceSamples:
    """Sample every facet on a cells_per_side x cells_per_side grid of equal cells.

    Heights are the facet paraboloid (if any) plus the B-spline deformation; normals come from
    their analytic slopes, so the samples are differentiable in control_heights, canting_error
    and the facet geometry. Cells are equal in the facet's parameter plane; the curvature of a
    heliostat facet (slopes of a few mrad) changes their areas by < 1e-5, which is neglected.
    """
    h = heliostat
    dtype, device = h.facet_size.dtype, h.facet_size.device
    g = cells_per_side
    s = (np.arange(g) + 0.5) / g  # cell centres in [0, 1]
    w, hgt = h.facet_size[:, 0], h.facet_size[:, 1]  # (F,)
    x = (torch.as_tensor(s, dtype=dtype, device=device) - 0.5)[None, :] * w[:, None]  # (F, G) right
    y = (0.5 - torch.as_tensor(s, dtype=dtype, device=device))[None, :] * hgt[:, None]  # (F, G) up (top row first)
    z, dz_dx, dz_dy = deformation(h.control_heights, h.facet_size, g)
    xx, yy = x[:, None, :].expand_as(z), y[:, :, None].expand_as(z)
    if h.facet_focal_length is not None:
        f = h.facet_focal_length
        z = z + (xx**2 + yy**2) / (4.0 * f)
        dz_dx = dz_dx + xx / (2.0 * f)
        dz_dy = dz_dy + yy / (2.0 * f)
    local = torch.stack((xx, yy, z), dim=-1).reshape(h.n_facets, -1, 3)  # (F, G*G, 3)
    local_normal = normalize(torch.stack((-dz_dx, -dz_dy, torch.ones_like(z)), dim=-1)).reshape(h.n_facets, -1, 3)
    frames = facet_frames(h.facet_normal, h.canting_error)  # (F, 3, 3)
    points = h.facet_translation[:, None, :] + torch.einsum("fij,fpj->fpi", frames, local)
    normals = torch.einsum("fij,fpj->fpi", frames, local_normal)
    half = torch.stack((frames[:, :, 0] * (w / (2 * g))[:, None], frames[:, :, 1] * (hgt / (2 * g))[:, None]), dim=1)
    n_points = h.n_facets * g * g
    return SurfaceSamples(
        points=points.reshape(-1, 3),
        normals=normals.reshape(-1, 3),
        half_extent=half[:, None].expand(-1, g * g, -1, -1).reshape(n_points, 2, 3),
        area=(w * hgt / g**2)[:, None].expand(-1, g * g).reshape(-1),
        owner=torch.zeros(n_points, dtype=torch.long, device=device),
    )


def deformation(control_heights: Tensor, facet_size: Tensor, cells_per_side: int) -> tuple[Tensor, Tensor, Tensor]:
    """The B-spline deformation at the cell centres of every facet (see `sample_surface`): its
    height (unit of the control heights), slope along the facet's right and up axes (that unit per
    metre), each (..., F, G, G) for (..., F, C, C) control heights and (F, 2) facet sizes (m), with
    rows along up (top first) and columns along right."""
    g, n_control = cells_per_side, control_heights.shape[-1]
    dtype, device = control_heights.dtype, control_heights.device
    b, db = (torch.as_tensor(a, dtype=dtype, device=device)
             for a in bspline_basis((np.arange(g) + 0.5) / g, n_control))
    w, hgt = facet_size[:, 0, None, None], facet_size[:, 1, None, None]
    c = control_heights  # (..., F, C, C) indexed [row along up (top first), column along right]
    z = torch.einsum("ui,...ij,vj->...uv", b, c, b)
    dz_dx = torch.einsum("ui,...ij,vj->...uv", b, c, db) / w
    dz_dy = -torch.einsum("ui,...ij,vj->...uv", db, c, b) / hgt
    return z, dz_dx, dz_dy


def ideal_joint_angles(mount: str, normal: Tensor) -> tuple[Tensor, Tensor]:
    """Joint angles (rad) that turn the rest normal (south) into the (..., 3) unit ENU `normal`."""
    nx, ny, nz = normal.unbind(-1)
    if mount == "az_el":
        return torch.atan2(nx, -ny), -torch.asin(nz.clamp(-1.0, 1.0))
    return torch.atan2(-nz, -ny), torch.asin(nx.clamp(-1.0, 1.0))


def joint_rotation(mount: str, angle1: Tensor, angle2: Tensor, tracking_error: Tensor) -> Tensor:
    """(..., 3, 3) rotation of the heliostat frame's rest pose, for joint commands (...) in rad,
    through the real kinematics with the (5,) tracking errors (TRACKING_PARAMETERS order)."""
    dtype, device = angle1.dtype, angle1.device
    a1, a2 = (a.to(dtype=dtype, device=device) for a in _JOINT_AXES[mount])
    e = tracking_error.to(dtype)
    ones = torch.ones_like(angle1)
    pedestal = rotation_about_axis(_E[1].to(dtype=dtype, device=device), e[2] * ones) @ rotation_about_axis(
        -_E[0].to(dtype=dtype, device=device), e[3] * ones
    )
    skew = rotation_about_axis(torch.cross(a1, a2, dim=0), e[4] * ones)
    return pedestal @ rotation_about_axis(a1, angle1 + e[0]) @ skew @ rotation_about_axis(a2, angle2 + e[1])


def orientation(heliostat: Heliostat, sun: Tensor, aim_point: Tensor) -> Tensor:
    """Heliostat frame -> ENU rotation for each sun direction.

    Args:
        sun: (S, 3) unit vectors towards the sun.
        aim_point: (3,) ENU aim point (m).

    Returns:
        (S, 3, 3) rotation matrices; columns = mirror right, up, normal in ENU.
    """
    to_aim = normalize(aim_point - heliostat.position)
    commanded = normalize(sun + to_aim)
    angle1, angle2 = ideal_joint_angles(heliostat.mount, commanded.detach())
    rest = REST_FRAME.to(dtype=sun.dtype, device=sun.device)
    return joint_rotation(heliostat.mount, angle1, angle2, heliostat.tracking_error) @ rest
