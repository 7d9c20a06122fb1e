"""The spot NeRF: rendering, training through the shared loop, resuming, the static-scene geometry
(against the reflection law and the tracer), model files."""

import math

import pytest
import torch

from helioflow.errors import ConfigError
from helioflow.models.base import TrainingData, sun_features
from helioflow.models.nerf import (
    NerfConfig,
    SpotNeRF,
    beam_direction,
    camera_direction,
    focusing_map,
    heliostat_rotation,
    mirror_normal,
)
from helioflow.models.registry import dataset_geometry, load_model, save_model
from helioflow.models.training import LoopConfig, train
from helioflow.physics.geometry import normalize, reflect, rotation_about_axis
from helioflow.physics.heliostat import ideal_heliostat
from helioflow.physics.raytrace import Optics, trace
from helioflow.physics.sun import SunShape
from helioflow.physics.target import Target

TINY = NerfConfig(frequencies=3, view_frequencies=1, width=16, depth=2, samples=4, rays=64, chunk=100)
SHAPE = (16, 16)
DEFAULT = NerfConfig()


def tiny_data(n: int = 6) -> TrainingData:
    """n Gaussian spots on 16x16 images that drift and shrink with the sun elevation."""
    az = torch.linspace(-40.0, 40.0, n)
    el = torch.linspace(20.0, 70.0, n)
    rows, cols = torch.meshgrid(torch.arange(16.0), torch.arange(16.0), indexing="ij")
    centre = 7.5 + 2 * torch.sin(torch.deg2rad(az))[:, None, None]
    width = 2.0 + torch.cos(torch.deg2rad(el))[:, None, None]
    images = torch.exp(-((rows - centre) ** 2 + (cols - 7.5) ** 2) / (2 * width**2))
    return TrainingData(images / images.max(), az, el, 1234.0)


def angle(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    return torch.acos((normalize(a) * normalize(b)).sum(-1).clamp(-1.0, 1.0))


@pytest.mark.parametrize("condition, emission", [(True, True), (False, False)])
def test_predict_gives_non_negative_images_of_the_right_shape_in_any_chunking(condition, emission):
    torch.manual_seed(0)
    config = NerfConfig(**{**TINY.__dict__, "condition": condition, "emission": emission})
    model = SpotNeRF(config, SHAPE)
    az, el = torch.tensor([10.0, -60.0, 120.0]), torch.tensor([5.0, 45.0, 80.0])
    images = model.predict(az, el, torch.Generator().manual_seed(0))
    assert images.shape == (3, *SHAPE)
    assert torch.isfinite(images).all() and (images >= 0).all() and images.max() > 0
    whole = SpotNeRF(NerfConfig(**{**config.__dict__, "chunk": 10_000}), SHAPE)
    whole.load_state_dict(model.state_dict())
    torch.testing.assert_close(whole.predict(az, el, None), images)


def test_two_training_steps_through_the_shared_loop(tmp_path):
    torch.manual_seed(0)
    model = SpotNeRF(TINY, SHAPE)
    before = [p.detach().clone() for p in model.parameters()]
    loop = LoopConfig(steps=2, batch_size=3, checkpoint_every=1)
    curve = train(model, tiny_data(), loop, tmp_path / "ckpt", progress=False)
    assert [row["step"] for row in curve] == [0, 1]
    assert all(math.isfinite(row["loss"]) and row["loss"] > 0 for row in curve)
    assert all(not torch.equal(a, b) for a, b in zip(before, model.parameters()))
    assert int(model.steps_done) == 2 and (tmp_path / "ckpt").exists()


def test_resumed_training_equals_uninterrupted_training(tmp_path, train_stopped_after):
    data = tiny_data()
    torch.manual_seed(0)
    straight = SpotNeRF(TINY, SHAPE)
    four = LoopConfig(steps=4, batch_size=3, checkpoint_every=2)
    train(straight, data, four, tmp_path / "a.ckpt", progress=False)

    torch.manual_seed(0)
    train_stopped_after(SpotNeRF(TINY, SHAPE), data, four, tmp_path / "b.ckpt", steps_done=3)  # checkpoint of step 2
    torch.manual_seed(1)  # the resumed model's own initialisation must not matter
    resumed = SpotNeRF(TINY, SHAPE)
    curve = train(resumed, data, four, tmp_path / "b.ckpt", progress=False)

    assert [row["step"] for row in curve] == [0, 1, 2, 3]
    for (name, a), (_, b) in zip(straight.state_dict().items(), resumed.state_dict().items()):
        assert torch.equal(a, b), name


def test_the_mirror_normal_turns_by_half_the_sun_angle():
    beam = beam_direction(torch.tensor(DEFAULT.heliostat_position_m, dtype=torch.float64),
                          torch.tensor(DEFAULT.aim_point_m, dtype=torch.float64))
    axis = normalize(torch.linalg.cross(beam, torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)))
    # suns on a great circle through the beam direction, 30..150 deg away from it
    phi = torch.deg2rad(torch.tensor([30.0, 47.0, 90.0, 150.0], dtype=torch.float64))
    suns = rotation_about_axis(axis, phi) @ beam
    normals = mirror_normal(suns, beam)
    for i in range(len(phi) - 1):
        torch.testing.assert_close(angle(normals[i], normals[i + 1]), angle(suns[i], suns[i + 1]) / 2)
    # and the heliostat's rotation puts its mirror normal (third column) exactly there
    sun = sun_features(torch.tensor([10.0, -75.0, 110.0]), torch.tensor([5.0, 40.0, 85.0])).double()
    rotation = heliostat_rotation("az_el", sun, beam)
    eye = torch.eye(3, dtype=torch.float64).expand(3, 3, 3)
    torch.testing.assert_close(rotation.transpose(1, 2) @ rotation, eye)
    torch.testing.assert_close(rotation[:, :, 2], mirror_normal(sun, beam))


