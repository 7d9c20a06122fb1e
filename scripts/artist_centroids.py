"""Focal-spot centroids of the ideal heliostat AA39 on the Jülich target, computed with ARTIST 2.0.

Cross-check (not part of CI) for helioflow: the PAINT authors' raytracer ARTIST aligns and traces the
IDEAL heliostat AA39 (``extract_paint_heliostats_ideal_surface``) onto ``solar_tower_juelich_upper``
for eight sun positions, with its default sun (normal, mean 0, covariance 4.3681e-06), equal power
per ray, weighted by -cos of the ray's incidence on ARTIST's target plane (through the tower file's
``center``, normal +north). Hits are computed here in float64 from ARTIST's rays. Table columns:

(a) ARTIST's centroid, aim point = the tower file's ``center``;
(b) ARTIST's centroid, aim point = the mean of the four corners (~1.3 mm south of ARTIST's plane);
(c) the rays of (a) as helioflow traces them: power ~ cos of the sun's incidence on the mirror
    element (helioflow's extra area factor moves nothing by > 0.01 mm on ARTIST's even grid), no
    target cosine, the corners' plane (helioflow's ``plane_from_corners``), no sun spread;
(d), (e) the central ray (concentrator origin and normal) on ARTIST's plane, aims of (a) and (b).

The mean of (a) - (c) is then split into steps that change one thing each. Steps with sun spread use
antithetic pairs (each of ARTIST's sun deviations and its negative); the first step is the Monte
Carlo noise that (a) and (b) keep: ARTIST reuses one set of deviations (seed 7) for every image,
which moves all its centroids alike by ~0.1 mm (right) and ~0.3 mm (up).

Finding: (c) reproduces helioflow's centroids within 0.13 mm. (a) lies on average ~(+0.75, +2.2) mm
from (c): ARTIST's target cosine ~(+1.0, +3.2), partly undone by its plane ~(-0.6, -1.9), the sun
spread's second-order shift of the mean hit on the oblique plane ~(+0.2, +0.7), which helioflow's
kernel trace leaves out, ARTIST's Monte Carlo noise ~(+0.1, +0.2) and its equal ray power (+0.07 mm
right on average, up to 0.3 mm in one image). On the target cosine helioflow is right: a ray's power
is set at the mirror, and hitting an oblique target already spreads the hits by 1/cos, so an extra
cos counts the obliquity twice.

Frame, in mm: origin = mean of the corners, right = west (-east), up = up (within 1 um of the
corners' plane's own axes). ENU: ARTIST's WGS84 -> ENU relative to the power plant; an exact
WGS84 -> ECEF -> ENU conversion is printed for comparison.

Install (CPU-only torch; an unpinned torch pulls a multi-GB CUDA build)::

    python -m venv /tmp/artist-venv
    /tmp/artist-venv/bin/pip install torch==2.13.0 artist-csp==2.0.0

(If the torchvision that comes with it is a CUDA build that cannot load next to a CPU-only torch,
the script replaces it by an empty module: ARTIST needs torchvision only for reading PNGs.)

Run (from the repository root; the PAINT directory is optional)::

    /tmp/artist-venv/bin/python scripts/artist_centroids.py [tests/data/paint]
"""

import dataclasses
import json
import pathlib
import sys
import tempfile
import time
import types

import h5py
import numpy as np
import torch


def _stub_broken_torchvision() -> None:
    """Replace a torchvision that cannot load (CUDA build next to a CPU torch) by an empty module.

    ARTIST imports torchvision only to decode calibration PNGs (``artist.io.calibration_parser``),
    which this script does not use.
    """
    try:
        import torchvision  # noqa: F401
    except (ImportError, OSError, RuntimeError):
        for name in [m for m in sys.modules if m == "torchvision" or m.startswith("torchvision.")]:
            del sys.modules[name]
        sys.modules["torchvision"] = types.ModuleType("torchvision")


_stub_broken_torchvision()

