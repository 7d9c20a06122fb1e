"""Field tracing: layouts, shading and blocking against hand-computed cases, attenuation against the
published Vittitoe-Biggs values, the power budget, and agreement with the single-heliostat tracer."""

import math
from dataclasses import fields, replace

import numpy as np
import pytest
import torch

from helioflow.errors import ConfigError, DataError
from helioflow.physics.effects import REGISTRY, check_effects, resolve, vittitoe_biggs
from helioflow.physics.field import BUDGET_TERMS, FieldHeliostats, field_flux, flat_receiver, orientations
from helioflow.physics.geometry import sun_vector
from helioflow.physics.heliostat import ideal_heliostat, orientation
from helioflow.physics.layout import (
    fermat_spiral,
    load_positions,
    min_spacing,
    nearest_distances,
    positions_from_list,
    radial_staggered,
)
from helioflow.physics.raytrace import Optics, trace
from helioflow.physics.sun import SunShape

DT = torch.float64
SQRT3 = math.sqrt(3.0)


def _sun(az_deg: float, el_deg: float) -> tuple[torch.Tensor, torch.Tensor]:
    return torch.tensor([math.radians(az_deg)], dtype=DT), torch.tensor([math.radians(el_deg)], dtype=DT)


# --- layouts --------------------------------------------------------------------------------------


@pytest.mark.parametrize("layout", [radial_staggered, fermat_spiral])
@pytest.mark.parametrize("n, sector_deg", [(1, 180.0), (37, 90.0), (400, 180.0), (300, 360.0)])
def test_layout_count_spacing_sector_and_radius(layout, n, sector_deg):
    spacing = min_spacing(3.2, 2.5, clearance=0.5)
    pos = layout(n, spacing, 25.0, sector_deg, height=2.0)
    assert pos.shape == (n, 3) and pos.dtype == DT
    if n > 1:
        assert nearest_distances(pos).min() >= spacing * (1 - 1e-12)
    radius = pos[:, :2].norm(dim=1)
    assert radius.min() >= 25.0 - 1e-9
    bearing = torch.atan2(pos[:, 0], pos[:, 1])  # from north towards east
    assert bearing.abs().max() <= math.radians(sector_deg) / 2 + 1e-9
    assert (pos[:, 2] == 2.0).all()


def test_layouts_are_dense():
    """The spiral's closest pair is exactly the spacing, and both layouts pack far better than a
    square grid of twice the spacing would (one heliostat per 4 spacing^2)."""
    spacing = 5.0
    for layout in (radial_staggered, fermat_spiral):
        pos = layout(500, spacing, 30.0)
        outer = pos[:, :2].norm(dim=1).max().item()
        area = math.pi * (outer**2 - 30.0**2) / 2
        assert area / 500 < 2.0 * spacing**2
    assert nearest_distances(fermat_spiral(500, spacing, 30.0)).min() == pytest.approx(spacing, rel=1e-8)


def test_min_spacing_is_the_diagonal_plus_clearance():
    assert min_spacing(3.0, 4.0) == 5.0 and min_spacing(3.0, 4.0, 0.5) == 5.5


def test_explicit_positions_from_a_list_and_a_csv(tmp_path):
    assert positions_from_list([[1, 2], [3, 4, 5]]).tolist() == [[1.0, 2.0, 0.0], [3.0, 4.0, 5.0]]
    path = tmp_path / "field.csv"
    path.write_text("east_m,north_m,up_m\n10.0,50.0,2.0\n-10.0,55.5,2.0\n")
    assert load_positions(path).tolist() == [[10.0, 50.0, 2.0], [-10.0, 55.5, 2.0]]
    path.write_text("10.0,50.0\n-10.0,oops\n")
    with pytest.raises(DataError, match="field.csv"):
        load_positions(path)
    with pytest.raises(DataError, match="missing.csv"):
        load_positions(tmp_path / "missing.csv")
    with pytest.raises(ConfigError, match="field.positions"):
        positions_from_list([[1.0, 2.0, 3.0, 4.0]])
    with pytest.raises(ConfigError, match="spacing"):
        radial_staggered(10, 0.0, 20.0)


