"""An independent world for testing inversions: a plain numpy Monte Carlo of a real heliostat
(PAINT's AA39 at the Jülich tower, geometry from tests/data/paint) that writes PAINT folders
(8-bit PNGs of the whole target, calibration-properties.json per image) for `source: paint`.

It shares no code with helioflow's tracer, kinematics, sun sampling or camera model: rotations,
sun shape (Buie 2003 / Gaussian), slope errors, facet tilts, the surface bump, the reflection, the
target intersection and the image are all written here, from their definitions. Only reading the
JSON files and WGS84 -> ENU come from helioflow (a conversion, not physics a fit inverts).

Effects (`world(...)` keywords), with the magnitudes a real heliostat has:
    tracking_mrad=(d1, d2)      offsets of the two joint angles (first about east, second about
                                the rotated up axis; the "juelich" mount)
    sun=("buie", csr) | ("gaussian", sigma_mrad) | ("pillbox", half_angle_mrad)
    slope_mrad=s                Gaussian slope error, std per axis of the surface normal's tilt
    canting_mrad=(F, 2) array   facet tilts about each facet's width and height axes
    bump=(facet, height_mm, width_m)  a Gaussian bump on one facet (the local surface error)
    camera=(background, blur_px)      background as a fraction of the peak, blur std in pixels of
                                      a 64 x 64 image of the target (4x that of the 256 x 256 PNG),
                                      applied to each ray's landing point (a photon's point-spread:
                                      the counting noise stays white, as a sensor's is)
    counted_blur_px=b           a blur after the counting (std in pixels of a 64 x 64 image), as a
                                resampled image has: the counting noise is smooth over a few pixels
    rectified=True              the image resampled as a rectification does: bilinear onto a camera
                                grid turned by 17 mrad, stretched by 1.3 % and shifted by a fraction of
                                a pixel, and bilinear back onto the target's grid (the geometry kept,
                                the noise correlated)
    focal_length_m=f            curved facets: each a paraboloid of this focal length (the model's
                                facets are flat)
    soiling=g                   soiling that grows down the mirror: the reflectance falls linearly from
                                the mirror's top edge (clean) to g less at its bottom edge
    neighbour_enu_m=(e, n, u)   a neighbouring heliostat of the same mirror size at this offset from
                                AA39's pivot, tracking the same aim point: its mirror (one rectangle
                                over all facets) shades the sun's rays and blocks the reflected ones
"""

from __future__ import annotations

import json
import math
import shutil
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from PIL import Image
from scipy.ndimage import gaussian_filter, map_coordinates

from helioflow.data.paint import Tower
from helioflow.physics.geometry import wgs84_to_enu

PAINT = Path(__file__).resolve().parents[1] / "data" / "paint"
HELIOSTAT = "AA39"
PNG_SIDE = 256
LATITUDE_DEG, LONGITUDE_DEG = 50.9134, 6.3878  # Jülich
BUIE_DISC_MRAD, BUIE_EDGE_MRAD = 4.65, 43.6


@dataclass
class World:
    """What the Monte Carlo puts into the images (module docstring)."""

    tracking_mrad: tuple[float, float] = (0.0, 0.0)
    sun: tuple = ("gaussian", 2.51)  # ~ the Buie sun of CSR 0.1's RMS width per axis
    slope_mrad: float = 0.0
    canting_mrad: np.ndarray | None = None
    bump: tuple[int, float, float] | None = None
    camera: tuple[float, float] = (0.0, 0.0)
    counted_blur_px: float = 0.0
    rectified: bool = False
    focal_length_m: float | None = None
    soiling: float = 0.0
    neighbour_enu_m: tuple[float, float, float] | None = None
    target: str = "solar_tower_juelich_upper"
    truth: dict = field(default_factory=dict)


def rotation(axis: np.ndarray, angle: float) -> np.ndarray:
    """(3, 3) right-handed rotation by `angle` (rad) about the unit `axis` (Rodrigues)."""
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + math.sin(angle) * k + (1 - math.cos(angle)) * k @ k


