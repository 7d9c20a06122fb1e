"""The NeRF focal-spot model: geometry of the static-scene transform, shapes, training, resume."""

import math

import torch

from helioflow.models.base import TrainingData, sun_features
from helioflow.models.nerf import NerfConfig, SpotNeRF, beam_direction, camera_direction, heliostat_rotation, mirror_normal
from helioflow.models.registry import load_model, save_model
from helioflow.models.training import LoopConfig, train

SMALL = NerfConfig(width=16, depth=2, samples=4, rays=64, frequencies=2, view_frequencies=1)


def tiny_data(n: int = 6, size: int = 16) -> TrainingData:
    g = torch.Generator().manual_seed(0)
    images = torch.rand(n, size, size, generator=g)
    az = torch.linspace(-30.0, 30.0, n)
    el = torch.linspace(20.0, 60.0, n)
    return TrainingData(images / images.max(), az, el, 1.0)


def test_the_mirror_turns_by_half_the_sun_angle():
    """The normal bisects sun and beam: moving the sun by a along a great circle through the beam
    turns the normal by a / 2 (the static-scene transform rests on this)."""
    beam = beam_direction(torch.tensor([0.0, 60.0, 0.0]), torch.tensor([0.0, 0.0, 20.0])).double()
    side = torch.linalg.cross(beam, torch.tensor([1.0, 0.0, 0.0], dtype=torch.float64))
    side = side / side.norm()
    for a in (0.3, 0.6, 1.0):
        b = 0.2
        s1 = math.cos(b) * beam + math.sin(b) * side
        s2 = math.cos(b + a) * beam + math.sin(b + a) * side
        turned = torch.arccos((mirror_normal(s1, beam) * mirror_normal(s2, beam)).sum().clamp(-1, 1))
        assert abs(turned.item() - a / 2) < 1e-6


def test_camera_direction_is_the_beam_seen_from_the_mirror():
    """d = R^T b: its z component is the cosine of incidence, and the sun seen from the mirror is
    the mirror image of d in the normal z."""
    beam = beam_direction(torch.tensor([0.0, 60.0, 0.0]), torch.tensor([0.0, 0.0, 20.0]))
    sun = sun_features(torch.tensor([10.0, -40.0]), torch.tensor([30.0, 55.0]))
    rotation = heliostat_rotation("az_el", sun, beam)
    d = camera_direction(rotation, beam)
    sun_h = torch.einsum("sji,sj->si", rotation, sun)
    z = torch.tensor([0.0, 0.0, 1.0])
    torch.testing.assert_close(sun_h, 2 * d[:, 2:3] * z - d, atol=1e-5, rtol=0)
    cos_incidence = (sun * mirror_normal(sun, beam)).sum(-1)
    torch.testing.assert_close(d[:, 2], cos_incidence, atol=1e-5, rtol=0)


def test_predict_shape_and_range():
    model = SpotNeRF(SMALL, (16, 16))
    out = model.predict(torch.tensor([0.0, 20.0, -50.0]), torch.tensor([30.0, 50.0, 70.0]), torch.Generator())
    assert out.shape == (3, 16, 16)
    assert torch.isfinite(out).all() and (out >= 0).all()


def _trained(steps: int, checkpoint, stop_at: int | None = None) -> SpotNeRF:
    torch.manual_seed(0)
    model = SpotNeRF(SMALL, (16, 16))
    data = tiny_data()
    model.prepare(data)
    if stop_at is not None:
        train(model, data, LoopConfig(steps=stop_at, batch_size=2, seed=3, checkpoint_every=2), checkpoint, progress=False)
        torch.manual_seed(0)
        model = SpotNeRF(SMALL, (16, 16))
        model.prepare(data)
    train(model, data, LoopConfig(steps=steps, batch_size=2, seed=3, checkpoint_every=2), checkpoint, progress=False)
    return model


def test_two_training_iterations_change_the_parameters(tmp_path):
    before = [p.clone() for p in SpotNeRF(SMALL, (16, 16)).parameters()]
    torch.manual_seed(0)
    model = _trained(2, tmp_path / "a.ckpt")
    assert any(not torch.equal(a, b) for a, b in zip(before, model.parameters()))


def test_resume_from_a_checkpoint_equals_an_uninterrupted_run(tmp_path):
    straight = _trained(4, tmp_path / "straight.ckpt")
    resumed = _trained(4, tmp_path / "resumed.ckpt", stop_at=2)
    for a, b in zip(straight.parameters(), resumed.parameters()):
        assert torch.equal(a, b)


def test_save_and_load_give_identical_predictions(tmp_path):
    model = _trained(2, tmp_path / "m.ckpt")
    save_model(tmp_path / "nerf.pt", model, "nerf", SMALL, 1.0, {})
    loaded, info = load_model(tmp_path / "nerf.pt")
    az, el = torch.tensor([5.0, 25.0]), torch.tensor([35.0, 45.0])
    assert info["network"] == "nerf"
    assert torch.equal(model.predict(az, el, torch.Generator()), loaded.predict(az, el, torch.Generator()))