# --- the batched field against the single-heliostat code ---------------------------------------------


def _errors(h, seed):
    g = torch.Generator().manual_seed(seed)
    return replace(h, canting_error=torch.randn(h.canting_error.shape, generator=g, dtype=DT) * 1e-3,
                   tracking_error=torch.randn(5, generator=g, dtype=DT) * 2e-3,
                   control_heights=torch.randn(h.control_heights.shape, generator=g, dtype=DT) * 5e-4)


def test_batched_orientation_equals_the_heliostat_kinematics():
    hs = [_errors(ideal_heliostat(2, 2, 1.0, 1.0, 0.02, position=(x, 40.0 + x, 1.0), mount=m), seed)
          for seed, (x, m) in enumerate([(-8.0, "az_el"), (0.0, "juelich"), (9.0, "az_el"),
                                         (3.0, "juelich")])]
    field = FieldHeliostats.stack(hs, 4)
    sun = sun_vector(*_sun(-35.0, 40.0))[0]
    aim = torch.tensor([0.0, 0.0, 30.0], dtype=DT)
    rot = orientations(field, sun, aim.expand(4, 3))
    for h, r in zip(hs, rot):
        assert torch.allclose(r, orientation(h, sun[None], aim)[0], atol=1e-14)


def _measured_heliostat(position):
    """2 x 2 curved canted facets focused at the slant range to (0, 0, 50), with canting, surface
    and tracking errors (the tracking error moves the spot ~0.5 m off the aim point at 60 m)."""
    distance = math.dist(position, (0.0, 0.0, 50.0))
    return _errors(ideal_heliostat(2, 2, 1.5, 1.2, 0.02, position=position, mount="juelich",
                                   canting_focal_distance=distance, facet_focal_length=distance), 3)


@pytest.mark.parametrize("sun", [SunShape("pillbox"), SunShape("buie", csr=0.1)])
@pytest.mark.parametrize("position, size", [((-30.0, 60.0, 2.0), 5.0), ((80.0, 300.0, 2.0), 8.0)])
def test_one_heliostat_agrees_with_the_kernel_tracer(sun, position, size):
    """The field tracer and raytrace.trace (kernel splatting) see the same physics: total power on the
    receiver, centroid and image agree. The near heliostat's spot is computed on the receiver's own
    pixels, the far one's on cells of 3 x 3 pixels (its spot, with the Buie aureole, spans the whole
    receiver and spills). The field tracer takes one footprint per heliostat, the kernel tracer adds
    its first-order change across the heliostat: where the spot spills, that changes the power on the
    receiver by up to 6e-4."""
    h = _measured_heliostat(position)
    receiver = flat_receiver([0.0, 0.0, 50.0], [0.0, 1.0, -0.5], size, size, (128, 128))
    optics = Optics(sun, slope_error=1e-3, dni=950.0, reflectivity=0.9)
    az, el = _sun(-30.0, 28.0)
    ref = trace(h, receiver, az, el, optics, rays=0, splat="kernel", cells_per_side=8)[0]
    result = field_flux(FieldHeliostats.stack([h], 8), receiver, az, el, optics)
    img = result.flux[0]
    power = img.sum().item() * receiver.pixel_area
    assert power == pytest.approx(ref.sum().item() * receiver.pixel_area, rel=2e-4 if size < 8 else 6e-4)
    assert power == pytest.approx(result.budget["on_receiver"].item(), rel=1e-12)
    shift = (receiver.centroid(img[None]) - receiver.centroid(ref[None])).norm().item()
    assert shift < 0.1 * receiver.pixel_size[0]
    psnr = 10 * math.log10(ref.max().item() ** 2 / ((img - ref) ** 2).mean().item())
    assert psnr > 45.0


