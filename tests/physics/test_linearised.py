"""The linearised trace (physics.linearised) against the tracer it stands in for: the kernel trace of
the same heliostat with realistic errors, per facet and in total power."""

import math

import pytest
import torch

from helioflow.physics.heliostat import ideal_heliostat, without_planes
from helioflow.physics.scene import LinearisedScene, Scene, effective_tensors
from helioflow.physics.target import Target

BUIE = {"kind": "buie", "csr": 0.1}
WORLD = {"sunshape": {"kind": "gaussian", "sigma_mrad": 1.0}, "slope_error": {"sigma_mrad": 0.5},
         "tracking": {}, "canting": {}, "surface": {}}


def scene() -> Scene:
    """A 2 x 3 facet heliostat canted at 60 m, 63 m from a 3 m target at 48 x 48 pixels."""
    h = ideal_heliostat(rows=2, cols=3, width=0.8, height=0.6, gap=0.02, position=(0.0, 60.0, 0.0),
                        canting_focal_distance=60.0, control_points=5, dtype=torch.float32)
    target = Target(torch.tensor([0.0, 0.0, 20.0]), torch.tensor([0.0, 1.0, 0.0]), 3.0, 3.0, (48, 48))
    return Scene(h, target, 1000.0, cells_per_side=16)


def errors(scale: float = 1.0) -> dict[str, torch.Tensor]:
    """Calibration-sized errors: tracking ~1 mrad, canting ~0.5 mrad, control heights ~0.3 mm."""
    g = torch.Generator().manual_seed(3)
    return {"tracking": torch.randn(5, generator=g) * scale, "canting": torch.randn(6, 2, generator=g) * 0.5 * scale,
            "surface": torch.randn(6, 5, 5, generator=g) * 0.3 * scale}


def suns() -> tuple[torch.Tensor, torch.Tensor]:
    return torch.tensor([-60.0, 0.0, 30.0, 80.0]), torch.tensor([20.0, 45.0, 60.0, 30.0])


def psnr(image: torch.Tensor, reference: torch.Tensor) -> float:
    return 10 * math.log10(float(reference.max()) ** 2 / float(((image - reference) ** 2).mean()))


@pytest.mark.parametrize("sunshape", [WORLD["sunshape"], BUIE])
def test_the_linearised_trace_reproduces_the_kernel_trace_of_a_heliostat_with_realistic_errors(sunshape):
    """Linearised at the design geometry, evaluated at errors of the sizes calibration measures: the
    images agree with the kernel trace far below the noise of any measured spot (> 50 dB), while
    the errors themselves change the images by far more (the design is > 25 dB further off)."""
    s, (az, el) = scene(), suns()
    world = {**WORLD, "sunshape": sunshape}
    design = {k: torch.zeros_like(v) for k, v in errors().items()}
    linear = LinearisedScene.of(s, world, design, az, el)
    with torch.no_grad():
        exact = s.simulate(world, errors(), az, el)
        fast = linear.simulate(world, errors(), az, el)
        flat = s.simulate(world, design, az, el)
    assert psnr(fast, exact) > 50.0, psnr(fast, exact)
    assert psnr(fast, exact) > psnr(flat, exact) + 25.0


def test_its_facets_add_up_and_it_conserves_the_reflected_power():
    """The facets' images add up to the heliostat's, and a spot that lies inside the target holds
    all the power the cells reflect towards it (W = flux * pixel area)."""
    s, (az, el) = scene(), suns()
    linear = LinearisedScene.of(s, WORLD, {k: torch.zeros_like(v) for k, v in errors().items()}, az, el)
    optics = s._physics(WORLD).optics
    tensors = effective_tensors(errors())
    whole, launched = linear.trace.images(tensors, optics, with_launched=True)
    parts = linear.trace.images(tensors, optics, torch.tensor([0, 4])) + \
        linear.trace.images(tensors, optics, torch.tensor([1, 2, 3, 5]))
    torch.testing.assert_close(parts, whole, rtol=1e-4, atol=1e-4 * float(whole.max()))
    torch.testing.assert_close(whole.sum((-2, -1)) * s.target.pixel_area, launched, rtol=1e-3, atol=0.0)


def test_it_is_differentiable_in_every_heliostat_tensor_and_refuses_other_sun_positions():
    s, (az, el) = scene(), suns()
    tensors = {k: v.clone().requires_grad_(True) for k, v in errors().items()}
    linear = LinearisedScene.of(s, WORLD, errors(0.0), az, el)
    linear.simulate(WORLD, tensors, az, el).pow(2).sum().backward()
    assert all(t.grad is not None and t.grad.abs().sum() > 0 for t in tensors.values())
    assert torch.allclose(without_planes(tensors["surface"].grad), tensors["surface"].grad, atol=1e-3)
    with pytest.raises(ValueError, match="sun positions it was linearised for"):
        linear.simulate(WORLD, errors(), az + 1.0, el)