def sun_vector(azimuth_deg: float, elevation_deg: float) -> np.ndarray:
    """Unit vector towards the sun (ENU); azimuth 0 = south, +90 = east."""
    az, el = math.radians(azimuth_deg), math.radians(elevation_deg)
    return np.array([math.cos(el) * math.sin(az), -math.cos(el) * math.cos(az), math.sin(el)])


def calibration_suns(n: int, seed: int) -> list[tuple[float, float]]:
    """n sun positions (azimuth, elevation deg) of calibrations spread over a year at Jülich: random
    days and daytime hours, the sun at least 15 deg high (declination and hour angle from the
    textbook approximation; only the spread of positions matters here)."""
    rng = np.random.default_rng(seed)
    lat = math.radians(LATITUDE_DEG)
    suns = []
    while len(suns) < n:
        day, hour = rng.uniform(0, 365), rng.uniform(7.0, 17.0)
        decl = math.radians(-23.44) * math.cos(2 * math.pi * (day + 10) / 365)
        h = math.radians(15.0 * (hour - 12.0))
        sin_el = math.sin(lat) * math.sin(decl) + math.cos(lat) * math.cos(decl) * math.cos(h)
        el = math.asin(sin_el)
        # azimuth from south, positive towards east (morning: hour angle < 0)
        from_north = math.degrees(math.atan2(-math.cos(decl) * math.sin(h), math.sin(decl) * math.cos(lat)
                                             - math.cos(decl) * math.sin(lat) * math.cos(h)))
        az = (180.0 - from_north + 180.0) % 360.0 - 180.0  # from north, clockwise -> 0 = south, +90 = east
        if math.degrees(el) >= 15.0:
            suns.append((round(az, 4), round(math.degrees(el), 4)))
    return suns


def buie_angles(csr: float, n: int, rng: np.random.Generator) -> np.ndarray:
    """(n,) angles (rad) from the sun centre drawn from the Buie (2003) profile with this CSR."""
    theta = np.linspace(0.0, BUIE_EDGE_MRAD, 200_001)
    chi = csr
    kappa = 0.9 * math.log(13.5 * chi) * chi ** -0.3
    gamma = 2.2 * math.log(0.52 * chi) * chi ** 0.43 - 0.1
    phi = np.where(theta <= BUIE_DISC_MRAD, np.cos(0.326 * theta) / np.cos(0.308 * theta),
                   math.exp(kappa) * np.maximum(theta, 1e-9) ** gamma)
    pdf = phi * theta  # per unit angle: the ring's circumference
    cdf = np.concatenate(([0.0], np.cumsum(0.5 * (pdf[1:] + pdf[:-1]) * np.diff(theta))))
    return np.interp(rng.uniform(0, cdf[-1], n), cdf, theta) * 1e-3


def sun_deviations(sun: tuple, n: int, rng: np.random.Generator) -> np.ndarray:
    """(n, 2) angular deviations (rad) of incoming rays from the sun centre."""
    kind, value = sun
    if kind == "gaussian":
        return rng.normal(0.0, value * 1e-3, (n, 2))
    if kind == "buie":
        radius = buie_angles(value, n, rng)
    elif kind == "pillbox":
        radius = value * 1e-3 * np.sqrt(rng.uniform(0, 1, n))
    else:
        raise ValueError(kind)
    angle = rng.uniform(0, 2 * math.pi, n)
    return np.stack((radius * np.cos(angle), radius * np.sin(angle)), -1)