def test_footprints_sampled_once_per_cell_where_smooth_give_the_supersampled_map(monkeypatch):
    """The far heliostats' footprints, smooth on the scale of their cells, are sampled once per cell
    (field.SMOOTH_CELLS); the map stays that of footprints supersampled everywhere to within 0.5 % of
    the peak at every pixel and 60 dB PSNR (measured: 0.26 %, 70 dB; the kernel tracer itself agrees
    with Monte Carlo to 45-56 dB), the budget to 1e-4 of the reflected power."""
    from helioflow.bench import field_scene
    from helioflow.physics import field as field_module

    field, receiver, physics, az, el = field_scene(1000)
    far = torch.arange(600, 1000, 3)  # every third of the outer rings, and a few nearer ones
    field = FieldHeliostats(*[value[far] if isinstance(value, torch.Tensor) else
                              None if value is None else tuple(value[i] for i in far)
                              for value in (getattr(field, f.name) for f in fields(field))])
    sampled = []
    footprint = field_module.footprint
    monkeypatch.setattr(field_module, "footprint", lambda *a: sampled.append(a[-1]) or footprint(*a))
    with torch.no_grad():
        smooth = field_flux(field, receiver, az, el, physics.optics)
        monkeypatch.setattr(field_module, "SMOOTH_CELLS", math.inf)
        every = field_flux(field, receiver, az, el, physics.optics)
    assert 1 in sampled and sampled.count(1) < len(sampled)  # both samplings were used
    peak = every.flux.max()
    assert (smooth.flux - every.flux).abs().max() < 5e-3 * peak
    psnr = 10 * math.log10(peak.item() ** 2 / ((smooth.flux - every.flux) ** 2).mean().item())
    assert psnr > 60.0
    for term in BUDGET_TERMS:
        # the spill is a difference of large terms: compared on the scale of the reflected power
        reflected = every.totals()["reflected"].item()
        assert smooth.totals()[term].item() == pytest.approx(every.totals()[term].item(), abs=1e-4 * reflected)


def test_spill_of_a_spot_on_the_receiver_edge_agrees_with_monte_carlo():
    """A spot half a metre off centre on a 3 m receiver spills 3.7 %; the power that stays agrees with
    2e6 bilinear Monte Carlo rays (noise ~1.3e-4 relative)."""
    h = _measured_heliostat((-30.0, 60.0, 2.0))
    receiver = flat_receiver([0.0, 0.0, 50.0], [0.0, 1.0, -0.5], 3.0, 3.0, (128, 128))
    optics = Optics(SunShape("pillbox"), slope_error=1e-3, dni=950.0, reflectivity=0.9)
    az, el = _sun(-30.0, 28.0)
    mc = trace(h, receiver, az, el, optics, rays=2_000_000, cells_per_side=32, seed=3)[0]
    budget = field_flux(FieldHeliostats.stack([h], 8), receiver, az, el, optics).budget
    assert 0.03 < budget["spilled"].item() / budget["reflected"].item() < 0.045
    assert budget["on_receiver"].item() == pytest.approx(mc.sum().item() * receiver.pixel_area, rel=5e-4)


def test_point_sun_without_slope_error_deposits_the_mirror_image():
    """A point sun and perfect mirrors: the spot is the mirror's image; power and centroid as the
    Monte Carlo tracer (4e6 rays)."""
    h = ideal_heliostat(1, 1, 2.0, 2.0, 0.0, position=(10.0, 60.0, 0.0))
    receiver = flat_receiver([0.0, 0.0, 20.0], [0.0, 1.0, -0.3], 6.0, 6.0, (64, 64))
    optics = Optics(SunShape("point"), dni=1000.0)
    az, el = _sun(20.0, 35.0)
    ref = trace(h, receiver, az, el, optics, rays=4_000_000, cells_per_side=32, seed=0)[0]
    img = field_flux(FieldHeliostats.stack([h], 32), receiver, az, el, optics).flux[0]
    assert img.sum().item() == pytest.approx(ref.sum().item(), rel=1e-9)
    assert (receiver.centroid(img[None]) - receiver.centroid(ref[None])).norm() < 1e-3


