"""Sun shapes: exact sampling, normalised beam-spread densities and config validation."""

import math

import numpy as np
import pytest
import torch

from helioflow.errors import ConfigError
from helioflow.physics.sun import (
    SUN_KINDS,
    SunShape,
    effective_sigma,
    radial_density,
    rms_radius,
    sample_deviations,
)

MRAD = 1e-3
N = 200_000


def _samples(shape: SunShape, n: int = N, seed: int = 0) -> torch.Tensor:
    return sample_deviations(shape, n, torch.Generator().manual_seed(seed), dtype=torch.float64)


def _buie_reference(csr: float) -> tuple[float, float]:
    """Independent Buie (nominal chi, cut at 43.6 mrad): (aureole energy fraction, E[theta^2] in rad^2)."""
    kappa = 0.9 * math.log(13.5 * csr) * csr**-0.3
    gamma = 2.2 * math.log(0.52 * csr) * csr**0.43 - 0.1
    t = np.linspace(0.0, 4.65, 200_001)
    phi = np.cos(0.326 * t) / np.cos(0.308 * t)
    disc, disc2 = np.trapezoid(phi * t, t), np.trapezoid(phi * t**3, t)
    aureole = math.exp(kappa) * (43.6 ** (gamma + 2) - 4.65 ** (gamma + 2)) / (gamma + 2)
    aureole2 = math.exp(kappa) * (43.6 ** (gamma + 4) - 4.65 ** (gamma + 4)) / (gamma + 4)
    total = disc + aureole
    return aureole / total, (disc2 + aureole2) / total * MRAD**2


def _integrate(f, theta_max: float, power: int = 0) -> float:
    """2*pi * integral_0^theta_max f(theta) theta^(power + 1) dtheta on a fine grid."""
    theta = torch.linspace(0.0, theta_max, 400_001, dtype=torch.float64)
    return 2 * math.pi * torch.trapezoid(f(theta) * theta ** (power + 1), theta).item()


def test_point_sun_gives_zero_deviations():
    d = _samples(SunShape("point"), 10)
    assert d.shape == (10, 2) and torch.all(d == 0)


def test_gaussian_per_axis_std_is_sigma():
    sigma = 2.0 * MRAD
    d = _samples(SunShape.from_config({"kind": "gaussian", "sigma_mrad": 2.0}))
    tol = 5 * sigma / math.sqrt(2 * N)
    assert torch.allclose(d.std(0), torch.full((2,), sigma, dtype=torch.float64), atol=tol)
    assert torch.allclose(d.mean(0), torch.zeros(2, dtype=torch.float64), atol=5 * sigma / math.sqrt(N))


def test_pillbox_samples_fill_the_disc_uniformly():
    big_r = 4.65 * MRAD
    r = _samples(SunShape("pillbox", half_angle_mrad=4.65)).norm(dim=1)
    assert r.max() <= big_r * (1 + 1e-12)
    assert abs(r.mean().item() - 2 * big_r / 3) < 5 * big_r / math.sqrt(18 * N)
    assert abs((r < big_r / 2).double().mean().item() - 0.25) < 5 * math.sqrt(0.25 * 0.75 / N)


def test_buie_aureole_fraction_matches_profile_and_grows_with_csr():
    fractions = []
    for csr in (0.02, 0.05, 0.1, 0.2, 0.4):
        r = _samples(SunShape.from_config({"kind": "buie", "csr": csr})).norm(dim=1)
        assert r.max() <= 43.6 * MRAD * (1 + 1e-12)
        fraction = (r > 4.65 * MRAD).double().mean().item()
        expected, _ = _buie_reference(csr)
        assert abs(fraction - expected) < 5 * math.sqrt(expected * (1 - expected) / N) + 1e-4, csr
        fractions.append(fraction)
    assert fractions == sorted(fractions) and fractions[0] < fractions[-1]


@pytest.mark.parametrize(
    "config, slope_mrad",
    [
        ({"kind": "point"}, 1.0),
        ({"kind": "pillbox"}, 0.0),
        ({"kind": "pillbox", "half_angle_mrad": 2.0}, 1.5),
        ({"kind": "gaussian"}, 0.0),
        ({"kind": "gaussian", "sigma_mrad": 1.0}, 0.5),
        ({"kind": "buie", "csr": 0.1}, 0.0),
        ({"kind": "buie", "csr": 0.1}, 1.0),
        ({"kind": "buie", "csr": 0.4}, 0.2),
    ],
)
def test_radial_density_is_normalised(config, slope_mrad):
    f = radial_density(SunShape.from_config(config), slope_mrad * MRAD)
    assert _integrate(f, 80 * MRAD) == pytest.approx(1.0, abs=2e-4)


