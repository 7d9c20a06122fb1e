"""Sun shapes: the angular spread of sunlight around the sun's central direction.

A *deviation* is a 2-vector of small angles (rad) in the plane perpendicular to the sun's central direction
(small-angle approximation). A *radial density* f(theta) is per steradian of that plane, so that
integral f(theta) * 2*pi*theta dtheta = 1.

Buie sun (Buie, Monger & Dey 2003, Solar Energy 74:113), theta in mrad, chi = CSR:
    disc     theta <= 4.65:        phi = cos(0.326 theta) / cos(0.308 theta)
    aureole  4.65 < theta <= 43.6: phi = exp(kappa) * theta**gamma,
             kappa = 0.9 ln(13.5 chi) chi**-0.3,  gamma = 2.2 ln(0.52 chi) chi**0.43 - 0.1
The profile is used with the *nominal* chi (no chi-correction polynomial) and, as in Buie's paper, is
defined only up to 43.6 mrad and normalised there. Its effective CSR (aureole energy / total energy within
43.6 mrad) differs from the nominal chi: 0.005 -> 8e-6, 0.02 -> 0.006, 0.05 -> 0.043, 0.1 -> 0.100,
0.2 -> 0.187, 0.4 -> 0.373 (so a low nominal chi is practically a bare disc). The cut-off is part of the
model, not a numerical truncation: for chi below about 0.025 (gamma >= -2) the aureole's energy diverges
beyond 43.6 mrad, and where it converges extending it to infinity would add 4.6 % (chi=0.1) to 23 %
(chi=0.4) to the energy within 43.6 mrad.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from functools import lru_cache
from typing import NamedTuple

import torch
from torch import Tensor

from helioflow.errors import ConfigError

SUN_KINDS = ("point", "pillbox", "gaussian", "buie")
_KINDS_TEXT = ", ".join(SUN_KINDS)
KIND_KEYS = {"point": (), "pillbox": ("half_angle_mrad",), "gaussian": ("sigma_mrad",), "buie": ("csr",)}
_CSR_MIN, _CSR_MAX = 0.005, 0.4
BUIE_DISC_MRAD = 4.65
BUIE_MAX_MRAD = 43.6
_TABLE_STEPS = 20_000  # a tabulated profile's finest radial step is its extent / _TABLE_STEPS
_BLUR_REACH = 8.0  # the Gaussian blur is cut off beyond this many sigmas


def _check(key: str, value: object, ok: Callable[[float], bool], allowed: str) -> float:
    """Return value as a float if it is a finite real number satisfying ok, else raise ConfigError."""
    if not (isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value) and ok(value)):
        raise ConfigError(f"sun shape: {key}={value!r} is not allowed; expected {allowed}")
    return float(value)


@dataclass(frozen=True)
class SunShape:
    """Angular shape of the sun: `kind` is one of SUN_KINDS; only the parameter of that kind is used.

    half_angle_mrad: pillbox angular radius (mrad); sigma_mrad: gaussian per-axis std (mrad);
    csr: Buie circumsolar ratio (nominal chi, see the module docstring).
    """

    kind: str
    half_angle_mrad: float = 4.65
    sigma_mrad: float = 2.51
    csr: float = 0.1

    def __post_init__(self) -> None:
        if self.kind not in SUN_KINDS:
            raise ConfigError(f"sun shape: kind={self.kind!r} is unknown; expected one of {_KINDS_TEXT}")
        for key in KIND_KEYS[self.kind]:
            if key == "csr":
                in_range, allowed = (lambda v: _CSR_MIN <= v <= _CSR_MAX), f"{_CSR_MIN} <= csr <= {_CSR_MAX}"
            else:
                in_range, allowed = (lambda v: v > 0), f"a number > 0 ({key})"
            object.__setattr__(self, key, _check(key, getattr(self, key), in_range, allowed))

    @classmethod
    def from_config(cls, d: dict) -> SunShape:
        """Build from a config mapping such as {"kind": "buie", "csr": 0.1}; unknown kinds or keys raise."""
        if not isinstance(d, dict) or "kind" not in d:
            raise ConfigError(f"sun: expected a mapping with key 'kind' (one of {_KINDS_TEXT}); got {d!r}")
        kind = d["kind"]
        if kind not in SUN_KINDS:
            raise ConfigError(f"sun shape: kind={kind!r} is unknown; expected one of {_KINDS_TEXT}")
        allowed = ("kind", *KIND_KEYS[kind])
        for key in d:
            if key not in allowed:
                raise ConfigError(
                    f"sun shape: unknown key {key!r}={d[key]!r} for kind {kind!r}; "
                    f"allowed keys: {', '.join(allowed)}"
                )
        return cls(**d)


class _Profile(NamedTuple):
    """A tabulated radial sun profile (float64, all (N,), theta ascending; a node repeats at a jump).

    theta: rad; density: f per steradian; cdf: P(radius <= theta); moment1: E[radius; radius <= theta] (rad).
    Between nodes the radius is uniformly distributed (cdf linear), which sampling and moments share.
    """

    theta: Tensor
    density: Tensor
    cdf: Tensor
    moment1: Tensor
    second_moment: float  # E[radius^2], rad^2


@lru_cache(maxsize=16)
def _profile_table(shape: SunShape) -> _Profile:
    """Tabulate a pillbox or Buie sun on a radial grid of step <= extent / _TABLE_STEPS."""
    if shape.kind == "pillbox":
        theta = torch.linspace(0.0, shape.half_angle_mrad, _TABLE_STEPS + 1, dtype=torch.float64)
        phi = torch.ones_like(theta)
    else:
        step = BUIE_MAX_MRAD / _TABLE_STEPS
        n_disc = math.ceil(BUIE_DISC_MRAD / step)
        n_aureole = _TABLE_STEPS - n_disc
        disc = torch.linspace(0.0, BUIE_DISC_MRAD, n_disc + 1, dtype=torch.float64)
        aureole = torch.linspace(BUIE_DISC_MRAD, BUIE_MAX_MRAD, n_aureole + 1, dtype=torch.float64)
        chi = shape.csr
        kappa = 0.9 * math.log(13.5 * chi) * chi**-0.3
        gamma = 2.2 * math.log(0.52 * chi) * chi**0.43 - 0.1
        theta = torch.cat([disc, aureole])  # 4.65 appears twice: disc value, then aureole value
        phi = torch.cat([torch.cos(0.326 * disc) / torch.cos(0.308 * disc), math.exp(kappa) * aureole**gamma])
    theta = theta * 1e-3
    ring_weight = torch.cat([theta.new_zeros(1), torch.cumulative_trapezoid(phi * theta, theta)])
    cdf = ring_weight / ring_weight[-1]
    dp = cdf.diff()
    moment1 = torch.cat([theta.new_zeros(1), torch.cumsum(dp * (theta[1:] + theta[:-1]) / 2, 0)])
    second = (dp * (theta[1:] ** 2 + theta[1:] * theta[:-1] + theta[:-1] ** 2) / 3).sum().item()
    return _Profile(theta, phi / (2 * math.pi * ring_weight[-1]), cdf, moment1, second)


def _interp(x: Tensor, xp: Tensor, fp: Tensor) -> Tensor:
    """Piecewise-linear interpolation of the table (xp ascending, (N,)) at x (any shape); 0 outside it."""
    i = torch.searchsorted(xp, x.contiguous(), right=True).clamp(1, xp.numel() - 1)
    x0, x1 = xp[i - 1], xp[i]
    w = ((x - x0) / (x1 - x0)).clamp(0.0, 1.0)
    y = fp[i - 1] + w * (fp[i] - fp[i - 1])
    return torch.where((x >= xp[0]) & (x <= xp[-1]), y, torch.zeros_like(y))


def _moment1_at(x: Tensor, table: _Profile) -> Tensor:
    """E[radius; radius <= x] (rad) for x (rad, within the table), uniform radius between nodes."""
    theta, cdf = table.theta, table.cdf
    i = torch.searchsorted(theta, x, right=True).clamp(1, theta.numel() - 1)
    slope = (cdf[i] - cdf[i - 1]) / (theta[i] - theta[i - 1])
    return table.moment1[i - 1] + slope * (x**2 - theta[i - 1] ** 2) / 2


def _blurred(table: _Profile, sigma: float) -> tuple[Tensor, Tensor]:
    """The table's density convolved with an isotropic 2D Gaussian of per-axis std sigma (rad).

    The sun is cut into rings of width sigma / 16 (exact mass m, mass-weighted radius c); each ring is blurred
    exactly: f(theta) = m / (2 pi sigma^2) * exp(-(theta - c)^2 / (2 sigma^2)) * I0e(theta c / sigma^2),
    evaluated every sigma / 32 (both steps at least extent / _TABLE_STEPS).
    Returns theta (rad, (J,)) and f (per sr, (J,)), float64.
    """
    extent = table.theta[-1].item()
    ring_step = max(sigma / 16, extent / _TABLE_STEPS)
    n_rings = math.ceil(extent / ring_step)
    edges = (torch.arange(n_rings + 1, dtype=torch.float64) * ring_step).clamp(max=extent)
    mass = _interp(edges, table.theta, table.cdf).diff()
    radius = torch.where(
        mass > 0, _moment1_at(edges, table).diff() / mass.clamp(min=1e-300), (edges[1:] + edges[:-1]) / 2
    )
    reach = math.ceil(_BLUR_REACH * sigma / ring_step)  # rings either side of theta that contribute
    step = max(sigma / 32, extent / _TABLE_STEPS)
    n_steps = math.ceil((extent + _BLUR_REACH * sigma) / step)
    theta = torch.arange(n_steps + 1, dtype=torch.float64) * step
    f = torch.empty_like(theta)
    for rows in torch.arange(theta.numel()).split(4096):
        t = theta[rows, None]
        ring = (t / ring_step).long() + torch.arange(-reach - 1, reach + 1)  # (rows, band)
        inside = (ring >= 0) & (ring < n_rings)
        ring = ring.clamp(0, n_rings - 1)
        c = radius[ring]
        kernel = torch.exp(-((t - c) ** 2) / (2 * sigma**2)) * torch.special.i0e(t * c / sigma**2)
        f[rows] = (torch.where(inside, mass[ring], 0.0) * kernel).sum(1) / (2 * math.pi * sigma**2)
    return theta, f


def sample_deviations(
    shape: SunShape, n: int, generator: torch.Generator, dtype: torch.dtype = torch.float32
) -> Tensor:
    """Draw n sun-ray deviations exactly from the sun shape: (n, 2) tensor of small angles (rad)."""
    if isinstance(n, bool) or not isinstance(n, int) or n < 0:
        raise ConfigError(f"sample_deviations: n={n!r} is not allowed; expected an integer >= 0")
    if shape.kind == "point":
        return torch.zeros(n, 2, dtype=dtype)
    if shape.kind == "gaussian":
        d = torch.randn(n, 2, generator=generator, dtype=torch.float64) * shape.sigma_mrad * 1e-3
        return d.to(dtype)
    u = torch.rand(n, 2, generator=generator, dtype=torch.float64)
    if shape.kind == "pillbox":
        radius = shape.half_angle_mrad * 1e-3 * u[:, 0].sqrt()
    else:
        table = _profile_table(shape)
        radius = _interp(u[:, 0], table.cdf, table.theta)
    azimuth = 2 * math.pi * u[:, 1]
    return torch.stack([radius * azimuth.cos(), radius * azimuth.sin()], dim=1).to(dtype)


def effective_sigma(shape: SunShape) -> float:
    """Per-axis std (rad) of the sun shape alone: sqrt(E[radius^2] / 2)."""
    if shape.kind == "point":
        return 0.0
    if shape.kind == "gaussian":
        return shape.sigma_mrad * 1e-3
    return math.sqrt(_profile_table(shape).second_moment / 2)


def _blur_sigma(slope_sigma_rad: float) -> float:
    """Per-axis std (rad) of the reflected-beam blur: slope errors double on reflection."""
    return 2 * _check("slope_sigma_rad", slope_sigma_rad, lambda v: v >= 0, "a number >= 0 (rad)")


def rms_radius(shape: SunShape, slope_sigma_rad: float = 0.0) -> float:
    """sqrt(E[theta^2]) (rad) of the reflected-beam spread: the sun shape blurred by 2 * slope_sigma_rad."""
    return math.sqrt(2 * effective_sigma(shape) ** 2 + 2 * _blur_sigma(slope_sigma_rad) ** 2)


def support_radius(shape: SunShape, slope_sigma_rad: float = 0.0) -> float:
    """Angle (rad) beyond which radial_density is zero (or, for a Gaussian, below exp(-32) of its peak)."""
    blur = _BLUR_REACH * _blur_sigma(slope_sigma_rad)
    if shape.kind in ("point", "gaussian"):
        return _BLUR_REACH * math.sqrt(effective_sigma(shape) ** 2 + _blur_sigma(slope_sigma_rad) ** 2)
    if shape.kind == "pillbox":
        return shape.half_angle_mrad * 1e-3 + blur
    return BUIE_MAX_MRAD * 1e-3 + blur


def finest_scale(shape: SunShape, slope_sigma_rad: float = 0.0) -> float:
    """Angle (rad) below which radial_density has no structure: the Gaussian's sigma for point and
    gaussian suns, the blur's sigma for pillbox and Buie suns (whose edges the blur smooths; 0, a
    sharp edge, without slope error)."""
    if shape.kind in ("point", "gaussian"):
        return math.hypot(effective_sigma(shape), _blur_sigma(slope_sigma_rad))
    return _blur_sigma(slope_sigma_rad)


def radial_density(shape: SunShape, slope_sigma_rad: float = 0.0) -> Callable[[Tensor], Tensor]:
    """Normalised radial density f(theta) (per sr) of the reflected-beam spread.

    The spread is the sun shape convolved with an isotropic 2D Gaussian of per-axis std 2 * slope_sigma_rad.
    Point and gaussian suns give a Gaussian (sigma^2 = s_sun^2 + 4 s_slope^2); pillbox and Buie suns are
    tabulated (step <= max(blur sigma / 32, extent / 20000)) and interpolated linearly, 0 beyond the table. A
    blur finer than the table step is neglected. The returned function maps theta (rad, any shape, >= 0) to f
    (same shape and dtype as theta); it is not meant to be differentiated.
    """
    blur = _blur_sigma(slope_sigma_rad)
    if shape.kind in ("point", "gaussian"):
        sigma = math.hypot(effective_sigma(shape), blur)
        if sigma == 0:
            raise ConfigError(
                "radial_density: a point sun with slope_sigma_rad=0 is a delta; kernel splatting needs a sun "
                "of finite size or a slope error > 0; use bilinear splatting instead"
            )
        return lambda theta: torch.exp(-(theta**2) / (2 * sigma**2)) / (2 * math.pi * sigma**2)
    table = _profile_table(shape)
    if blur < table.theta[-1].item() / _TABLE_STEPS:
        grid, f = table.theta, table.density
    else:
        grid, f = _blurred(table, blur)
    return lambda theta: _interp(theta.double(), grid.to(theta.device), f.to(theta.device)).to(theta.dtype)