# --- shading and blocking: hand-computed cases ----------------------------------------------------------
#
# Sun due south at 60 deg elevation, s = (0, -1/2, sqrt3/2); every heliostat aims far north along
# a = (0, 1, 0) (its own aim point 10 km away at its own height). Its normal is the bisector
# n = (s + a)/|s + a| = (0, 1/2, sqrt3/2), the incidence 60 deg (s.n = a.n = 1/2); an az_el mount then
# turns the mirror's right axis to west and its up axis in the north-south plane, so a shift in
# that plane is a shift along the mirror's up axis (height h = 2 m; width 3 m).
#
# Shading: a neighbour d south of and dz above heliostat 1, rel = (0, -d, dz). Its shadow on
# heliostat 1's plane, cast along s, is the mirror shifted by q = rel - (rel.n / s.n) s, and
# rel.n / s.n = -d + sqrt3 dz gives q = (0, -3/2 d + sqrt3/2 dz, sqrt3/2 d - dz/2): |q| = |sqrt3 d - dz|,
# along the up axis. Shaded fraction 1 - |sqrt3 d - dz| / h = 1 - |2 sqrt3 - 2.5| / 2 = 0.51795 for
# d = 2, dz = 2.5.
#
# Blocking: a neighbour d north of and dz above, rel = (0, d, dz); heliostat 1's reflected rays
# (along a) hit its plane shifted by q = rel - (rel.n / a.n) a = (0, -sqrt3 dz, dz): |q| = 2 dz.
# Blocked fraction 1 - 2 dz / h = 0.6 for dz = 0.4, whatever d.

H = ideal_heliostat(1, 1, 3.0, 2.0, 0.0, mount="az_el")
AZ, EL = _sun(0.0, 60.0)
CELLS = 40  # the shadow edge is resolved to half a cell: 1 / 80 of the height


def _two(neighbour, **kwargs):
    positions = torch.tensor([[0.0, 0.0, 0.0], neighbour], dtype=DT)
    field = FieldHeliostats.stack([replace(H, position=p) for p in positions], CELLS)
    aims = positions + torch.tensor([0.0, 1e4, 0.0], dtype=DT)
    receiver = flat_receiver([0.0, 1e4, 1.0], [0.0, -1.0, 0.0], 60.0, 60.0, (32, 32))
    optics = Optics(SunShape("pillbox"), dni=1000.0, reflectivity=0.9)
    return field_flux(field, receiver, AZ, EL, optics, aim_points=aims, **kwargs).budget


def test_shading_by_a_higher_neighbour_to_the_south():
    budget = _two([0.0, -2.0, 2.5])
    expected = 1 - abs(2 * SQRT3 - 2.5) / 2
    assert expected == pytest.approx(0.51795, abs=1e-5)
    incident = budget["incident"][0]
    assert incident.tolist() == pytest.approx([3000.0, 3000.0], rel=1e-12)  # 1000 W/m^2 * 6 m^2 * cos 60 deg
    assert (budget["shaded"][0] / incident).tolist() == pytest.approx([expected, 0.0], abs=0.5 / CELLS)
    lit = (incident[0] - budget["shaded"][0, 0]).item()
    assert budget["reflected"][0, 0].item() == pytest.approx(0.9 * lit, rel=1e-12)
    assert budget["blocked"].abs().max() == 0.0


def test_blocking_by_a_higher_neighbour_to_the_north():
    budget = _two([0.0, 3.0, 0.4])
    reflected = budget["reflected"][0]
    assert (budget["blocked"][0] / reflected).tolist() == pytest.approx([0.6, 0.0], abs=0.5 / CELLS)
    assert budget["shaded"].abs().max() == 0.0


def test_blocking_shading_off_loses_nothing():
    budget = _two([0.0, -2.0, 2.5], blocking_shading=False)
    assert budget["shaded"].abs().max() == 0.0 and budget["blocked"].abs().max() == 0.0


def _random_field(n=40, seed=0):
    """A crowded random field 40-60 m from a low tower: 2 x 2 canted facets with errors, pivots
    >= 3.4 m apart."""
    g = torch.Generator().manual_seed(seed)
    pos = radial_staggered(n, min_spacing(2.0, 2.0, 0.5), 40.0, 60.0, 1.6)
    pos[:, :2] += torch.rand(n, 2, generator=g, dtype=DT) * 0.3
    template = ideal_heliostat(2, 2, 0.98, 0.98, 0.04, canting_focal_distance=40.0)
    return [_errors(replace(template, position=p), seed + i) for i, p in enumerate(pos)]