from artist.geometry import coordinates  # noqa: E402
from artist.io import paint_scenario_parser  # noqa: E402
from artist.raytracing import HeliostatRayTracer, reflect  # noqa: E402
from artist.scenario import H5ScenarioGenerator, Scenario  # noqa: E402
from artist.util import constants  # noqa: E402
from artist.util.config import LightSourceConfig, LightSourceListConfig  # noqa: E402

HELIOSTAT = "AA39"
TARGET = "solar_tower_juelich_upper"
CORNERS = ("upper_left", "upper_right", "lower_left", "lower_right")
SUN_POSITIONS = [  # (azimuth, elevation) in degrees, 0 = south, +90 = east
    (-59.43, 57.67), (-0.12, 42.98), (16.24, 31.60), (-75.41, 38.01),
    (-56.33, 44.83), (68.51, 27.39), (-68.73, 21.21), (-59.24, 50.46),
]
RAYS_PER_POINT = 100  # x 4 facets x 50 x 50 surface points = 1e6 rays per image
DEVICE = torch.device("cpu")
EFFECTS = (  # between consecutive entries of ``helioflow_chain``
    "Monte Carlo noise (ARTIST's own sun samples - antithetic pairs)",
    "target cosine (ray weight -cos of the incidence on the target - equal weights)",
    "mirror cosine (equal ray power - power ~ cos of the sun's incidence on the mirror element)",
    "plane (ARTIST's: through `center`, normal +north - the corners' plane)",
    "sun spread (ARTIST's sun - none: unscattered reflected rays)",
)