def test_gaussian_with_slope_error_is_the_analytic_gaussian():
    s_sun, s_slope = 2.0 * MRAD, 1.0 * MRAD
    f = radial_density(SunShape("gaussian", sigma_mrad=2.0), s_slope)
    theta = torch.linspace(0.0, 20 * MRAD, 101, dtype=torch.float64)
    var = s_sun**2 + 4 * s_slope**2
    assert torch.allclose(f(theta), torch.exp(-(theta**2) / (2 * var)) / (2 * math.pi * var), rtol=1e-9)
    assert rms_radius(SunShape("gaussian", sigma_mrad=2.0), s_slope) == pytest.approx(math.sqrt(2 * var))


def test_pillbox_density_edge_and_blurred_centre():
    big_r, s_slope = 4.65 * MRAD, 1.0 * MRAD
    shape = SunShape("pillbox")
    bare = radial_density(shape)(torch.tensor([0.0, 0.99 * big_r, 1.01 * big_r], dtype=torch.float64))
    assert torch.allclose(bare, torch.tensor([1.0, 1.0, 0.0], dtype=torch.float64) / (math.pi * big_r**2))
    # the blurred centre has a closed form, (1 - exp(-R^2 / (2 sigma^2))) / (pi R^2); rings cost ~2e-4
    sigma = 2 * s_slope
    centre = radial_density(shape, s_slope)(torch.zeros(1, dtype=torch.float64)).item()
    expected = (1 - math.exp(-(big_r**2) / (2 * sigma**2))) / (math.pi * big_r**2)
    assert centre == pytest.approx(expected, rel=5e-4)
    assert effective_sigma(shape) == pytest.approx(big_r / 2, rel=1e-6)
    second = _integrate(radial_density(shape, s_slope), 30 * MRAD, power=2)
    assert second == pytest.approx(big_r**2 / 2 + 8 * s_slope**2, rel=1e-4)


def test_buie_second_moment_density_matches_samples():
    shape, s_slope = SunShape("buie", csr=0.2), 1.0 * MRAD
    _, sun_second = _buie_reference(0.2)
    assert 2 * effective_sigma(shape) ** 2 == pytest.approx(sun_second, rel=1e-4)
    g = torch.Generator().manual_seed(3)
    d = sample_deviations(shape, 400_000, g, torch.float64)
    d = d + torch.randn(d.shape, generator=g, dtype=torch.float64) * 2 * s_slope
    r2 = (d**2).sum(1)
    density_second = _integrate(radial_density(shape, s_slope), 60 * MRAD, power=2)
    assert density_second == pytest.approx(rms_radius(shape, s_slope) ** 2, rel=1e-3)
    assert abs(r2.mean().item() - density_second) < 5 * r2.std().item() / math.sqrt(r2.numel())


def test_same_seed_gives_identical_samples():
    for kind in SUN_KINDS:
        shape = SunShape(kind)
        assert torch.equal(_samples(shape, 1000, seed=7), _samples(shape, 1000, seed=7))
        if kind != "point":
            assert not torch.equal(_samples(shape, 1000, seed=7), _samples(shape, 1000, seed=8))
    assert _samples(SunShape("buie"), 10).dtype == torch.float64
    assert sample_deviations(SunShape("buie"), 10, torch.Generator()).dtype == torch.float32


def test_from_config_builds_the_named_shape():
    assert SunShape.from_config({"kind": "buie", "csr": 0.1}) == SunShape("buie", csr=0.1)
    assert SunShape.from_config({"kind": "pillbox", "half_angle_mrad": 4}).half_angle_mrad == 4.0
    assert SunShape.from_config({"kind": "point"}).kind == "point"


@pytest.mark.parametrize(
    "config, key",
    [
        ({"kind": "sunny"}, "sunny"),
        ({"csr": 0.1}, "kind"),
        ({"kind": "buie", "csr": 0.5}, "csr"),
        ({"kind": "buie", "csr": 0.001}, "csr"),
        ({"kind": "buie", "csr": "0.1"}, "csr"),
        ({"kind": "pillbox", "half_angle_mrad": 0.0}, "half_angle_mrad"),
        ({"kind": "gaussian", "sigma_mrad": -1.0}, "sigma_mrad"),
        ({"kind": "gaussian", "sigma_mrad": float("nan")}, "sigma_mrad"),
        ({"kind": "gaussian", "sigma": 2.0}, "sigma"),
        ({"kind": "point", "csr": 0.1}, "csr"),
    ],
)
def test_bad_config_names_the_key(config, key):
    with pytest.raises(ConfigError, match=key):
        SunShape.from_config(config)


def test_bad_arguments_raise_config_error():
    with pytest.raises(ConfigError, match="finite size or a slope error"):
        radial_density(SunShape("point"))
    with pytest.raises(ConfigError, match="slope_sigma_rad"):
        radial_density(SunShape("buie"), -1e-3)
    with pytest.raises(ConfigError, match="n="):
        sample_deviations(SunShape("buie"), -1, torch.Generator())