def _brute_force_losses(field, sun, aim):
    """Shaded and blocked power (W, (N,)) by testing every cell's two rays against every facet of
    every other heliostat, in plain numpy (dni 1000 W/m^2, reflectivity 1)."""
    rot = orientations(field, sun, aim).numpy()
    pos = field.position.numpy()
    points = pos[:, None] + np.einsum("nij,npj->npi", rot, field.points.numpy())  # (N, P, 3)
    normals = np.einsum("nij,npj->npi", rot, field.normals.numpy())
    s = sun.numpy()
    rays = -s + 2 * (normals @ s)[..., None] * normals
    centres = pos[:, None] + np.einsum("nij,nfj->nfi", rot, field.facet_centre.numpy())  # (N, F, 3)
    axes = np.einsum("nij,nfjk->nfik", rot, field.facet_axes.numpy())
    half = field.facet_half_size.numpy()
    power = 1000.0 * field.area.numpy() * np.clip(normals @ s, 0, None)
    shaded, blocked = np.zeros(len(pos)), np.zeros(len(pos))
    for h in range(len(pos)):
        lost = []
        for direction in (np.broadcast_to(s, points[h].shape), rays[h]):
            hit = np.zeros(len(points[h]), dtype=bool)
            for g in range(len(pos)):
                for f in range(centres.shape[1]):
                    right, up, normal = axes[g, f].T
                    denom = direction @ normal
                    with np.errstate(divide="ignore", invalid="ignore"):
                        t = ((centres[g, f] - points[h]) @ normal) / denom
                    at = points[h] + t[:, None] * direction - centres[g, f]
                    hit |= (g != h) & (t > 1e-9) & (np.abs(at @ right) <= half[g, f, 0]) & \
                        (np.abs(at @ up) <= half[g, f, 1])
            lost.append(hit)
        shaded[h] = power[h][lost[0]].sum()
        blocked[h] = power[h][~lost[0] & lost[1]].sum()
    return shaded, blocked


def test_shading_and_blocking_of_a_crowded_field_against_brute_force():
    """Low sun over a crowded field: the neighbour lists (8 per direction) lose exactly what testing
    every cell against every facet of every other heliostat loses."""
    field = FieldHeliostats.stack(_random_field(), 6)
    receiver = flat_receiver([0.0, 0.0, 10.0], [0.0, 1.0, -0.2], 8.0, 8.0, (32, 32))
    az, el = _sun(50.0, 12.0)
    optics = Optics(SunShape("pillbox"), slope_error=1e-3)
    budget = field_flux(field, receiver, az, el, optics, neighbours=8).budget
    shaded, blocked = _brute_force_losses(field, sun_vector(az, el)[0], receiver.center.expand(len(field), 3))
    assert budget["shaded"].sum() > 0.02 * budget["incident"].sum()  # the case is not empty
    assert budget["blocked"].sum() > 0.02 * budget["reflected"].sum()
    assert np.allclose(budget["shaded"][0].numpy(), shaded, rtol=1e-12, atol=1e-9)
    assert np.allclose(budget["blocked"][0].numpy(), blocked, rtol=1e-12, atol=1e-9)


# --- attenuation -------------------------------------------------------------------------------------


@pytest.mark.parametrize("hazy", [False, True])
def test_vittitoe_biggs_against_the_published_loss_polynomials(hazy):
    """Vittitoe & Biggs (1978) as tabulated in DELSOL (Kistler 1986) and SolarPILOT: attenuation loss in
    percent, R in km: clear day (23 km visibility) 0.6739 + 10.46 R - 1.7 R^2 + 0.2845 R^3, hazy day
    (5 km) 1.293 + 27.48 R - 3.394 R^2. At 1 km: 9.7184 % and 25.379 % (transmittance 0.902816 and
    0.74621)."""
    r_km = torch.tensor([0.1, 0.25, 0.5, 1.0, 1.5, 2.0], dtype=DT)
    loss = (1.293 + 27.48 * r_km - 3.394 * r_km**2) if hazy else \
        (0.6739 + 10.46 * r_km - 1.7 * r_km**2 + 0.2845 * r_km**3)
    tau = vittitoe_biggs(r_km * 1000.0, hazy=hazy)
    assert torch.allclose(tau, 1 - loss / 100, atol=2e-6)
    at_1km = vittitoe_biggs(torch.tensor(1000.0), hazy=hazy).item()
    assert at_1km == pytest.approx(0.74621 if hazy else 0.902816, abs=2e-6)
    # physically sensible over the fits' range (0-2 km): in (0, 1), decreasing, hazy below clear
    ranges = torch.linspace(0.0, 2000.0, 201, dtype=DT)
    tau = vittitoe_biggs(ranges, hazy=hazy)
    assert (tau > 0).all() and (tau < 1).all() and (tau.diff() < 0).all()
    assert (vittitoe_biggs(ranges[1:], hazy=True) < vittitoe_biggs(ranges[1:], hazy=False)).all()