@pytest.mark.parametrize("mount", ["az_el", "juelich"])
def test_the_camera_sits_at_the_mirror_image_of_the_sun(mount):
    """For sun position p the camera looks from d = R(p)^T b on the virtual sphere; d makes the angle
    of incidence with the mirror normal and is the sun direction in the heliostat frame mirrored in
    the normal."""
    beam = beam_direction(torch.tensor([0.0, 60.0, 0.0], dtype=torch.float64),
                          torch.tensor([0.0, 0.0, 20.0], dtype=torch.float64))
    az, el = torch.tensor([10.0, -75.0, 110.0, 0.0]), torch.tensor([5.0, 40.0, 85.0, 18.43])
    sun = sun_features(az, el).double()
    rotation = heliostat_rotation(mount, sun, beam)
    d = camera_direction(rotation, beam)
    z = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)
    sun_h = (sun[:, None, :] @ rotation)[:, 0]
    torch.testing.assert_close(d, (rotation.transpose(1, 2) @ beam[:, None])[..., 0])
    torch.testing.assert_close(d[:, 2], torch.cos(angle(sun, beam) / 2))  # cos(incidence)
    torch.testing.assert_close(sun_h, 2 * d[:, 2:3] * z - d)
    torch.testing.assert_close(reflect(-sun_h, z), d)  # the reflected central ray runs along the view
    # the sun straight behind the target (azimuth 0, elevation = the beam's) gives normal incidence
    torch.testing.assert_close(d[3], z, atol=1e-4, rtol=0)


def test_camera_rays_meet_the_mirror_where_the_tracer_puts_the_spot():
    """An ideal flat 2 m x 2 m mirror and a point sun: the pixels whose backward ray hits the
    mirror (z = 0, |x|, |y| < 1 m in the heliostat frame) are the traced spot."""
    window = 3.79
    heliostat = ideal_heliostat(1, 1, 2.0, 2.0, 0.0, (0.0, 60.0, 0.0), "az_el", None, None, 4, torch.float32)
    target = Target(torch.tensor([0.0, 0.0, 20.0]), torch.tensor([0.0, 1.0, 0.0]), window, window, (32, 32))
    az, el = torch.tensor([10.0, 60.0, -70.0]), torch.tensor([30.0, 20.0, 50.0])
    optics = Optics(sun=SunShape(kind="point"))
    traced = trace(heliostat, target, torch.deg2rad(az), torch.deg2rad(el), optics, rays=300_000,
                   splat="bilinear", cells_per_side=48)
    model = SpotNeRF(DEFAULT, (32, 32))
    views = model.views(az, el)
    for i in range(len(az)):
        origin = (model.ray_offsets * window) @ views["rotation"][i]
        d = views["direction"][i]
        hit = origin - (origin[:, 2:3] / d[2]) * d
        seen = ((hit[:, 0].abs() < 1) & (hit[:, 1].abs() < 1)).reshape(32, 32)
        spot = traced[i] > 0.5 * traced[i].max()
        assert seen.sum() > 100
        assert (seen != spot).sum() <= 0.05 * seen.sum(), (az[i], el[i])


