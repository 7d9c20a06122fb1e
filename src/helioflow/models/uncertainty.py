"""How sure each fitted number is: the covariance of a physics fit at its end point, and the spread
it implies for predicted spots.

The fit (models/physics_fit.py) minimises the unweighted mean squared difference between predicted
and measured images. Near its end point the residual images are linear in the P fitted parameters,
r(theta + d) = r + J d with J (pixels x P) the Jacobian. Pixel noise e of variance s_k^2 moves the
least-squares optimum by d = -H+ J^T e, H = J^T J, so the fitted parameters scatter with the
sandwich covariance

    C = H+ (J^T S J) H+,  S = diag(s) R diag(s)

(Gauss-Newton / Laplace for an unweighted fit of pixels whose noise grows with their signal; R the
noise's correlation between pixels, the identity for white noise: below). H+ is
the pseudo-inverse: a direction that changes no image (a facet's plane, the facets' mean tilt: both
removed from the model by `effective_tensors`) carries no variance, and none of its value is
reported. A direction the images barely see gets a large variance: the images do not determine it.

**The noise** s_k is white pixel noise read in the fit's residual (data/noise.py's operator on
measured - predicted, per level of the prediction): the spot is gone from the residual, so the
operator no longer sees its curvature (on the sharp ray-traced spots of semi_sphere, reading the
images themselves put the noise variance 2.4 times above the true heliostat's whole residual). It
is taken to be at least NOISE_FLOOR of the peak: noise-free synthetic images (helioflow's own
default datasets) would otherwise make any numerical residual look like a structured misfit.

**A fit that stopped short or a model that lacks an effect** is confidently wrong: its covariance
describes the neighbourhood of its end point and says nothing about how far the truth is. What
tells it is the residual's **structure**: noise is white at the pixel scale, while a wrong facet or
a missing effect leaves a residual that is smooth over several pixels. Smoothed over SMOOTH_PX x
SMOOTH_PX pixels, white noise keeps 1 / SMOOTH_PX^2 of its power and a smooth residual all of it;
`structure`, the smoothed residual's power over what the noise alone keeps, is ~1 for noise (0.9-1.0
for a 2 x 2-facet fit that reached its optimum; noise then read in the images) and large for a fit
in a local minimum (semi_sphere's drt: 4.3 overall, 1.4-9.3 per facet, against 1.2-2.6 per facet
for the true heliostat, whose kernel trace differs from the dataset's ray trace). Then:

- the covariance is multiplied by max(1, misfit), the residual's mean square over the noise's (the
  residual scatters the parameters as noise of its size would: Birge's ratio, what SciPy's
  `curve_fit` does without `absolute_sigma`), and R is the whitened residual's own correlation
  over pixels (models/correlated.py): a residual smooth over n pixels (a camera's optics, a
  rectified image, the model's mismatch) moves the spot's smooth parameters up to n times more
  than white noise of its size;
- the Gauss-Newton step from the end point, d = -H+ J^T r, is how far the fit stopped short of
  the optimum of its own images (0 at an optimum, local or not): d d^T is added to the covariance
  (on sanity_check's noise-free images the fit stops 0.0065 mrad short in slope error, 40 times
  the sigma the noise floor alone gives);
- the canting and surface of each facet whose own structure (pixels weighted by its share of the
  flux) exceeds STRUCTURED are reported "not determined", and every spread scalar when the whole
  fit's exceeds SPREADS_STRUCTURED (a width covers for a wrong shape or for what the model leaves
  out: on the independent Monte Carlo's 8-bit images, structure 1.5-2.2, the sun width and the slope
  error come out 2-5 % low, many sigma from the truth); the facets' entries may be off by as much as a typical
  entry of their tensor (its RMS), and what that does to every other parameter (the least-squares
  optimum moves with them, by -H_dd^+ H_du) is added to the covariance (`_systematic`): the
  semi_sphere tracking's sigma becomes 0.03-0.14 mrad (its error: at most 0.014 mrad) instead of a
  confident 0.003-0.007 mrad.

The Jacobian is a central difference of every fitted parameter on the exact trace: a heliostat
tensor's entries as the heliostat takes them (effective: canting without its mean, heights without
each facet's plane), each with only its own facet traced (1/F of the cells), then mapped to the
fit's free entries through the projection `effective_tensors` applies; a spread scalar (sun width,
slope error, camera blur) with a relative step on the whole trace; the linear scalars (camera gain,
background) analytically, as the closed form of the fit moves them.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass, field, replace

import numpy as np
import torch
from torch import Tensor

from helioflow.data.noise import NoiseModel, measure_noise
from helioflow.models.correlated import correlated_gram, ring_spectrum
from helioflow.physics.effects import REGISTRY, TENSOR_EFFECTS, with_role
from helioflow.physics.scene import LinearisedScene, Scene, effective_tensors, normalised

NOISE_FLOOR = 1e-3  # pixel noise below this fraction of the peak is not resolved: the images of helioflow's own
#                    synthetic datasets hold none (kernel traces), and a 10-bit camera's quantisation is about this
SMOOTH_PX = 5  # box side (pixels) over which `structure` smooths the residual
STRUCTURED = 2.0  # a facet's structure beyond this: the fit has not found that facet (module docstring)
SPREADS_STRUCTURED = 1.15  # the whole fit's structure beyond this: its spread scalars are not determined
RELATIVE_STEP = 0.01  # central-difference step of a spread scalar, relative to its value ...
SPREAD_SCALE = 0.1  # ... or to this (its unit: mrad, px) when it is smaller (a spread fitted at 0)
EIGEN_CUT = 1e-9  # directions of H below this fraction of its largest eigenvalue change no image
CORRELATED = 0.9  # correlations reported beyond this |r| (the strongest few)
Z95 = 1.959964  # half-width of a normal 95 % interval in sigmas


@dataclass
class FitUncertainty:
    """The covariance of a fit's parameters and what it rests on.

    Attributes:
        names: (P,) "effect.parameter" for scalars, "effect.parameter[i, j]" for tensor entries
            (tensor entries as the heliostat takes them: `effective_tensors`).
        units: (P,) each one's unit ("mrad", "mm", "" for a factor, "W/m^2" ...).
        values: (P,) the fitted values.
        covariance: (P, P) in those units, scaled by max(1, misfit).
        misfit: residual mean square over the noise's (~1 for a residual that is noise).
        structure: smoothed residual power over the smoothed noise's (`structure`; ~1 for noise).
        noise_rms: RMS noise of the compared pixels (in the loss' units).
        facet_structure: (F,) `structure` where each facet's flux lands (None for a fit without
            per-facet parameters).
        undetermined: names reported "not determined" (module docstring).
        noise: the white pixel noise read in the fit's residual (the loss' units), per level of
            the compared prediction (what `planning` weighs new images with).
        statistical: (P, P) the covariance without what facets the fit has not found do
            (`_systematic`): the noise's, misfit-inflated, and the step the fit stopped short. What a
            test of whether an effect is there at all takes (diagnosis: the Wald test): `_systematic`
            gives a not-found facet's entries the variance of the tensor's own typical entry, so that
            its departure from zero is about its own size by construction, whatever the images say.
            With the noise taken white, not with the residual's correlation: with it, a 0.7 mrad
            canting beside a tracking error on the independent Monte Carlo's images went unnamed
            (test_a_canting_too_small_to_cut_a_quarter_is_named_by_its_fitted_tilts), and what it does
            to the plant's named-right share is not measured yet. Not kept in model files (None when
            loaded).
        correlation_gain: the median over the parameters of the noise's variance in them with the
            residual's correlation over pixels (models/correlated.py) over that of white noise of
            the same size (1 for a white residual; ~ the pixels per independent one for a smooth one).
        refits: the fits of the same model with one image left out each whose jackknife spread bounds
            every sigma from below (`widened_by_refits`; 0: none, the covariance as the fit's end point gives it).
    """

    names: list[str]
    units: list[str]
    values: np.ndarray
    covariance: np.ndarray
    misfit: float
    structure: float
    noise_rms: float
    facet_structure: np.ndarray | None = None
    undetermined: list[str] = field(default_factory=list)
    noise: NoiseModel | None = None
    statistical: np.ndarray | None = None
    correlation_gain: float = 1.0
    refits: int = 0

    @property
    def sigma(self) -> np.ndarray:
        """(P,) standard deviation of each parameter (its unit)."""
        return np.sqrt(np.clip(np.diag(self.covariance), 0.0, None))

    def index(self, name: str) -> int:
        """The position of the parameter `name` in `names`."""
        return self.names.index(name)

    def correlation(self) -> np.ndarray:
        """(P, P) correlation matrix (0 where a parameter has no variance)."""
        s = self.sigma
        outer = np.outer(s, s)
        return np.divide(self.covariance, outer, out=np.zeros_like(self.covariance), where=outer > 0)

    def strongest_correlations(self, count: int = 8, beyond: float = CORRELATED) -> list[dict]:
        """The `count` strongest correlations with |r| > `beyond`, strongest first."""
        r = self.correlation()
        i, j = np.triu_indices(len(self.names), 1)
        keep = np.abs(r[i, j]) > beyond
        order = np.argsort(-np.abs(r[i, j][keep]))[:count]
        return [{"a": self.names[a], "b": self.names[b], "r": round(float(r[a, b]), 4)}
                for a, b in zip(i[keep][order], j[keep][order])]

    def as_json(self) -> dict:
        """Every scalar with its sigma and unit; per tensor the sigma in its shape; the misfit, the
        flags and the strongest correlations."""
        scalars, tensors = {}, {}
        sigma = self.sigma
        for name, unit, value, s in zip(self.names, self.units, self.values, sigma):
            if "[" in name:
                continue
            scalars[name] = {"value": _num(value), "sigma": _num(s), "unit": unit,
                             "determined": name not in self.undetermined}
        for key, role in TENSOR_EFFECTS.items():
            prefix = f"{key}.{role.key}["
            at = [k for k, n in enumerate(self.names) if n.startswith(prefix)]
            if not at:
                continue
            shape = _shape([self.names[k] for k in at])
            tensors[prefix[:-1]] = {"sigma": np.round(sigma[at].reshape(shape), 5).tolist(),
                                    "unit": self.units[at[0]],
                                    "undetermined": sum(self.names[k] in self.undetermined for k in at)}
        return {"method": "sandwich covariance at the fit's end point (models/uncertainty.py)",
                "scalars": scalars, "tensors": tensors, "misfit": _num(self.misfit),
                "structure": _num(self.structure),
                "structured_beyond": {"facet": STRUCTURED, "spreads": SPREADS_STRUCTURED},
                "noise_rms": _num(self.noise_rms), "correlation_gain": _num(self.correlation_gain),
                "refits": self.refits,
                "facet_structure": None if self.facet_structure is None else np.round(self.facet_structure, 3).tolist(),
                "correlations": self.strongest_correlations()}

    def state(self) -> dict:
        """What a model file keeps (arrays as tensors)."""
        return {"names": self.names, "units": self.units, "values": torch.as_tensor(self.values),
                "covariance": torch.as_tensor(self.covariance), "misfit": self.misfit, "structure": self.structure,
                "noise_rms": self.noise_rms, "correlation_gain": self.correlation_gain, "refits": self.refits,
                "facet_structure": None if self.facet_structure is None else torch.as_tensor(self.facet_structure),
                "undetermined": self.undetermined,
                "noise": None if self.noise is None else {"levels": torch.as_tensor(self.noise.levels),
                                                          "variance": torch.as_tensor(self.noise.variance),
                                                          "slope": self.noise.slope}}

    @classmethod
    def from_state(cls, state: dict) -> FitUncertainty:
        """The uncertainty `state` wrote."""
        facet, noise = state["facet_structure"], state.get("noise")
        return cls(list(state["names"]), list(state["units"]), np.asarray(state["values"]),
                   np.asarray(state["covariance"]), float(state["misfit"]), float(state["structure"]),
                   float(state["noise_rms"]),
                   None if facet is None else np.asarray(facet), list(state["undetermined"]),
                   None if noise is None else NoiseModel(np.asarray(noise["levels"]), np.asarray(noise["variance"]),
                                                         float(noise["slope"])),
                   correlation_gain=float(state.get("correlation_gain", 1.0)),  # 1: a file written before it
                   refits=int(state.get("refits", 0)))  # 0: a file written before it


def parameter_value(effects: dict, tensors: dict[str, Tensor], name: str) -> float:
    """The value of the parameter `name` (a `FitUncertainty.names` entry: "effect.parameter" of a scalar or
    of a tensor of named scalars, "effect.key[i, j]" of a tensor's entry as the heliostat takes it) in
    the fit (`effects`, `tensors`) (models/physics_fit.FitResult's)."""
    effect, parameter = name.split(".", 1)
    if "[" in parameter:
        index = tuple(int(i) for i in parameter[parameter.index("[") + 1:-1].split(","))
        return float(TENSOR_EFFECTS[effect].effective(tensors[effect])[index])
    if effect in tensors:  # a tensor of named scalars (tracking)
        scalars = [p.name for p in REGISTRY[effect].parameters if not p.array]
        return float(TENSOR_EFFECTS[effect].effective(tensors[effect])[scalars.index(parameter)])
    return float(effects[effect][parameter])


def widened_by_refits(uncertainty: FitUncertainty, refits: list) -> FitUncertainty:
    """`uncertainty` with every parameter's sigma at least the jackknife's over `refits`, the same
    model fitted with one of the n images left out each (FitResults: `effects`, `tensors`):
    ((n - 1) / n) sum_i (theta_i - mean theta)^2, the variance of the fit on all n images that the
    images themselves show, whatever the model lacks (the jackknife approximates the sandwich's
    robust variance without assuming the residual is noise). On a handful of real images no model
    matches them, and the covariance at the end point, read from a residual that is model mismatch
    more than noise, is many times too confident: a fold of AA31 on 3 images put its tracking 5.7
    sigma from the fit on the target's 4. The covariance is rescaled by D C D, D = diag(max(1,
    sigma_jackknife / sigma)): its correlations stay. Refits fewer than two: unchanged."""
    if len(refits) < 2 or not uncertainty.names:
        return uncertainty
    values = np.array([[parameter_value(r.effects, r.tensors, name) for name in uncertainty.names] for r in refits])
    n = len(refits)
    jackknife = (n - 1) / n * ((values - values.mean(0)) ** 2).sum(0)
    variance = np.diag(uncertainty.covariance)
    ratio = np.divide(jackknife, variance, out=np.ones_like(variance), where=variance > 0)
    factor = np.sqrt(np.maximum(ratio, 1.0))
    return replace(uncertainty, covariance=uncertainty.covariance * np.outer(factor, factor), refits=n)


def _num(x: float) -> float | None:
    return None if not math.isfinite(float(x)) else float(f"{float(x):.5g}")


def _shape(names: list[str]) -> tuple[int, ...]:
    """The tensor shape spanned by entry names "x[i, j]" (the last one is the largest index)."""
    last = names[-1][names[-1].index("[") + 1:-1]
    return tuple(int(i) + 1 for i in last.split(","))


@dataclass(frozen=True)
class _Parameter:
    """One fitted parameter: its name, unit, value and how to move it."""

    name: str
    unit: str
    value: float
    kind: str  # "tensor" | "spread" | "scale" | "offset"
    key: tuple = ()  # (tensor name, entry index) or (effect, parameter)


@dataclass
class _State:
    """A fit's end point as the Jacobian needs it."""

    scene: Scene
    effects: dict  # numbers for scalars, "fit" kept for tensor parameters
    tensors: dict[str, Tensor]  # effective (as the heliostat takes them)
    azimuth_deg: Tensor
    elevation_deg: Tensor
    loss: str
    scale: float  # the images' divisor (Measurements.scale)
    gain: float = 1.0  # the fitted scale factor (1 where none is fitted)
    offset: float = 0.0  # the fitted background (image units divided by `scale`)
    fast: LinearisedScene | None = None  # what the Jacobian's differences trace, where set (module docstring)

    def traced(self, effects: dict, tensors: dict, facets: Tensor | None = None,
               fast: bool = False) -> tuple[Tensor, Tensor]:
        """Images (N, H, W) and their lost flux (N,), divided by `scale`, with the fitted linear
        scalars neutral (they are applied in `prediction`); `fast`: on the linearised scene where
        there is one."""
        scene = self.fast if fast and self.fast is not None else self.scene
        with torch.no_grad():
            images, lost = scene.simulate(_neutral_linear(effects), tensors, self.azimuth_deg,
                                          self.elevation_deg, with_lost=True, facets=facets, projected=True)
        return images.double() / self.scale, lost.double() / self.scale

    def at(self, azimuth_deg: Tensor, elevation_deg: Tensor) -> _State:
        """The same end point at other sun positions (the linearised scene linearised there)."""
        fast = None if self.fast is None else LinearisedScene.of(self.scene, self.effects, self.tensors,
                                                                 azimuth_deg, elevation_deg)
        return replace(self, azimuth_deg=azimuth_deg, elevation_deg=elevation_deg, fast=fast)

    def prediction(self, images: Tensor, lost: Tensor, gain: float | None = None,
                   offset: float | None = None) -> tuple[Tensor, Tensor]:
        """(images, lost) as the model predicts them (gain and background applied)."""
        a = self.gain if gain is None else gain
        b = self.offset if offset is None else offset
        return a * images + b, a * lost

    def compared(self, images: Tensor, lost: Tensor | None) -> Tensor:
        """A prediction as the loss compares it (physics_fit: `normalised`)."""
        return normalised(images, self.loss, 1.0, lost if self.loss == "shape" else None)


def _neutral_linear(effects: dict) -> dict:
    out = {e: dict(p or {}) for e, p in effects.items()}
    for e, k in with_role("scale") | with_role("offset"):
        if e in out and k in out[e]:
            out[e][k] = 1.0 if (e, k) in with_role("scale") else 0.0
    return out


def parameters(state: _State, fitted: list[tuple[str, str]], masks: dict[str, Tensor]) -> list[_Parameter]:
    """The fitted parameters in registry order: every effective entry of a tensor with a free entry,
    then the fitted spread and linear scalars (one scale: the fit takes the first; none in a "shape"
    loss, which a scale does not change)."""
    out = []
    for key, tensor in state.tensors.items():
        if not bool(masks[key].any()):
            continue
        scalars = [p.name for p in REGISTRY[key].parameters if not p.array]
        unit = _unit(TENSOR_EFFECTS[key].key if not scalars else scalars[0])
        for index in np.ndindex(*tensor.shape):
            if scalars:
                name = f"{key}.{scalars[index[0]]}"
            else:
                name = f"{key}.{TENSOR_EFFECTS[key].key}[{', '.join(map(str, index))}]"
            out.append(_Parameter(name, unit, float(tensor[index]), "tensor", (key, index)))
    scales = [pair for pair in fitted if pair in with_role("scale")][:1] if state.loss == "absolute" else []
    for e, k in fitted:
        role = REGISTRY[e].parameter(k).role
        if role == "spread" or (e, k) in scales or role == "offset":
            out.append(_Parameter(f"{e}.{k}", _unit(k), float(state.effects[e][k]), role, (e, k)))
    return out


def _unit(parameter: str) -> str:
    """The unit a parameter's name ends with (config convention: sigma_mrad, control_heights_mm);
    "" for a factor."""
    suffix = parameter.rsplit("_", 1)[-1]
    return {"mrad": "mrad", "mm": "mm", "px": "px", "m2": "W/m^2", "deg": "deg", "m": "m"}.get(suffix, "")


def projection(key: str, tensor: Tensor, mask: Tensor) -> np.ndarray:
    """(entries, free entries) the linear map from the fit's free entries of `key` to the tensor
    as the heliostat takes it (`effective_tensors`: a projection, applied to unit vectors)."""
    free = mask.flatten().nonzero()[:, 0].tolist()
    flat = tensor.numel()
    columns = []
    for i in free:
        unit = torch.zeros(flat, dtype=torch.float64)
        unit[i] = 1.0
        columns.append(TENSOR_EFFECTS[key].effective(unit.reshape(tensor.shape)).flatten().numpy())
    return np.stack(columns, 1)


def perturbed(state: _State, params: list[_Parameter]) -> Iterator[tuple[int, float, tuple, tuple]]:
    """For each parameter k: (k, step, (images, lost) at +step, at -step), predictions in the units
    of `state.prediction`. A tensor entry of a facet traces that facet alone (the rest of the image
    is the unperturbed trace's)."""
    base = state.traced(state.effects, state.tensors, fast=True)
    per_facet: dict[int, tuple[Tensor, Tensor]] = {}
    for k, p in enumerate(params):
        if p.kind == "tensor":
            key, index = p.key
            step = TENSOR_EFFECTS[key].fd_step
            local = key != "tracking"  # every other tensor has its facet first
            facets = torch.tensor([index[0]], device=state.azimuth_deg.device) if local else None
            if local and index[0] not in per_facet:
                per_facet.clear()  # entries come facet by facet: one facet's own trace kept at a time
                per_facet[index[0]] = state.traced(state.effects, state.tensors, facets, fast=True)
            pair = []
            for sign in (1.0, -1.0):
                moved = {n: v.clone() for n, v in state.tensors.items()}
                moved[key][index] += sign * step
                images, lost = state.traced(state.effects, moved, facets, fast=True)
                if local:
                    own = per_facet[index[0]]
                    images, lost = base[0] - own[0] + images, base[1] - own[1] + lost
                pair.append(state.prediction(images, lost))
            yield k, step, pair[0], pair[1]
        elif p.kind == "spread":
            e, name = p.key
            low, high = _within_bounds(p)
            pair = []
            for value in (high, low):
                effects = {**state.effects, e: {**state.effects[e], name: value}}
                pair.append(state.prediction(*state.traced(effects, state.tensors, fast=True)))
            yield k, (high - low) / 2.0, pair[0], pair[1]
        else:  # linear: the prediction is linear in it
            typical = 1e-3 if p.kind == "scale" else float(base[0].mean()) * state.scale
            step = RELATIVE_STEP * max(abs(p.value), typical)
            if p.kind == "scale":
                plus, minus = (state.prediction(*base, gain=p.value + s * step) for s in (1.0, -1.0))
            else:
                plus, minus = (state.prediction(*base, offset=(p.value + s * step) / state.scale) for s in (1.0, -1.0))
            yield k, step, plus, minus


def _within_bounds(p: _Parameter) -> tuple[float, float]:
    """The central difference's two values of a spread scalar: +- RELATIVE_STEP of it, moved inside
    its registry bounds (one-sided at a bound)."""
    bounds = REGISTRY[p.key[0]].parameter(p.key[1])
    step = RELATIVE_STEP * max(abs(p.value), SPREAD_SCALE)
    lower, upper = bounds.lower if bounds.lower is not None else -math.inf, bounds.upper or math.inf
    low, high = max(p.value - step, lower), min(p.value + step, upper)
    if high - low < step:  # squeezed against a bound: a one-sided difference of one step
        low, high = (high - step, high) if high >= upper else (low, low + step)
    return low, high


def at_bound(p: _Parameter) -> bool:
    """A spread scalar fitted within RELATIVE_STEP of a registry bound (the images ask for a value
    beyond what the effect allows: it stands in for something else, and its sigma means nothing)."""
    bounds = REGISTRY[p.key[0]].parameter(p.key[1])
    return any(b is not None and abs(p.value - b) <= RELATIVE_STEP * max(abs(p.value), SPREAD_SCALE)
               for b in (bounds.lower, bounds.upper))


def fit_uncertainty(state: _State, fitted: list[tuple[str, str]], masks: dict[str, Tensor],
                    measured: Tensor) -> FitUncertainty:
    """The covariance of the fit ending in `state` (module docstring).

    Args:
        fitted: the fit's (effect, parameter) pairs (FitResult.fitted).
        masks: {tensor: bool mask of the fit's free entries} (physics_fit.initial_tensors).
        measured: (N, H, W) the fitted images, divided by `state.scale` (Measurements.images).
    """
    params = parameters(state, fitted, masks)
    if not params:
        return FitUncertainty([], [], np.zeros(0), np.zeros((0, 0)), 0.0, 0.0, 0.0)
    base = state.prediction(*state.traced(state.effects, state.tensors))
    predicted = state.compared(*base)
    residual = predicted - state.compared(measured.double(), None)
    noise = measure_noise(residual, predicted)  # white noise, read where no spot is left (module docstring)
    columns, std, _ = compared_jacobian(state, params, noise)
    jacobian, names, units, values, entry_of = _free_jacobian(columns, params, state, masks)
    variance = std**2
    h = (jacobian.T @ jacobian).double()
    weighted = jacobian * std.float()[:, None]
    h_plus = _pseudo_inverse(h.numpy())
    misfit = float((residual**2).sum() / variance.sum().clamp_min(1e-300))
    whitened = residual / std.reshape(measured.shape)
    n, rows, cols = measured.shape
    gram = correlated_gram(weighted, (n, rows, cols), ring_spectrum(whitened, unit_mean=max(1.0, misfit)))
    white_gram = (weighted.T @ weighted).double().numpy() * max(1.0, misfit)
    white = np.diag(white_gram)
    gain = np.divide(np.diag(gram), white, out=np.ones_like(white), where=white > 0)
    shaped = variance.reshape(measured.shape)
    overall = structure(residual, shaped)
    facets = _facet_structure(state, residual, shaped) if _has_facets(params) else None
    off = set() if facets is None else {int(f) for f in np.flatnonzero(facets > STRUCTURED)}
    undetermined = [p.name for p in params if (p.kind == "spread" and (overall > SPREADS_STRUCTURED or at_bound(p)))
                    or (p.kind == "tensor" and p.key[0] != "tracking" and p.key[1][0] in off)]
    newton = h_plus @ (jacobian.T @ residual.flatten().float()).double().numpy()  # what the fit has left to go
    stopped = np.outer(newton, newton)
    covariance = entry_of @ (h_plus @ gram @ h_plus + stopped + _systematic(h.numpy(), state, masks, off)) @ entry_of.T
    statistical = h_plus @ white_gram @ h_plus + stopped  # the Wald test's: white noise (FitUncertainty.statistical)
    return FitUncertainty(names, units, values, covariance, misfit, overall, float(variance.mean().sqrt()), facets,
                          undetermined, noise, entry_of @ statistical @ entry_of.T, float(np.median(gain)))


def compared_jacobian(state: _State, params: list[_Parameter],
                      noise: NoiseModel) -> tuple[Tensor, Tensor, tuple[Tensor, Tensor]]:
    """(Jacobian (N*H*W, P) of the prediction as the loss compares it, in the parameters as the
    heliostat takes them (`perturbed`), the pixels' noise std (N*H*W,) at the predicted level
    (`noise`: in the loss' units; at least NOISE_FLOOR of the peak), the prediction (images
    (N, H, W), lost flux (N,)))."""
    base = state.prediction(*state.traced(state.effects, state.tensors))
    compared = state.compared(*base)
    std = noise.std(compared).flatten().clamp_min(NOISE_FLOOR * float(compared.abs().max()))
    columns = torch.zeros(base[0].numel(), len(params), dtype=torch.float32)
    for k, step, plus, minus in perturbed(state, params):
        columns[:, k] = ((state.compared(*plus) - state.compared(*minus)) / (2.0 * step)).flatten().float()
    return columns, std, base


def _systematic(h: np.ndarray, state: _State, masks: dict[str, Tensor], off: set[int]) -> np.ndarray:
    """(Q, Q) covariance, in the fit's free entries, of what facets the fit has not found (`off`)
    do to the rest: their entries may be off by as much as a typical entry of their tensor (its
    RMS over the heliostat), and every other entry moves with them as the least-squares optimum
    does, by -H_dd^+ H_du (d: the other entries, u: theirs)."""
    facets: list[int] = []
    typicals: list[float] = []
    for key, tensor in state.tensors.items():
        if not bool(masks[key].any()):
            continue
        free = masks[key].flatten().nonzero()[:, 0]
        per_facet = key != "tracking"
        index = np.unravel_index(free.cpu().numpy(), tuple(tensor.shape))[0] if per_facet else np.full(len(free), -1)
        facets.extend(index.tolist())
        typicals.extend([float(tensor.detach().double().pow(2).mean().sqrt())] * len(free))
    facet = np.array(facets + [-1] * (len(h) - len(facets)))
    typical = np.array(typicals + [0.0] * (len(h) - len(typicals)))
    u = np.isin(facet, sorted(off))
    out = np.zeros_like(h)
    if not u.any():
        return out
    d = ~u
    spread = typical[u] ** 2
    out[np.ix_(u, u)] = np.diag(spread)
    if not d.any():
        return out
    sensitivity = -_pseudo_inverse(h[np.ix_(d, d)]) @ h[np.ix_(d, u)]  # (|d|, |u|)
    out[np.ix_(d, d)] = (sensitivity * spread) @ sensitivity.T
    out[np.ix_(d, u)] = sensitivity * spread
    out[np.ix_(u, d)] = out[np.ix_(d, u)].T
    return out


def _has_facets(params: list[_Parameter]) -> bool:
    return any(p.kind == "tensor" and p.key[0] != "tracking" for p in params)


def _free_jacobian(columns: Tensor, params: list[_Parameter], state: _State,
                   masks: dict[str, Tensor]) -> tuple[Tensor, list, list, np.ndarray, np.ndarray]:
    """(Jacobian in the fit's free entries (pixels, Q), names, units and values of the reported
    parameters (P,), the map (P, Q) from free entries to reported ones)."""
    blocks, maps = [], []
    at = 0
    for key, tensor in state.tensors.items():
        if not bool(masks[key].any()):
            continue
        n = tensor.numel()
        p = projection(key, tensor.detach().cpu(), masks[key].cpu())  # (n, free)
        blocks.append(columns[:, at:at + n] @ torch.as_tensor(p, dtype=torch.float32))
        maps.append(p)
        at += n
    rest = len(params) - at
    if rest:
        blocks.append(columns[:, at:])
        maps.append(np.eye(rest))
    size = (sum(m.shape[0] for m in maps), sum(m.shape[1] for m in maps))
    entry_of = np.zeros(size)
    r = c = 0
    for m in maps:
        entry_of[r:r + m.shape[0], c:c + m.shape[1]] = m
        r, c = r + m.shape[0], c + m.shape[1]
    return (torch.cat(blocks, 1), [p.name for p in params], [p.unit for p in params],
            np.array([p.value for p in params]), entry_of)


def _pseudo_inverse(h: np.ndarray) -> np.ndarray:
    """Pseudo-inverse of a symmetric positive semi-definite matrix, directions below EIGEN_CUT of
    its largest eigenvalue dropped (they change no image)."""
    values, vectors = np.linalg.eigh(h)
    keep = values > EIGEN_CUT * max(values.max(), 1e-300)
    return (vectors[:, keep] / values[keep]) @ vectors[:, keep].T


def structure(residual: Tensor, variance: Tensor, weight: Tensor | None = None) -> float:
    """Smoothed residual power over what noise alone leaves after the same smoothing (~1 for a
    residual that is noise; larger for one with structure over several pixels).

    Args:
        residual: (N, H, W) residual images (loss units).
        variance: (N, H, W) the pixels' noise variance (same units squared).
        weight: (N, H, W) pixel weights (a facet's share of the flux), None = all alike.
    """
    box = torch.ones(1, 1, SMOOTH_PX, SMOOTH_PX, dtype=torch.float64) / SMOOTH_PX**2
    smoothed = torch.nn.functional.conv2d(residual.double()[:, None], box)[:, 0] ** 2
    expected = torch.nn.functional.conv2d(variance.double()[:, None], box**2)[:, 0]  # white noise's
    if weight is not None:
        w = torch.nn.functional.conv2d(weight.double()[:, None], box)[:, 0]
        smoothed, expected = smoothed * w, expected * w
    return float(smoothed.sum() / expected.sum().clamp_min(1e-300))


def _facet_structure(state: _State, residual: Tensor, variance: Tensor) -> np.ndarray:
    """(F,) `structure` where each facet's flux lands, each pixel weighted by the facet's share of
    the predicted flux there."""
    device = state.azimuth_deg.device
    parts = torch.stack([state.traced(state.effects, state.tensors, torch.tensor([f], device=device), fast=True)[0]
                         for f in range(state.scene.heliostat.n_facets)])  # (F, N, H, W)
    share = parts / parts.sum(0).clamp_min(1e-30)
    return np.array([structure(residual, variance, s) for s in share])


def end_state(scene: Scene, result, azimuth_deg: Tensor, elevation_deg: Tensor, scale: float, loss: str,
              masks: dict[str, Tensor]) -> _State:
    """The `_State` of a physics_fit.FitResult (fitted with `loss` to images divided by `scale`, its
    tensors' free entries `masks`) at (N,) sun positions (deg). With heliostat tensors on several
    facets, the Jacobian's differences trace the scene linearised at the fit (physics/linearised.py:
    the hits are linear in the tensors at these sizes; a deposit and a convolution per image instead
    of a trace: 38 -> 9 s for semi_sphere's 654 parameters on 24 images)."""
    tensors = effective_tensors({k: v.detach() for k, v in result.tensors.items() if k in masks})
    gain, offset = 1.0, 0.0
    scales = [pair for pair in result.fitted if pair in with_role("scale")][:1] if loss == "absolute" else []
    for e, k in result.fitted:
        if (e, k) in scales:
            gain = float(result.effects[e][k])
        elif (e, k) in with_role("offset"):
            offset = float(result.effects[e][k]) / scale
    fast = None
    if tensors and scene.heliostat.n_facets > 1 and isinstance(scene, Scene):
        fast = LinearisedScene.of(scene, result.effects, tensors, azimuth_deg, elevation_deg)
    return _State(scene, result.effects, tensors, azimuth_deg, elevation_deg, loss, scale, gain, offset, fast)


def _centroid_jacobian(state: _State, params: list[_Parameter], centroid) -> Tensor | None:
    """(N, 2, K) the derivative of each image's `centroid` ((N, H, W) predictions -> (N, 2) mrad) by
    the K tensor entries `params`, by autograd through the trace linearised at the fit
    (physics/linearised.py), each of the N images with its own copy of the tensors: one backward
    pass per centroid axis instead of two traces per entry (200 images and 69 entries: ~100 times
    fewer traces). Its derivatives are the linearised trace's, which hold each cell's power and
    footprint at the fit: on sanity_check's surface and tracking the sigma they give is that of
    central differences on the kernel trace to 0.2 % at the median, 3 % on every image. None when
    the scene cannot be linearised."""
    fast = state.fast
    if fast is None:
        if not isinstance(state.scene, Scene):
            return None
        fast = LinearisedScene.of(state.scene, state.effects, state.tensors, state.azimuth_deg, state.elevation_deg)
    n = len(state.azimuth_deg)
    own = {k: v.detach().expand(n, *v.shape).clone().requires_grad_() for k, v in state.tensors.items()}
    with torch.enable_grad():
        images, lost = fast.simulate(_neutral_linear(state.effects), own, state.azimuth_deg, state.elevation_deg,
                                     with_lost=True, projected=True)
        images, _ = state.prediction(images.double() / state.scale, lost.double() / state.scale)
        c = centroid(images)
        columns = []
        for axis in (0, 1):
            grads = torch.autograd.grad(c[:, axis].sum(), list(own.values()), retain_graph=axis == 0,
                                        allow_unused=True)
            by_key = {k: torch.zeros_like(v) if g is None else g for (k, v), g in zip(own.items(), grads)}
            columns.append(torch.stack([by_key[p.key[0]][(slice(None), *p.key[1])] for p in params], -1))
    return torch.stack(columns, 1).double()


def predicted_spread(state: _State, fitted: list[tuple[str, str]], masks: dict[str, Tensor],
                     uncertainty: FitUncertainty, with_flux: bool = False) -> dict[str, Tensor]:
    """What the covariance implies for the spots at `state`'s sun positions (N of them), to first
    order: {"centroid_mrad": (N, 2) predicted centroid (target right, up; as seen from the
    heliostat), "centroid_sigma_mrad": (N, 2) its sigma, "centroid_jacobian": (N, 2, P) the
    centroid's derivative by each parameter (mrad per parameter unit), and with_flux "flux": (N, H, W)
    the predicted flux (image units divided by `state.scale`) with "flux_sigma" (N, H, W)}."""
    params = parameters(state, fitted, masks)
    if [p.name for p in params] != uncertainty.names:
        raise ValueError("the uncertainty was computed for other parameters than this fit's")
    slant = float((state.scene.target.center - state.scene.heliostat.position).norm())

    def centroid(images: Tensor) -> Tensor:  # (N, 2) mrad
        return state.scene.target.centroid(images.float()).double() / slant * 1e3

    images, _ = state.prediction(*state.traced(state.effects, state.tensors))
    c_columns = torch.zeros(len(images), 2, len(params), dtype=torch.float64)
    f_columns = torch.zeros(images.numel(), len(params), dtype=torch.float32) if with_flux else None
    by_tensor = [] if with_flux else [k for k, p in enumerate(params) if p.kind == "tensor"]
    if by_tensor and (columns := _centroid_jacobian(state, [params[k] for k in by_tensor], centroid)) is not None:
        c_columns[..., by_tensor] = columns
    else:
        by_tensor = []
    rest = [k for k in range(len(params)) if k not in by_tensor]
    for j, step, plus, minus in perturbed(state, [params[k] for k in rest]) if rest else ():
        k = rest[j]
        c_columns[..., k] = (centroid(plus[0]) - centroid(minus[0])) / (2.0 * step)
        if f_columns is not None:  # with_flux
            f_columns[:, k] = ((plus[0] - minus[0]) / (2.0 * step)).flatten().float()
    cov = torch.as_tensor(uncertainty.covariance)
    out = {"centroid_mrad": centroid(images),
           "centroid_sigma_mrad": torch.einsum("nap,pq,naq->na", c_columns, cov, c_columns).clamp_min(0).sqrt(),
           "centroid_jacobian": c_columns}
    if f_columns is not None:  # with_flux
        values, vectors = torch.linalg.eigh(cov)
        root = (vectors * values.clamp_min(0).sqrt()).float()  # cov = root root^T
        out["flux"] = images
        out["flux_sigma"] = (f_columns @ root).pow(2).sum(1).sqrt().reshape(images.shape)
    return out