@pytest.mark.parametrize("model", ["vittitoe_biggs_clear", "vittitoe_biggs_hazy", "constant"])
def test_attenuation_by_the_slant_range_of_each_heliostat(model):
    """Two heliostats 300 m and 1 km from their aim point lose (1 - transmittance(range)) of what
    they send."""
    effects = {"sunshape": {"kind": "pillbox"}, "attenuation": {"model": model, "transmittance": 0.8}}
    aim = torch.tensor([0.0, 0.0, 0.0], dtype=DT)
    hs = [ideal_heliostat(position=(0.0, r, 0.0)) for r in (300.0, 1000.0)]
    physics = resolve(effects, hs[0], dni=1000.0)
    receiver = flat_receiver(aim, [0.0, 1.0, 0.0], 40.0, 40.0, (32, 32))
    budget = field_flux(FieldHeliostats.stack(hs, 4), receiver, *_sun(0.0, 45.0), physics.optics,
                        blocking_shading=physics.blocking_shading).budget
    if model == "constant":
        tau = torch.tensor([0.8, 0.8], dtype=DT)
    else:
        tau = vittitoe_biggs(torch.tensor([300.0, 1000.0], dtype=DT), hazy=model.endswith("hazy"))
    sent = budget["reflected"][0] - budget["blocked"][0]
    assert torch.allclose(budget["attenuated"][0], sent * (1 - tau), rtol=1e-12)


# --- the power budget ------------------------------------------------------------------------------------


def test_power_budget_identity_on_a_random_field():
    """reflected = on_receiver + spilled + blocked + attenuated for every heliostat and sun position;
    the image integrates to on_receiver; each term is >= 0; totals are the sums; chunking changes nothing."""
    field = FieldHeliostats.stack(_random_field(30, seed=5), 6)
    receiver = flat_receiver([0.0, 0.0, 10.0], [0.0, 1.0, -0.2], 3.0, 3.0, (48, 48))  # small: it spills
    physics = resolve({"sunshape": {"kind": "buie", "csr": 0.1}, "slope_error": {"sigma_mrad": 1.0},
                       "reflectivity": {"value": 0.93}, "attenuation": {"model": "vittitoe_biggs_hazy"},
                       "blocking_shading": {}}, ideal_heliostat(), dni=900.0)
    assert physics.blocking_shading
    az = torch.tensor([-1.0, 0.2, 1.1], dtype=DT)
    el = torch.tensor([0.25, 0.9, 0.35], dtype=DT)
    result = field_flux(field, receiver, az, el, physics.optics, blocking_shading=True)
    b = result.budget
    assert set(b) == set(BUDGET_TERMS) and all(v.shape == (3, len(field)) for v in b.values())
    balance = b["on_receiver"] + b["spilled"] + b["blocked"] + b["attenuated"]
    assert torch.allclose(balance, b["reflected"], rtol=1e-12, atol=0)
    assert torch.allclose(b["reflected"], 0.93 * (b["incident"] - b["shaded"]), rtol=1e-12)
    for term in BUDGET_TERMS:
        assert (b[term] >= -1e-9 * b["incident"]).all(), term
    assert (b["shaded"].sum(-1)[[0, 2]] > 0).all() and (b["blocked"].sum(-1) > 0).all()  # low suns shade
    assert (b["spilled"].sum(-1) > 0.002 * b["reflected"].sum(-1)).all()  # the Buie aureole
    image_power = result.flux.sum((-2, -1)) * receiver.pixel_area
    assert torch.allclose(image_power, b["on_receiver"].sum(-1), rtol=1e-12)
    assert all(torch.equal(v, b[k].sum(-1)) for k, v in result.totals().items())
    chunked = field_flux(field, receiver, az, el, physics.optics, chunk=7)
    assert torch.allclose(chunked.flux, result.flux, rtol=1e-10, atol=1e-9)
    assert all(torch.allclose(chunked.budget[k], b[k], rtol=1e-10, atol=1e-9) for k in BUDGET_TERMS)