def test_the_focusing_map_follows_the_reflection_law():
    """A normal tilted by e sends the central ray to the mirror-plane point r + A(d) 2 L e (first
    order), and for on-axis canting at f the ray arriving at m comes from r = M m."""
    torch.manual_seed(0)
    z = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)
    d = normalize(torch.tensor([[0.3, -0.5, 0.8], [-0.6, 0.1, 0.55], [0.0, 0.0, 1.0]], dtype=torch.float64))
    sun_h = 2 * d[:, 2:3] * z - d
    distance, focal = 63.0, 200.0

    def landing(r: torch.Tensor, normal: torch.Tensor) -> torch.Tensor:
        """Where the ray reflected at mirror point r reaches the plane perpendicular to d at the
        slant range, traced back along d onto the mirror plane (xy)."""
        out = reflect(-sun_h, normal)
        p = r + distance * out / (out * d).sum(-1, keepdim=True)
        p = p - distance * d
        return (p - (p[:, 2:3] / d[:, 2:3]) * d)[:, :2]

    k = distance / focal
    a = focusing_map(d, 0.0)[0]  # identity for a flat mirror
    torch.testing.assert_close(a, torch.eye(2, dtype=torch.float64).expand(3, 2, 2))
    eye = torch.eye(2, dtype=torch.float64)
    big_a = d[:, 2:3, None] * eye + d[:, :2, None] * d[:, None, :2] / d[:, 2:3, None]
    tilt = 1e-6 * torch.randn(3, 2, dtype=torch.float64)
    tilted = normalize(z + torch.cat((tilt, torch.zeros(3, 1)), -1))
    shift = landing(torch.zeros(3, 3, dtype=torch.float64), tilted)
    expected = (big_a @ (2 * distance * tilt)[..., None])[..., 0]
    torch.testing.assert_close(shift, expected, rtol=1e-4, atol=1e-12)

    r = torch.tensor([[0.4, -0.3, 0.0], [-0.2, 0.25, 0.0], [0.1, 0.1, 0.0]], dtype=torch.float64)
    canted = normalize(z - torch.cat((r[:, :2] / (2 * focal), torch.zeros(3, 1)), -1))
    m = landing(r, canted)
    warp, gain = focusing_map(d, k)
    torch.testing.assert_close((warp @ m[..., None])[..., 0], r[:, :2], atol=2e-4, rtol=0)
    assert (gain > 1).all()  # a focusing heliostat concentrates the flux


def test_save_and_load_give_identical_predictions(tmp_path):
    torch.manual_seed(0)
    config = NerfConfig(**{**TINY.__dict__, "canting_focal_distance_m": 200.0})
    model = SpotNeRF(config, SHAPE)
    train(model, tiny_data(), LoopConfig(steps=2, batch_size=3), tmp_path / "ckpt", progress=False)
    save_model(tmp_path / "nerf.pt", model, "nerf", config, 1234.0, {"dataset": "tiny"})
    loaded, info = load_model(tmp_path / "nerf.pt")
    assert isinstance(loaded, SpotNeRF) and info["scale"] == 1234.0 and loaded.config == config
    az, el = torch.tensor([0.0, 45.0]), torch.tensor([30.0, 60.0])
    assert torch.equal(loaded.predict(az, el, None), model.eval().predict(az, el, None))


@pytest.mark.parametrize("key, value", [("samples", 0), ("slab", 0.0), ("mount", "tripod"),
                                        ("target_normal", (0.0, 1.0)), ("canting_focal_distance_m", -5.0)])
def test_bad_settings_are_config_errors(key, value):
    with pytest.raises(ConfigError, match=key):
        NerfConfig(**{key: value})


def test_the_nerf_takes_mount_and_canting_distance_from_the_dataset():
    attrs = {"heliostat_position_m": [1.0, 50.0, 0.0], "target_center_m": [0.0, 0.0, 20.0],
             "target_normal": [0.0, 1.0, 0.0], "heliostat_mount": "juelich", "canting_focal_distance_m": 200.0}
    geometry = dataset_geometry("nerf", attrs)
    assert geometry == {"heliostat_position_m": (1.0, 50.0, 0.0), "aim_point_m": (0.0, 0.0, 20.0),
                        "target_normal": (0.0, 1.0, 0.0), "mount": "juelich", "canting_focal_distance_m": 200.0}
    assert NerfConfig(**geometry).canting_focal_distance_m == 200.0
