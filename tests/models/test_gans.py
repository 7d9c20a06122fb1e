"""The DCGAN (`gan`) and the conditional GAN (`cgan`): shapes, ranges, training through the shared
loop, exact resume from a checkpoint, conditioning and the model-file round trip."""

import numpy as np
import pytest
import torch

from helioflow.errors import ConfigError
from helioflow.models.base import TrainingData
from helioflow.models.cgan import CganConfig, ConditionalGAN
from helioflow.models.dcgan import DCGAN, GanConfig
from helioflow.models.registry import load_model, save_model
from helioflow.models.training import LoopConfig, train

SMALL = {"latent": 8, "features": 4}
MODELS = {"gan": (DCGAN, GanConfig), "cgan": (ConditionalGAN, CganConfig)}


def make(network: str, size: int = 16, **overrides):
    model_cls, config_cls = MODELS[network]
    torch.manual_seed(0)
    return model_cls(config_cls(**{**SMALL, **overrides}), (size, size))


def tiny_data(n: int = 8, size: int = 16) -> TrainingData:
    g = torch.Generator().manual_seed(1)
    images = torch.rand(n, size, size, generator=g) ** 4
    return TrainingData(images, torch.linspace(-60, 60, n), torch.linspace(15, 75, n), scale=1.0)


def positions(n: int):
    return torch.linspace(-90, 90, n), torch.linspace(10, 80, n)


@pytest.mark.parametrize("network", MODELS)
def test_predict_shape_and_range_64(network):
    model = make(network, 64).eval()
    with torch.no_grad():
        out = model.predict(*positions(3), torch.Generator().manual_seed(0))
    assert out.shape == (3, 64, 64)
    assert out.min() >= 0 and out.max() <= 1


@pytest.mark.parametrize("size", [16, 32, 64])
def test_discriminator_maps_images_to_logits(size):
    model = make("gan", size)
    assert model.netD(torch.rand(5, 1, size, size)).shape == (5,)
    cgan = make("cgan", size)
    assert cgan.netD(torch.rand(5, 1, size, size), torch.rand(5, 3)).shape == (5,)


@pytest.mark.parametrize("shape", [(48, 48), (8, 8), (32, 16)])
def test_unsupported_image_shapes_are_refused(shape):
    with pytest.raises(ConfigError, match="power-of-two"):
        DCGAN(GanConfig(**SMALL), shape)


def test_dcgan_ignores_positions_and_draws_from_the_generator():
    model = make("gan").eval()
    with torch.no_grad():
        a = model.predict(*positions(2), torch.Generator().manual_seed(3))
        b = model.predict(*positions(2), torch.Generator().manual_seed(3))
        c = model.predict(*positions(2), torch.Generator().manual_seed(4))
    assert torch.equal(a, b) and not torch.equal(a, c)
    assert not torch.equal(a[0], a[1])  # N independent samples


@pytest.mark.parametrize("network", MODELS)
def test_training_through_the_loop_changes_parameters(network, tmp_path):
    model = make(network)
    before = {k: v.clone() for k, v in model.state_dict().items()}
    curve = train(model, tiny_data(), LoopConfig(steps=2, batch_size=4, checkpoint_every=10), tmp_path / "c.pt",
                  progress=False)
    assert len(curve) == 2
    expected = {"step", "loss_d", "loss_g"} | ({"loss_l1"} if network == "cgan" else set())
    for row in curve:
        assert set(row) == expected and all(np.isfinite(v) for v in row.values())
    after = model.state_dict()
    for net in ("netG", "netD"):
        assert any(not torch.equal(before[k], after[k]) for k in after if k.startswith(net + ".")), net