def perpendicular_axes(d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors perpendicular to the unit vector d and to each other."""
    a = np.cross(d, [0.0, 0.0, 1.0])
    if np.linalg.norm(a) < 1e-6:
        a = np.cross(d, [1.0, 0.0, 0.0])
    a /= np.linalg.norm(a)
    return a, np.cross(d, a)


class Scene:
    """The heliostat and the target in ENU, read from the PAINT files."""

    def __init__(self, target: str):
        tower = Tower(PAINT / "tower-measurements.json")
        self.tower = tower
        props = json.loads((PAINT / HELIOSTAT / "heliostat-properties.json").read_text())
        self.position = tower.enu(props["heliostat_position"])
        facets = props["facet_properties"]["facets"]
        # facet vectors in the heliostat frame (right, up, normal); PAINT's (e, n, u) are exactly these,
        # relative to the concentrator's origin, which sits at the concentrator translation from the pivot
        # (given at rest in (e, n, u); the mirror faces -n there: (right, up, normal) = (e, u, -n)), as in
        # ARTIST's rigid-body kinematics
        self.centre = np.array([f["translation_vector"] for f in facets], float)
        kin = props["kinematics_properties"]
        self.concentrator = np.array([kin["concentrator_translation_e"], kin["concentrator_translation_u"],
                                      -kin["concentrator_translation_n"]], float)
        self.half_e = np.array([f["canting_e"] for f in facets], float)
        self.half_n = np.array([f["canting_n"] for f in facets], float)
        normal = np.cross(self.half_e, self.half_n)
        self.normal = normal / np.linalg.norm(normal, axis=-1, keepdims=True)
        plane = tower.target(target, PAINT / "tower-measurements.json")
        self.target = plane
        # the importer's axes: right from upper_left to upper_right, up along the sides
        corners = {c: tower.enu(tower.data[target]["coordinates"][c])
                   for c in ("upper_left", "upper_right", "lower_left", "lower_right")}
        right = 0.5 * ((corners["upper_right"] - corners["upper_left"])
                       + (corners["lower_right"] - corners["lower_left"]))
        up = 0.5 * ((corners["upper_left"] - corners["lower_left"]) + (corners["upper_right"] - corners["lower_right"]))
        self.right, self.up = right / np.linalg.norm(right), up / np.linalg.norm(up)

    def mirror_rotation(self, sun: np.ndarray, tracking_mrad: tuple[float, float],
                        position: np.ndarray | None = None) -> np.ndarray:
        """(3, 3) heliostat frame (right, up, normal) -> ENU: the joints set so that the mirror
        normal bisects the sun and the direction from the concentrator's origin to the aim point
        (the tower file's `center`; the origin turns with the mirror: fixed-point iterations, as
        ARTIST's), then offset by the tracking errors. `position`: another heliostat's pivot (ENU)."""
        position = self.position if position is None else position
        frame = np.eye(3)
        for _ in range(6):
            to_aim = self.target.aim - (position + frame @ self.concentrator)
            frame = self._joints(sun, to_aim / np.linalg.norm(to_aim), (0.0, 0.0))
        return self._joints(sun, to_aim / np.linalg.norm(to_aim), tracking_mrad)

    def _joints(self, sun: np.ndarray, to_aim: np.ndarray, tracking_mrad: tuple[float, float]) -> np.ndarray:
        """(3, 3) heliostat frame -> ENU for the normal bisecting `sun` and `to_aim`, the joint angles
        offset by `tracking_mrad`."""
        n = sun + to_aim
        n /= np.linalg.norm(n)
        east, up = np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.0, 1.0])
        rest = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])  # columns: east, up, south
        # n = R_east(a1) R_up(a2) south:  (sin a2, -cos a2 cos a1, -cos a2 sin a1)
        a2 = math.asin(np.clip(n[0], -1, 1))
        a1 = math.atan2(-n[2], -n[1])
        a1 += tracking_mrad[0] * 1e-3
        a2 += tracking_mrad[1] * 1e-3
        r = rotation(east, a1) @ rotation(up, a2)
        return r @ rest


def trace_image(scene: Scene, world: World, azimuth_deg: float, elevation_deg: float, rays: int,
                rng: np.random.Generator) -> np.ndarray:
    """(256, 256) flux image of the whole target (rows top-down, columns right) for one sun."""
    sun = sun_vector(azimuth_deg, elevation_deg)
    frame = scene.mirror_rotation(sun, world.tracking_mrad)
    n_facets = len(scene.centre)
    facet = rng.integers(0, n_facets, rays)
    u, v = rng.uniform(-1, 1, (2, rays))
    # facet axes and normal in the heliostat frame, tilted by the canting errors
    e_axis = scene.half_e / np.linalg.norm(scene.half_e, axis=-1, keepdims=True)
    n_axis = scene.half_n / np.linalg.norm(scene.half_n, axis=-1, keepdims=True)
    normals = scene.normal.copy()
    if world.canting_mrad is not None:
        for f in range(n_facets):
            tilt = (rotation(e_axis[f], world.canting_mrad[f, 0] * 1e-3)
                    @ rotation(n_axis[f], world.canting_mrad[f, 1] * 1e-3))
            normals[f] = tilt @ normals[f]
    points = scene.centre[facet] + u[:, None] * scene.half_e[facet] + v[:, None] * scene.half_n[facet]
    normal = normals[facet]
    if world.bump is not None:
        f0, height_mm, width_m = world.bump
        local = np.stack((u * np.linalg.norm(scene.half_e[facet], axis=-1),
                          v * np.linalg.norm(scene.half_n[facet], axis=-1)), -1)  # m on the facet
        g = height_mm * 1e-3 * np.exp(-(local ** 2).sum(-1) / (2 * width_m ** 2)) * (facet == f0)
        slope = -local / width_m ** 2 * g[:, None]  # dh/dx, dh/dy
        normal = normal - slope[:, :1] * e_axis[facet] - slope[:, 1:] * n_axis[facet]
        normal /= np.linalg.norm(normal, axis=-1, keepdims=True)
    if world.focal_length_m is not None:  # z = (x^2 + y^2) / (4 f): slopes x / (2 f), y / (2 f)
        local = np.stack((u * np.linalg.norm(scene.half_e[facet], axis=-1),
                          v * np.linalg.norm(scene.half_n[facet], axis=-1)), -1)
        slope = local / (2 * world.focal_length_m)
        normal = normal - slope[:, :1] * e_axis[facet] - slope[:, 1:] * n_axis[facet]
        normal /= np.linalg.norm(normal, axis=-1, keepdims=True)
    if world.slope_mrad:
        tilt = rng.normal(0.0, world.slope_mrad * 1e-3, (rays, 2))
        normal = normal + tilt[:, :1] * e_axis[facet] + tilt[:, 1:] * n_axis[facet]
        normal /= np.linalg.norm(normal, axis=-1, keepdims=True)
    if world.soiling:
        top = (scene.centre[:, 1] + np.linalg.norm(scene.half_n, axis=-1)).max()
        bottom = (scene.centre[:, 1] - np.linalg.norm(scene.half_n, axis=-1)).min()
        reflectance = 1.0 - world.soiling * (top - points[:, 1]) / (top - bottom)
    points = (points + scene.concentrator) @ frame.T + scene.position
    normal = normal @ frame.T
    a, b = perpendicular_axes(sun)
    dev = sun_deviations(world.sun, rays, rng)
    towards_sun = sun[None] + dev[:, :1] * a + dev[:, 1:] * b
    towards_sun /= np.linalg.norm(towards_sun, axis=-1, keepdims=True)
    incoming = -towards_sun
    cos_in = -(incoming * normal).sum(-1)
    reflected = incoming + 2 * cos_in[:, None] * normal
    t = ((scene.target.center - points) @ scene.target.normal) / (reflected @ scene.target.normal)
    hit = points + t[:, None] * reflected - scene.target.center
    x, y = hit @ scene.right, hit @ scene.up
    if world.camera[1] > 0:  # the camera's blur, photon by photon: the counting noise stays white, as a sensor's
        x = x + rng.normal(0.0, world.camera[1] * scene.target.width / 64, rays)
        y = y + rng.normal(0.0, world.camera[1] * scene.target.height / 64, rays)
    weight = np.clip(cos_in, 0, None)  # the facet area's projection towards the sun
    if world.soiling:
        weight = weight * reflectance
    if world.neighbour_enu_m is not None:
        weight = weight * ~neighbour_hits(scene, sun, points, towards_sun, world.neighbour_enu_m)
        weight = weight * ~neighbour_hits(scene, sun, points, reflected, world.neighbour_enu_m)
    col = (x / scene.target.width + 0.5) * PNG_SIDE
    row = (0.5 - y / scene.target.height) * PNG_SIDE
    image, _, _ = np.histogram2d(row, col, bins=PNG_SIDE, range=[[0, PNG_SIDE], [0, PNG_SIDE]], weights=weight)
    return image


def neighbour_hits(scene: Scene, sun: np.ndarray, points: np.ndarray, direction: np.ndarray,
                   offset_enu_m: tuple[float, float, float]) -> np.ndarray:
    """(R,) whether rays from `points` (R, 3) along `direction` (R, 3) meet the neighbour's mirror:
    one rectangle spanning all of AA39's facets, at the neighbour's pivot, tracking the same aim."""
    position = scene.position + np.asarray(offset_enu_m, float)
    frame = scene.mirror_rotation(sun, (0.0, 0.0), position)
    centre = position + frame @ scene.concentrator
    normal = frame[:, 2]
    half_w = np.abs(scene.centre[:, 0]).max() + np.linalg.norm(scene.half_e, axis=-1).max()
    half_h = np.abs(scene.centre[:, 1]).max() + np.linalg.norm(scene.half_n, axis=-1).max()
    along = direction @ normal
    t = ((centre - points) @ normal) / np.where(np.abs(along) < 1e-12, 1e-12, along)
    local = (points + t[:, None] * direction - centre) @ frame
    return (t > 0) & (np.abs(local[:, 0]) <= half_w) & (np.abs(local[:, 1]) <= half_h)


def camera(image: np.ndarray, world: World) -> np.ndarray:
    """What reaches the file of the counted image (PNG_SIDE, PNG_SIDE): the blur after the counting
    and the rectification's resampling (World), then the background, a share of the peak (the
    camera's own blur acts on each photon in trace_image)."""
    if world.counted_blur_px > 0:
        image = gaussian_filter(image, world.counted_blur_px * PNG_SIDE / 64, mode="constant")
    if world.rectified:
        image = _warped(_warped(image, 0.017, 1.013, (0.37, 0.21)), -0.017, 1 / 1.013, (0.0, 0.0), (0.37, 0.21))
    return image + world.camera[0] * image.max()


def _warped(image: np.ndarray, turn: float, stretch: float, shift: tuple[float, float],
            undo: tuple[float, float] | None = None) -> np.ndarray:
    """`image` (PNG_SIDE, PNG_SIDE) sampled bilinearly at its grid turned by `turn` (rad) and stretched
    by `stretch` about its centre, then shifted by `shift` (px); `undo`: a shift taken off before the
    turn (the inverse of a warp by that shift)."""
    y, x = np.mgrid[:PNG_SIDE, :PNG_SIDE].astype(float) - PNG_SIDE / 2
    if undo is not None:
        y, x = y - undo[0], x - undo[1]
    rows = stretch * (math.cos(turn) * y - math.sin(turn) * x) + PNG_SIDE / 2 + shift[0]
    cols = stretch * (math.sin(turn) * y + math.cos(turn) * x) + PNG_SIDE / 2 + shift[1]
    return map_coordinates(image, [rows, cols], order=1)


def enu_to_wgs84(tower: Tower, enu: np.ndarray) -> list[float]:
    """Inverse of the tower's WGS84 -> ENU, by Newton steps (for the focal-spot centroid field)."""
    lat0, lon0, alt0 = tower.origin
    guess = np.array([lat0 + enu[1] / 111_200.0, lon0 + enu[0] / (111_200.0 * math.cos(math.radians(lat0))),
                      alt0 + enu[2]])
    for _ in range(3):
        err = enu - wgs84_to_enu(*guess, lat0, lon0, alt0)
        guess += [err[1] / 111_200.0, err[0] / (111_200.0 * math.cos(math.radians(lat0))), err[2]]
    return guess.tolist()


def write_paint_folder(folder: Path, world: World, n_images: int = 40, rays: int = 1_000_000,
                       seed: int = 0, neighbour: str | None = None, name: str = HELIOSTAT,
                       offset_enu_m: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> list[tuple[float, float]]:
    """A PAINT folder (tower-measurements.json, <name>/heliostat-properties.json and, per image,
    <id>-calibration-properties.json and <id>-flux.png) of `n_images` calibrations under `world`;
    returns their sun positions (azimuth, elevation deg). The heliostat is AA39's design with its
    pivot moved by `offset_enu_m` (m) from AA39's, published as folder `name`. `neighbour`: a folder
    name under which the world's neighbour is published (its heliostat-properties.json: AA39's, at
    the neighbour's position), as PAINT lists every heliostat of the field; None: it stays unknown."""
    folder = Path(folder)
    (folder / name).mkdir(parents=True, exist_ok=True)
    shutil.copy(PAINT / "tower-measurements.json", folder / "tower-measurements.json")
    scene = Scene(world.target)
    scene.position = scene.position + np.asarray(offset_enu_m, float)
    if any(offset_enu_m):
        props = json.loads((PAINT / HELIOSTAT / "heliostat-properties.json").read_text())
        props["heliostat_position"] = enu_to_wgs84(scene.tower, scene.position)
        (folder / name / "heliostat-properties.json").write_text(json.dumps(props))
    else:
        shutil.copy(PAINT / HELIOSTAT / "heliostat-properties.json", folder / name / "heliostat-properties.json")
    if neighbour is not None and world.neighbour_enu_m is not None:
        props = json.loads((PAINT / HELIOSTAT / "heliostat-properties.json").read_text())
        props["heliostat_position"] = enu_to_wgs84(scene.tower, scene.position + np.asarray(world.neighbour_enu_m))
        (folder / neighbour).mkdir(exist_ok=True)
        (folder / neighbour / "heliostat-properties.json").write_text(json.dumps(props))
    rng = np.random.default_rng(seed)
    suns = calibration_suns(n_images, seed)
    for i, (az, el) in enumerate(suns):
        flux = camera(trace_image(scene, world, az, el, rays, rng), world)
        png = np.round(flux / flux.max() * 255).astype(np.uint8)
        mid = str(100_000 + i)
        Image.fromarray(png, mode="L").save(folder / name / f"{mid}-flux.png")
        rows, cols = np.indices(png.shape) + 0.5
        w = png.astype(float)
        x = ((cols * w).sum() / w.sum() / PNG_SIDE - 0.5) * scene.target.width
        y = (0.5 - (rows * w).sum() / w.sum() / PNG_SIDE) * scene.target.height
        centroid = enu_to_wgs84(scene.tower, scene.target.center + x * scene.right + y * scene.up)
        (folder / name / f"{mid}-calibration-properties.json").write_text(json.dumps({
            "motor_position": {"axis_1_motor_position": 0, "axis_2_motor_position": 0},
            "target_name": world.target, "sun_elevation": el, "sun_azimuth": az,
            "focal_spot": {"HeliOS": centroid, "UTIS": centroid}}))
    return suns


DEMO = World(tracking_mrad=(1.2, -0.9), camera=(0.03, 1.5))  # the PAINT demo: workflow/variants/paint_world_demo.yaml


def plant_worlds(n: int, seed: int, sun: tuple = ("gaussian", 2.51), camera: tuple = (0.03, 1.5),
                 canting_rms_mrad: tuple[float, float] = (0.5, 1.0),
                 ) -> dict[str, tuple[tuple[float, float, float], World]]:
    """{name: (pivot offset from AA39's (m, ENU), world)} of a plant of n heliostats under one sun
    and one camera (what every heliostat of a calibration campaign shares), each with its own hidden
    effects drawn at random: a tracking error always (joint offsets, 0.3-1.5 mrad each, random
    sign), and on about a third each a facet canting error (RMS drawn from `canting_rms_mrad`), a
    surface bump (0.5-1 mm high, 0.3 m wide, on one facet) or a slope error (0.5-1 mrad). Pivots on
    rows 8 m apart east-west and 10 m north-south around AA39's (names P000, P001, ...). The same
    seed draws the same plant whatever the canting's range (only its size scales)."""
    rng = np.random.default_rng(seed)
    out = {}
    for i in range(n):
        offset = (8.0 * (i % 6 - 2.5), 10.0 * (i // 6), 0.0)
        tracking = tuple(float(rng.uniform(0.3, 1.5) * rng.choice([-1.0, 1.0])) for _ in range(2))
        kind = ("canting", "bump", "slope")[i % 3] if rng.uniform() < 0.9 else None
        truth = {"tracking_mrad": tracking, "hidden": ["tracking"] + ([kind] if kind else [])}
        world = World(tracking_mrad=tracking, sun=sun, camera=camera, truth=truth)
        if kind == "canting":
            world.canting_mrad = rng.normal(0.0, rng.uniform(*canting_rms_mrad), (4, 2))
        elif kind == "bump":
            world.bump = (int(rng.integers(0, 4)), float(rng.uniform(0.5, 1.0)), 0.3)
        elif kind == "slope":
            world.slope_mrad = float(rng.uniform(0.5, 1.0))
        out[f"P{i:03d}"] = (offset, world)
    return out


def write_plant(folder: Path, worlds: dict, n_images: int, rays: int, seed: int) -> dict:
    """A PAINT directory of a plant (plant_worlds): one folder per heliostat, every heliostat
    calibrated at the same sun positions; writes truth.json beside ({name: the world's truth and
    offset}) and returns it."""
    truth = {}
    for k, (name, (offset, world)) in enumerate(worlds.items()):
        write_paint_folder(folder, world, n_images, rays, seed=seed + 1000 * k, name=name, offset_enu_m=offset)
        truth[name] = {**world.truth, "offset_enu_m": list(offset)}
    (Path(folder) / "truth.json").write_text(json.dumps(truth, indent=1))
    return truth

PLANT_DEMO = {"n": 6, "seed": 11, "n_images": 16, "rays": 500_000}  # workflow/variants/plant_demo.yaml

if __name__ == "__main__":  # python tests/support/paint_world.py examples/paint_world | plant DIR [--heliostats N ...]
    import argparse

    ap = argparse.ArgumentParser(description="Write the PAINT demo folder, or (first argument `plant`) a plant's "
                                             "PAINT directory (the demo's: examples/plant_world).")
    ap.add_argument("what", nargs="+", metavar="FOLDER | plant FOLDER")
    ap.add_argument("--heliostats", type=int, default=PLANT_DEMO["n"], help="heliostats (default: the demo's)")
    ap.add_argument("--images", type=int, default=PLANT_DEMO["n_images"], help="calibration images per heliostat")
    ap.add_argument("--rays", type=int, default=PLANT_DEMO["rays"], help="Monte Carlo rays per image")
    ap.add_argument("--seed", type=int, default=PLANT_DEMO["seed"], help="the seed the plant is drawn with")
    args = ap.parse_args()
    if args.what[0] == "plant":
        write_plant(Path(args.what[1]), plant_worlds(args.heliostats, args.seed), args.images, args.rays, args.seed)
    else:
        write_paint_folder(Path(args.what[0]), DEMO, n_images=40, rays=1_000_000, seed=7)