def test_single_spots_are_the_shares_of_the_map():
    """spots=[...] returns those heliostats' own spots (across chunks), each integrating to its
    on_receiver power; all of them sum to the map."""
    field = FieldHeliostats.stack(_random_field(20, seed=3), 6)
    receiver = flat_receiver([0.0, 0.0, 10.0], [0.0, 1.0, -0.2], 3.0, 3.0, (32, 32))
    physics = resolve({"sunshape": {"kind": "pillbox"}, "blocking_shading": {}}, ideal_heliostat(),
                      dni=1000.0)
    az, el = torch.tensor([0.3, -0.8], dtype=DT), torch.tensor([0.4, 0.7], dtype=DT)
    every = field_flux(field, receiver, az, el, physics.optics, spots=range(20), chunk=7)
    assert every.spots.shape == (2, 20, 32, 32)
    assert torch.allclose(every.spots.sum(1), every.flux, rtol=1e-10, atol=1e-9)
    on_receiver = every.spots.sum((-2, -1)) * receiver.pixel_area
    assert torch.allclose(on_receiver, every.budget["on_receiver"], rtol=1e-10)
    some = field_flux(field, receiver, az, el, physics.optics, spots=[15, 2], chunk=7)
    assert torch.equal(some.spots, every.spots[:, [15, 2]]) and torch.equal(some.flux, every.flux)
    assert field_flux(field, receiver, az, el, physics.optics).spots is None


def test_each_heliostat_with_its_own_slope_error_gets_the_spot_of_that_slope_error():
    """FieldHeliostats.slope_error: every heliostat's spot is the one the field traced with the optics'
    slope error set to its own (same blocking, shading and budget), whatever chunk it shares."""
    heliostats = _random_field(12, seed=4)
    own = [(0.5e-3, 2.5e-3, 1.0e-3)[i % 3] for i in range(12)]
    field = FieldHeliostats.stack(heliostats, 6, slope_error=own)
    receiver = flat_receiver([0.0, 0.0, 10.0], [0.0, 1.0, -0.2], 4.0, 4.0, (40, 40))
    physics = resolve({"sunshape": {"kind": "pillbox"}, "blocking_shading": {}}, ideal_heliostat(), dni=1000.0)
    az, el = torch.tensor([0.3], dtype=DT), torch.tensor([0.6], dtype=DT)
    mixed = field_flux(field, receiver, az, el, physics.optics, spots=range(12), chunk=5)
    for value in set(own):
        alike = field_flux(FieldHeliostats.stack(heliostats, 6), receiver, az, el,
                           replace(physics.optics, slope_error=value), spots=range(12), chunk=5)
        rows = [i for i, v in enumerate(own) if v == value]
        assert torch.allclose(mixed.spots[:, rows], alike.spots[:, rows], rtol=1e-9, atol=1e-9)
        for term in BUDGET_TERMS:
            assert torch.allclose(mixed.budget[term][:, rows], alike.budget[term][:, rows], rtol=1e-9, atol=1e-9)
    with pytest.raises(ValueError, match="2 slope errors for 12 heliostats"):
        FieldHeliostats.stack(heliostats, 6, slope_error=[1e-3, 2e-3])