def wgs84_to_enu_exact(lla: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """Convert ``[n, 3]`` (lat, lon, alt) to ENU metres around ``ref`` via ECEF (float64)."""
    a, e2 = 6378137.0, 6.69437999014e-3

    def ecef(p: np.ndarray) -> np.ndarray:
        lat, lon, h = np.radians(p[..., 0]), np.radians(p[..., 1]), p[..., 2]
        n = a / np.sqrt(1.0 - e2 * np.sin(lat) ** 2)
        return np.stack([(n + h) * np.cos(lat) * np.cos(lon),
                         (n + h) * np.cos(lat) * np.sin(lon),
                         (n * (1.0 - e2) + h) * np.sin(lat)], axis=-1)

    lat0, lon0 = np.radians(ref[0]), np.radians(ref[1])
    rot = np.array([
        [-np.sin(lon0), np.cos(lon0), 0.0],
        [-np.sin(lat0) * np.cos(lon0), -np.sin(lat0) * np.sin(lon0), np.cos(lat0)],
        [np.cos(lat0) * np.cos(lon0), np.cos(lat0) * np.sin(lon0), np.sin(lat0)],
    ])
    return (ecef(lla) - ecef(ref)) @ rot.T


def wgs84_to_enu_artist(lla: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """ARTIST's own WGS84 -> ENU conversion (inputs float64; ARTIST returns float32)."""
    enu = coordinates.convert_wgs84_coordinates_to_local_enu(
        torch.tensor(lla, dtype=torch.float64), torch.tensor(ref, dtype=torch.float64), device=DEVICE
    )
    return enu.double().numpy()


def build_scenario(paint_dir: pathlib.Path, workdir: pathlib.Path) -> Scenario:
    """Write an ARTIST scenario (tower + ideal AA39 + default sun) to HDF5 and load it."""
    power_plant, planar, cylindrical = paint_scenario_parser.extract_paint_tower_measurements(
        tower_measurements_path=paint_dir / "tower-measurements.json", device=DEVICE
    )
    sun = LightSourceConfig(
        light_source_key="sun", light_source_type=constants.sun_key, number_of_rays=RAYS_PER_POINT,
        distribution_type=constants.light_source_distribution_is_normal, mean=0.0, covariance=4.3681e-06,
    )
    heliostats, prototype = paint_scenario_parser.extract_paint_heliostats_ideal_surface(
        paths=[(HELIOSTAT, paint_dir / HELIOSTAT / "heliostat-properties.json")],
        power_plant_position=power_plant.power_plant_position, device=DEVICE,
    )
    path = workdir / "scenario.h5"
    H5ScenarioGenerator(
        file_path=path, power_plant_config=power_plant, target_area_list_planar_config=planar,
        target_area_list_cylindrical_config=cylindrical,
        light_source_list_config=LightSourceListConfig(light_source_list=[sun]),
        heliostat_list_config=heliostats, prototype_config=prototype,
    ).generate_scenario()
    with h5py.File(path) as f:
        return Scenario.load_scenario_from_hdf5(scenario_file=f, device=DEVICE)


Plane = tuple[np.ndarray, np.ndarray]  # (point on the plane, unit normal), ENU


@dataclasses.dataclass
class Image:
    """One aligned heliostat's rays (ENU, float64).

    ``dirs[0]``: ARTIST's own sun samples [rays, points, 3]; ``dirs[1]`` (if traced): their antithetic
    pairs; ``preferred``: unscattered directions; ``cos_sun``: cosine of the sun's incidence on each
    surface point; ``central``: origin and direction of the central ray.
    """

    origins: np.ndarray
    dirs: np.ndarray
    preferred: np.ndarray
    cos_sun: np.ndarray
    central: tuple[np.ndarray, np.ndarray]


def corners_plane(corners: np.ndarray) -> Plane:
    """helioflow's ``plane_from_corners`` for ENU corners in ``CORNERS`` order.

    right = mean of the upper and lower edges (left -> right), up = mean of the side edges
    (lower -> upper), normal = right x up with its sign towards +north, through the corners' mean.
    """
    upper_left, upper_right, lower_left, lower_right = corners
    right = upper_right - upper_left + lower_right - lower_left
    normal = np.cross(right, upper_left - lower_left + upper_right - lower_right)
    return corners.mean(axis=0), normal * np.sign(normal[1]) / np.linalg.norm(normal)


def plane_hits(origins: np.ndarray, dirs: np.ndarray, center: np.ndarray, normal: np.ndarray):
    """Intersect rays with the plane (center, normal) in float64; return hits and Lambert weights."""
    cos = dirs @ normal
    t = ((center - origins) @ normal) / np.where(cos < 0.0, cos, -1.0)
    hits = origins + t[..., None] * dirs
    return hits, np.where(cos < 0.0, -cos, 0.0)


def centroid(hits: np.ndarray, weights) -> np.ndarray:
    """Weighted mean of ``hits`` [..., 3]; ``weights`` broadcasts to ``hits.shape[:-1]``."""
    w = np.broadcast_to(weights, hits.shape[:-1])
    return (hits * w[..., None]).reshape(-1, 3).sum(axis=0) / w.sum()


def trace(scenario: Scenario, aim: np.ndarray, azimuth: float, elevation: float, antithetic: bool) -> Image:
    """Align AA39 on ``aim`` for one sun position and scatter its rays with ARTIST.

    With ``antithetic``, the rays are scattered a second time with ARTIST's sun deviations negated.
    """
    group = scenario.heliostat_field.heliostat_groups[0]
    mask = torch.ones(1, dtype=torch.int32, device=DEVICE)
    group.activate_heliostats(active_heliostats_mask=mask, device=DEVICE)
    sun_enu = coordinates.azimuth_elevation_to_enu(
        torch.tensor([azimuth]), torch.tensor([elevation]), degree=True, device=DEVICE
    )
    incident = coordinates.convert_3d_directions_to_4d_format(-sun_enu, device=DEVICE)
    aim_4d = torch.tensor([[*aim, 1.0]], dtype=torch.float32)
    # Central ray: same (deterministic) inverse kinematics as used by the alignment below.
    orientation = group.kinematics.incident_ray_directions_to_orientations(
        incident_ray_directions=incident, aim_points=aim_4d, device=DEVICE
    )[0].double()
    group.align_surfaces_with_incident_ray_directions(
        aim_points=aim_4d, incident_ray_directions=incident, active_heliostats_mask=mask, device=DEVICE
    )
    tracer = HeliostatRayTracer(scenario=scenario, heliostat_group=group, blocking_active=False)
    preferred = reflect(incident[:, None, :], group.active_surface_normals)
    sun_samples = tracer.distortions_dataset
    dirs = np.stack([tracer.scatter_rays(
        distortion_u=sign * sun_samples.distortions_u, distortion_e=sign * sun_samples.distortions_e,
        original_ray_direction=preferred, device=DEVICE,
    ).ray_directions[0, ..., :3].double().numpy() for sign in ((1.0, -1.0) if antithetic else (1.0,))])
    sun, normals = incident[0, :3].double(), group.active_surface_normals[0, :, :3].double()
    return Image(
        origins=group.active_surface_points[0, None, :, :3].double().numpy(), dirs=dirs,
        preferred=preferred[0, :, :3].double().numpy(), cos_sun=-(normals @ sun).numpy(),
        central=(orientation[:3, 3].numpy(), reflect(sun, orientation[:3, 2]).numpy()),  # +u = normal
    )


def artist_centroid(image: Image, plane: Plane) -> np.ndarray:
    """ARTIST's centroid: its own sun samples, weighted by -cos of the incidence on ``plane``."""
    return centroid(*plane_hits(image.origins, image.dirs[0], *plane))


def helioflow_chain(image: Image, artist_plane: Plane, hf_plane: Plane) -> list[np.ndarray]:
    """Centroids from ARTIST's (column a) to helioflow's tracing (column c), one ``EFFECTS`` step apart."""
    hits, cos_target = plane_hits(image.origins, image.dirs, *artist_plane)
    hf_hits, _ = plane_hits(image.origins, image.dirs, *hf_plane)
    unscattered, _ = plane_hits(image.origins[0], image.preferred, *hf_plane)
    return [artist_centroid(image, artist_plane), centroid(hits, cos_target), centroid(hits, 1.0),
            centroid(hits, image.cos_sun), centroid(hf_hits, image.cos_sun),
            centroid(unscattered, image.cos_sun)]


def to_frame(p: np.ndarray, origin: np.ndarray) -> tuple[float, float]:
    """ENU point -> (right = -east, up) in mm relative to ``origin``."""
    return -(p[0] - origin[0]) * 1e3, (p[2] - origin[2]) * 1e3


def print_centroids(scenario: Scenario, artist_plane: Plane, corners: np.ndarray) -> None:
    """Trace every sun position for both aim points; print columns (a)-(e) and the decomposition."""
    origin = corners.mean(axis=0)
    print("| sun az/el (deg) | (a) ARTIST aim at center (mm right, up) | (b) ARTIST aim at mean of corners "
          "| (c) ARTIST's rays as helioflow traces them: no target cosine, the corners' plane, no sun spread "
          "| (d) central ray, aim at center | (e) central ray, aim at mean of corners |")
    print("|---|---|---|---|---|---|")
    start, chains = time.perf_counter(), []
    for az, el in SUN_POSITIONS:
        at_center = trace(scenario, artist_plane[0], az, el, antithetic=True)
        at_corners = trace(scenario, origin, az, el, antithetic=False)
        chain = helioflow_chain(at_center, artist_plane, corners_plane(corners))
        chains.append([to_frame(p, origin) for p in chain])
        central = [plane_hits(*image.central, *artist_plane)[0] for image in (at_center, at_corners)]
        row = [chain[0], artist_centroid(at_corners, artist_plane), chain[-1], *central]
        cells = " | ".join("({:+.1f}, {:+.1f})".format(*to_frame(p, origin)) for p in row)
        print(f"| {az:.2f} / {el:.2f} | {cells} |")
    elapsed = time.perf_counter() - start
    steps = np.array(chains).mean(axis=0)  # [step, (right, up)]
    print("\nMean over the sun positions of (a) - (c), one change at a time (mm right, up):")
    shifts = [*(steps[:-1] - steps[1:]), steps[0] - steps[-1]]
    for label, shift in zip([*EFFECTS, "total, (a) - (c)"], shifts):
        print(f"- {label}: ({shift[0]:+.2f}, {shift[1]:+.2f})")
    print(f"\n{at_corners.dirs[0, ..., 0].size} rays per ARTIST image, "
          f"{2 * len(SUN_POSITIONS)} images plus the antithetic pairs for aim at center, "
          f"{elapsed:.1f} s, torch {torch.__version__}, float64 hit points")


def main() -> None:
    """Print the ENU table, build the scenario and print the centroid table."""
    root = pathlib.Path(__file__).resolve().parent.parent
    paint_dir = pathlib.Path(sys.argv[1]) if len(sys.argv) > 1 else root / "tests" / "data" / "paint"
    tower = json.loads((paint_dir / "tower-measurements.json").read_text())
    ref = np.array(tower["power_plant_properties"]["coordinates"], dtype=np.float64)
    coords = tower[TARGET]["coordinates"]
    names = [*CORNERS, "center"]
    lla = np.array([coords[k] for k in names], dtype=np.float64)
    helio_lla = np.array([json.loads((paint_dir / HELIOSTAT / "heliostat-properties.json").read_text())
                          ["heliostat_position"]], dtype=np.float64)
    enu_artist, enu_exact = wgs84_to_enu_artist(lla, ref), wgs84_to_enu_exact(lla, ref)
    h_artist, h_exact = wgs84_to_enu_artist(helio_lla, ref)[0], wgs84_to_enu_exact(helio_lla, ref)[0]

    print(f"## ENU (m) relative to power plant {ref.tolist()}\n")
    print("| point | ARTIST E, N, U | exact ECEF E, N, U | ARTIST - exact (mm) |")
    print("|---|---|---|---|")
    for name, pa, pe in [*zip(names, enu_artist, enu_exact), (f"heliostat {HELIOSTAT}", h_artist, h_exact)]:
        d = (pa - pe) * 1e3
        print(f"| {name} | {pa[0]:.4f}, {pa[1]:.4f}, {pa[2]:.4f} | {pe[0]:.4f}, {pe[1]:.4f}, {pe[2]:.4f} "
              f"| {d[0]:+.2f}, {d[1]:+.2f}, {d[2]:+.2f} |")
    origin = enu_artist[:4].mean(axis=0)
    mean_exact = enu_exact[:4].mean(axis=0)
    centre = "({:+.1f}, {:+.1f})".format(*to_frame(enu_artist[4], origin))
    exact = "({:+.2f}, {:+.2f})".format(*to_frame(mean_exact, origin))
    print(f"\nOrigin (mean of corners, ARTIST ENU): {origin.round(4).tolist()} m; "
          f"ARTIST centre in this frame: {centre} mm right, up; exact-ECEF origin in this frame: {exact} mm; "
          f"corner mean is {(enu_artist[4, 1] - origin[1]) * 1e3:.1f} mm south of ARTIST's target plane")

    with tempfile.TemporaryDirectory() as tmp:
        scenario = build_scenario(paint_dir, pathlib.Path(tmp))
    target_index = scenario.solar_tower.target_name_to_index[TARGET]
    artist_center = scenario.solar_tower.target_areas[0].centers[target_index, :3].double().numpy()
    helio_pos = scenario.heliostat_field.heliostat_groups[0].positions[0, :3].double().numpy()
    f32_round = np.spacing(np.abs(np.vstack([enu_artist, h_artist])).astype(np.float32)).max() / 2
    print(f"ARTIST's WGS84->ENU converts float64 lat/lon/alt but returns float32 ENU "
          f"(rounding <= {f32_round * 1e6:.1f} um here); aiming and tracing run in float32.")
    print(f"Slant range heliostat -> target centre: {np.linalg.norm(artist_center - helio_pos):.3f} m\n")

    areas = scenario.solar_tower.target_areas[0]
    artist_plane = (artist_center, areas.normals[target_index, :3].double().numpy())
    print_centroids(scenario, artist_plane, enu_artist[:4])


if __name__ == "__main__":
    main()