@pytest.mark.parametrize("network", MODELS)
def test_resumed_training_equals_uninterrupted(network, tmp_path, train_stopped_after):
    data, loop = tiny_data(), LoopConfig(steps=4, batch_size=4, checkpoint_every=2)
    straight = make(network)
    train(straight, data, loop, tmp_path / "a.pt", progress=False)

    train_stopped_after(make(network), data, loop, tmp_path / "b.pt", steps_done=3)  # checkpoint of step 2
    torch.manual_seed(123)  # a fresh model with other initial weights: everything comes from the checkpoint
    resumed = MODELS[network][0](straight.config, straight.image_shape)
    curve = train(resumed, data, loop, tmp_path / "b.pt", progress=False)

    assert [row["step"] for row in curve] == [0, 1, 2, 3]
    a, b = straight.state_dict(), resumed.state_dict()
    assert a.keys() == b.keys()
    for k in a:
        assert torch.equal(a[k], b[k]), k


def test_a_run_resumed_with_fewer_steps_equals_a_clean_run(tmp_path, train_stopped_after):
    """Killed at step 4 of 6, `steps` lowered to 3, rerun: the model and the curve are those of a
    clean 3-step run (the step-4 checkpoint is not resumed)."""
    data = tiny_data()
    train_stopped_after(make("cgan"), data, LoopConfig(steps=6, batch_size=4, checkpoint_every=2), tmp_path / "k.pt",
                        steps_done=4)
    three = LoopConfig(steps=3, batch_size=4, checkpoint_every=2)
    rerun, clean = make("cgan"), make("cgan")
    curve = train(rerun, data, three, tmp_path / "k.pt", progress=False)
    clean_curve = train(clean, data, three, tmp_path / "clean.pt", progress=False)

    assert curve == clean_curve and [row["step"] for row in curve] == [0, 1, 2]
    for k, v in clean.state_dict().items():
        assert torch.equal(rerun.state_dict()[k], v), k


@pytest.mark.parametrize("changed", [{"features": 8}, {"lr": 1e-3}], ids=["architecture", "learning_rate"])
def test_a_checkpoint_of_another_configuration_is_not_resumed(changed, tmp_path):
    """A run stopped midway, its config edited, rerun: the new training starts afresh (not from the
    old weights, and not with a load error when the architecture changed)."""
    data, loop = tiny_data(), LoopConfig(steps=2, batch_size=4, checkpoint_every=1)
    train(make("gan"), data, loop, tmp_path / "stale.pt", progress=False)
    edited = make("gan", **changed)
    curve = train(edited, data, loop, tmp_path / "stale.pt", progress=False)
    fresh = make("gan", **changed)
    train(fresh, data, loop, tmp_path / "fresh.pt", progress=False)

    assert [row["step"] for row in curve] == [0, 1]
    for k, v in fresh.state_dict().items():
        assert torch.equal(edited.state_dict()[k], v), k


def test_cgan_prediction_is_deterministic_and_depends_on_the_condition(tmp_path):
    model = make("cgan")
    train(model, tiny_data(), LoopConfig(steps=3, batch_size=4), tmp_path / "c.pt", progress=False)
    az, el = torch.tensor([-80.0, 0.0, 80.0]), torch.tensor([10.0, 45.0, 85.0])
    with torch.no_grad():
        a = model.predict(az, el, torch.Generator().manual_seed(0))
        b = model.predict(az, el, torch.Generator().manual_seed(1))
    assert torch.equal(a, b)
    assert not torch.allclose(a[0], a[2])

    az = az.clone().requires_grad_(True)
    el = el.clone().requires_grad_(True)
    model.predict(az, el, None).sum().backward()
    assert az.grad.abs().sum() > 0 and el.grad.abs().sum() > 0


@pytest.mark.parametrize("network", MODELS)
def test_model_file_round_trip(network, tmp_path):
    model = make(network, **({"l1_weight": 5.0} if network == "cgan" else {}))
    train(model, tiny_data(), LoopConfig(steps=2, batch_size=4), tmp_path / "c.pt", progress=False)
    save_model(tmp_path / "m.pt", model, network, model.config, 2.5, {"steps": 2})
    loaded, info = load_model(tmp_path / "m.pt")
    assert type(loaded) is type(model) and loaded.config == model.config and info["scale"] == 2.5
    with torch.no_grad():
        a = model.predict(*positions(4), torch.Generator().manual_seed(7))
        b = loaded.predict(*positions(4), torch.Generator().manual_seed(7))
    assert torch.equal(a, b)