def test_nothing_spills_from_a_receiver_that_holds_every_spot():
    """A pillbox sun's footprint ends at the disc plus 8 sigma of the slope blur: a large receiver
    catches all of it."""
    field = FieldHeliostats.stack(_random_field(10, seed=2), 6)
    receiver = flat_receiver([0.0, 0.0, 10.0], [0.0, 1.0, -0.2], 12.0, 12.0, (64, 64))
    b = field_flux(field, receiver, *_sun(10.0, 50.0), Optics(SunShape("pillbox"), slope_error=1e-3)).budget
    assert (b["spilled"].abs() < 1e-9 * b["reflected"]).all()


# --- the effect ------------------------------------------------------------------------------------------


def test_blocking_shading_is_a_registry_effect_for_world_and_model():
    assert REGISTRY["blocking_shading"].acts_on == "rays lost on the way in or out"
    check_effects({"blocking_shading": {}}, "world.effects", allow_fit=False)
    check_effects({"blocking_shading": None}, "model.effects", allow_fit=True)
    with pytest.raises(ConfigError, match="model.effects.blocking_shading: unknown parameter 'radius'"):
        check_effects({"blocking_shading": {"radius": 3}}, "model.effects", allow_fit=True)
    assert not resolve({}, ideal_heliostat(), dni=1000.0).blocking_shading


def test_bad_field_inputs_raise_clear_errors():
    with pytest.raises(ValueError, match="share the facet layout"):
        FieldHeliostats.stack([ideal_heliostat(1, 1), ideal_heliostat(2, 2)])
    field = FieldHeliostats.stack([ideal_heliostat(position=(0.0, 50.0, 0.0))], 4)
    receiver = flat_receiver([0.0, 0.0, 20.0], [0.0, 1.0, 0.0], 4.0, 4.0, (16, 16))
    with pytest.raises(ValueError, match="below the horizon"):
        field_flux(field, receiver, *_sun(0.0, -5.0), Optics(SunShape("pillbox")))


def _all_pairs_candidates(origin, direction, radius, widening, k):
    """_candidates' rule applied to every pair (the reference for its k-d tree search)."""
    rel = origin[None, :, :] - origin[:, None, :]  # (N, N, 3)
    along = (rel * direction[:, None, :]).sum(-1)
    perp2 = (rel * rel).sum(-1) - along**2
    reach = radius[:, None] + radius[None, :]
    ok = (along > -reach) & (perp2 < (reach + along.clamp_min(0) * widening[:, None]) ** 2)
    ok.fill_diagonal_(False)
    values, index = torch.topk(torch.where(ok, along, torch.full_like(along, math.inf)), k, dim=1, largest=False)
    return index, torch.isfinite(values)


@pytest.mark.parametrize("elevation_deg", [2.0, 12.0, 45.0])
def test_neighbour_candidates_from_the_k_d_tree_are_those_of_every_pair(elevation_deg):
    """The k-d tree search (_candidates) finds exactly the neighbours the rule finds among all pairs:
    shading towards a low or high sun, blocking towards a receiver with a widening beam, uneven
    pivot heights."""
    from helioflow.physics.field import _candidates

    g = torch.Generator().manual_seed(int(elevation_deg))
    n = 600
    origin = torch.cat((torch.rand(n, 2, generator=g, dtype=DT) * 120 - 60,
                        torch.rand(n, 1, generator=g, dtype=DT) * 3), -1)
    radius = 1.2 + 0.3 * torch.rand(n, generator=g, dtype=DT)
    sun = sun_vector(torch.tensor(0.7, dtype=DT), torch.tensor(math.radians(elevation_deg), dtype=DT))
    aim = torch.tensor([0.0, -80.0, 30.0], dtype=DT)
    cases = [(sun.expand(n, 3), torch.zeros(n, dtype=DT)),
             ((aim - origin) / (aim - origin).norm(dim=-1, keepdim=True), 4.0 / (aim - origin).norm(dim=-1))]
    for direction, widening in cases:
        index, valid = _candidates(origin, direction, radius, widening, 8)
        ref_index, ref_valid = _all_pairs_candidates(origin, direction, radius, widening, 8)
        assert torch.equal(valid, ref_valid)
        assert torch.equal(torch.where(valid, index, -1), torch.where(ref_valid, ref_index, -1))
        assert valid.any()
