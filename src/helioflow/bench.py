"""Benchmarks that print numbers: `python -m helioflow.bench raytrace`, `... field`, `... fit`, `... dag` or `... aim`.

raytrace: one 2 m x 2 m deformed heliostat 63 m from a 64 x 64 target (the sanity_check scene:
Buie sun CSR 0.1, slope error 0.5 mrad).
  - bilinear throughput (rays/s) and peak memory at several ray counts, one sun position, each
    measured in a fresh process (peak RSS, beside the RSS after imports), inference (no autograd).
    Ray sampling: every ray reads its sun and slope deviations from a pool of exact samples at
    seeded random offsets (counted in the rates); the pool itself is drawn once per sun shape and
    slope error and reused by every later trace (its time is printed beside, not in the rates);
  - time to reach PSNR 40 dB against a 10^8-ray bilinear reference image per sun position, for
    bilinear (growing the rays) and kernel splatting (refining the surface grid), for one sun
    position and for a batch of 16 different ones traced at once (as datasets are traced); all in
    this process, so their ratios are measured under the same load.

field: a flux map of 100, 300 and 1000 heliostats (`--sizes`) (radially staggered, north of a 60 m tower, each
2 x 2 facets of 1.6 m x 1.25 m canted at its slant range, with its own seeded surface, canting and
tracking errors) on an 8 m x 8 m receiver at 128 x 128, Buie sun CSR 0.1, slope error 1.5 mrad,
clear-day attenuation, shading and blocking; one sun position. Each field in a fresh process:
wall time of building the geometry and of the flux map (after a warm-up map of 10 heliostats that
fills the footprint tables), peak RSS beside the RSS after imports, and the power budget. `--device cuda`
runs it on a GPU (peak GPU memory added); `--json PATH` writes the figures to PATH as well.

aim: the aim optimiser (field.aim.optimise, 300 steps) on 1,000 and 10,000 heliostats (`--sizes`) of the
field benchmark's layout, one design point: each spot a Gaussian of 3.5 mrad beam spread times its
slant range, moved off its aim by a pointing error of 1 mrad std (so the spots are whole images, not
traced: the optimiser's cost, not the tracer's), on a 128 x 128 receiver whose side grows with the field
(8 m at 1,000 heliostats, 20 m at 10,000), limit three times the mean flux of all the power on the receiver.
Each size in a fresh process: setup and optimisation wall time, peak RSS, the peak before (all at the
centre) and after, and the share of the power on the receiver.

dag: `snakemake -n all` on the plant_demo variant with a plant of `--heliostats` heliostats (2000):
a generated PAINT directory (in a temporary folder) of AA39-design heliostats on a grid north of
the tower, 2 calibration images each (examples/plant_world/P000's, linked); prints the wall time,
the peak memory of snakemake and the number of jobs it plans. Run it from the repository root.

fit: drt's fit of a dataset's heliostat from its design (default: the default experiment's
semi_sphere, 24 facets; `snakemake -j2 results/default/datasets/semi_sphere.h5` makes it), with the
settings of config.yaml's networks.drt, in one process: the fit (on the linearised trace for several
facets) and the rounds-only descent on the exact trace (no hops; bilinear rays for a ray-traced
dataset: what drt ran before the linearised trace, as the `quick` variant), each
with its wall time, traces (images traced with gradient or without, counted), held-out PSNR per
split (mean over its images, as the evaluate rule scores) and surface height error (RMS error over RMS
amplitude, as the recovery rule computes it).
"""

from __future__ import annotations

import argparse
import json
import math
import multiprocessing as mp
import resource
import time

import numpy as np
import torch

from helioflow.data.surfaces import HeliostatSpec, true_heliostat
from helioflow.device import resolve_device
from helioflow.field.aim import SpotPatches, optimise, render
from helioflow.io import write_text_atomic
from helioflow.physics.effects import resolve
from helioflow.physics.field import FieldHeliostats, field_flux, flat_receiver
from helioflow.physics.layout import min_spacing, radial_staggered
from helioflow.physics.raytrace import POOL_SIZE, sample_pool, trace
from helioflow.physics.target import Target
from helioflow.scoring.metrics import psnr as metric_psnr

SCENE_HELIOSTAT = HeliostatSpec("bench", (0.0, 60.0, 0.0), "az_el", 1, 1, 2.0, 2.0, 0.0, None, None, 6, 0.5, 1.0,
                                0.0, 1)
SCENE_EFFECTS = {"sunshape": {"kind": "buie", "csr": 0.1}, "slope_error": {"sigma_mrad": 0.5}, "tracking": {},
                 "surface": {}}
# 16 sun positions (azimuth, elevation deg) over the calibration sky; the first is the one-position scene's
SUN_DEG = [(10.0, 40.0)] + [(az, el) for el in (20.0, 45.0, 70.0) for az in (-75.0, -40.0, 0.0, 40.0, 75.0)]


def scene(batch: int = 1):
    """(heliostat float32, optics, target, azimuth (batch,), elevation (batch,)) of the benchmark: the
    first `batch` sun positions of SUN_DEG (rad)."""
    physics = resolve(SCENE_EFFECTS, true_heliostat(SCENE_HELIOSTAT), dni=1000.0)
    target = Target.facing([0.0, 0.0, 20.0], [0.0, 60.0, 0.0], 3.8, 3.8, (64, 64))
    az, el = (torch.tensor([math.radians(p[k]) for p in SUN_DEG[:batch]]) for k in (0, 1))
    return physics.heliostat.to("cpu"), physics.optics, target, az, el


def psnr(image: torch.Tensor, reference: torch.Tensor) -> float:
    """PSNR (dB, scoring.metrics.psnr) with both images divided by the reference's maximum."""
    scale = reference.max()
    return float(metric_psnr((image / scale).numpy(), (reference / scale).numpy()))


def _timed(batch: int = 1, **kwargs) -> tuple[torch.Tensor, float]:
    """(batch, H, W) images at the first `batch` sun positions traced at once, and the wall time per
    image (s)."""
    heliostat, optics, target, az, el = scene(batch)
    start = time.perf_counter()
    with torch.no_grad():
        images = trace(heliostat, target, az, el, optics, **kwargs)
    return images, (time.perf_counter() - start) / batch


def _rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _throughput_worker(rays: int, threads: int, queue) -> None:
    torch.set_num_threads(threads)
    base = _rss_mb()
    _, optics, *_ = scene()
    start = time.perf_counter()
    sample_pool(optics.sun, float(optics.slope_error), POOL_SIZE)  # the exact samples every trace reads
    pool_seconds = time.perf_counter() - start
    _timed(rays=10_000, cells_per_side=32)  # warm-up: einsum paths, allocator
    _, seconds = _timed(rays=rays, cells_per_side=32, seed=1)
    queue.put((rays / seconds, _rss_mb(), base, pool_seconds))


def throughput(rays: int, threads: int) -> tuple[float, float, float, float]:
    """(rays per second, peak RSS in MB, RSS after imports in MB, seconds to draw the sample pool) of
    one bilinear trace (after a small warm-up trace), each in a fresh process."""
    ctx = mp.get_context("spawn")
    queue = ctx.Queue()
    proc = ctx.Process(target=_throughput_worker, args=(rays, threads, queue))
    proc.start()
    result = queue.get()
    proc.join()
    return result


def time_to_psnr(reference: torch.Tensor, batch: int, goal_db: float = 40.0) -> dict[str, tuple[float, float, str]]:
    """For each splat mode: (seconds per image, worst PSNR in the batch, setting) of the cheapest
    setting whose every image reaches goal_db against its reference (batch, H, W), tracing the
    first `batch` sun positions at once (as datasets are traced). Bilinear rays grow by 1.25x per
    step, kernel cells by one per side."""
    found = {}
    rays = 100_000
    while rays <= 64_000_000:
        images, seconds = _timed(batch, rays=rays, cells_per_side=32, seed=7)
        worst = min(psnr(image, ref) for image, ref in zip(images, reference))
        if worst >= goal_db:
            found["bilinear"] = (seconds, worst, f"{rays:.2e} rays")
            break
        rays = int(rays * 1.25)
    for cells in range(4, 65):
        _timed(batch, rays=0, splat="kernel", cells_per_side=cells)  # warm-up of the footprint tables
        images, seconds = _timed(batch, rays=0, splat="kernel", cells_per_side=cells)
        worst = min(psnr(image, ref) for image, ref in zip(images, reference))
        if worst >= goal_db:
            found["kernel"] = (seconds, worst, f"{cells}x{cells} cells")
            break
    return found


def raytrace(threads: int, reference_rays: int) -> None:
    """The raytrace benchmark (module docstring): throughput, memory and time to PSNR 40 dB, printed."""
    torch.set_num_threads(threads)
    print(f"helioflow raytrace benchmark: 64x64 target, {threads} threads, torch {torch.__version__}")
    print(f"{'rays':>12} {'Mrays/s':>9} {'peak RSS MB':>12} {'after imports MB':>17}")
    for rays in (10**5, 10**6, 10**7, 10**8):
        rate, peak, base, pool_seconds = throughput(rays, threads)
        print(f"{rays:>12.0e} {rate / 1e6:>9.1f} {peak:>12.0f} {base:>17.0f}")
    print(f"ray sampling: each ray's draw from the pool is in the rates; the pool ({POOL_SIZE:.1e} exact Buie sun "
          f"and slope samples, drawn once per sun shape and slope error) took {pool_seconds:.2f} s, not in the rates")
    batch = len(SUN_DEG)
    start = time.perf_counter()
    reference, _ = _timed(batch, rays=reference_rays, cells_per_side=64, seed=12345)
    print(f"reference: {reference_rays:.0e} bilinear rays per image at {batch} sun positions in "
          f"{time.perf_counter() - start:.1f} s")
    for batch in (1, len(SUN_DEG)):
        found = time_to_psnr(reference[:batch], batch)
        for mode, (seconds, db, setting) in found.items():
            print(f"time to PSNR 40 dB, {mode:>8}, batch of {batch:>2}: {seconds * 1e3:7.1f} ms per image "
                  f"({setting}, worst {db:.1f} dB)")
        if len(found) == 2:
            print(f"  kernel reaches 40 dB {found['bilinear'][0] / found['kernel'][0]:.0f}x sooner than bilinear")


FIELD_SIZES = (100, 300, 1000)  # heliostats, default of --sizes
FIELD_EFFECTS = {"sunshape": {"kind": "buie", "csr": 0.1}, "slope_error": {"sigma_mrad": 1.5}, "tracking": {},
                 "canting": {}, "surface": {}, "reflectivity": {"value": 0.95},
                 "attenuation": {"model": "vittitoe_biggs_clear"}, "blocking_shading": {}}
FIELD_SUN_DEG = (-30.0, 35.0)
TOWER_M = 60.0


def field_scene(n: int, device: str | torch.device = "cpu"):
    """(FieldHeliostats float32, receiver, physics of heliostat 0, azimuth (1,), elevation (1,)) of the
    field benchmark with n heliostats, on `device`."""
    facet_w, facet_h, gap = 1.6, 1.25, 0.05
    spacing = min_spacing(2 * facet_w + gap, 2 * facet_h + gap, clearance=1.0)
    positions = radial_staggered(n, spacing, min_radius=40.0, height=2.0)
    aim = torch.tensor([0.0, 0.0, TOWER_M], dtype=torch.float64)
    physics = [
        resolve(FIELD_EFFECTS, true_heliostat(HeliostatSpec(
            name=f"h{i}", position_m=tuple(p.tolist()), mount="juelich", rows=2, cols=2, width_m=facet_w,
            height_m=facet_h, gap_m=gap, canting_focal_distance_m=float((aim - p).norm()),
            facet_focal_length_m=None, control_points=6, deformation_mm=0.2, tracking_error_mrad=0.5,
            canting_error_mrad=0.5, seed=i)),
            dni=1000.0)
        for i, p in enumerate(positions)
    ]
    field = FieldHeliostats.stack([p.heliostat.to(device, torch.float64) for p in physics], 8, torch.float32)
    receiver = flat_receiver(aim.to(device), torch.tensor([0.0, 1.0, -0.45], device=device), 8.0, 8.0, (128, 128),
                             dtype=torch.float32)
    az, el = (torch.tensor([math.radians(a)], device=device) for a in FIELD_SUN_DEG)
    return field, receiver, physics[0], az, el


def _field_worker(n: int, threads: int, device: str | torch.device, queue) -> None:
    torch.set_num_threads(threads)
    device = resolve_device(device)
    cuda = device.type == "cuda"
    base = _rss_mb()
    start = time.perf_counter()
    field, receiver, physics, az, el = field_scene(n, device)
    setup = time.perf_counter() - start
    options = {"blocking_shading": physics.blocking_shading}
    with torch.no_grad():
        field_flux(field_scene(10, device)[0], receiver, az, el, physics.optics, **options)  # warm-up
        if cuda:
            torch.cuda.synchronize(device)
            torch.cuda.reset_peak_memory_stats(device)
        start = time.perf_counter()
        result = field_flux(field, receiver, az, el, physics.optics, **options)
        if cuda:
            torch.cuda.synchronize(device)
        seconds = time.perf_counter() - start
    totals = {k: v.item() for k, v in result.totals().items()}
    device_mb = torch.cuda.max_memory_allocated(device) / 2**20 if cuda else None
    queue.put((setup, seconds, _rss_mb(), base, device_mb, totals))


def field(threads: int, sizes: tuple[int, ...] = FIELD_SIZES, device: str = "cpu", json_path: str | None = None
          ) -> None:
    """The `field` benchmark (module docstring); with json_path also written there as JSON."""
    name = str(resolve_device(device))
    print(f"helioflow field benchmark: 128x128 receiver, {threads} threads, torch {torch.__version__}, {name}")
    print(f"{'heliostats':>10} {'setup s':>8} {'flux map s':>10} {'peak RSS MB':>12} {'after imports MB':>17}"
          f" {'shaded':>7} {'blocked':>8} {'attenuated':>10} {'intercept':>9}"
          + (f" {'peak GPU MB':>11}" if name.startswith("cuda") else ""))
    ctx = mp.get_context("spawn")
    rows = []
    for n in sizes:
        queue = ctx.Queue()
        proc = ctx.Process(target=_field_worker, args=(n, threads, device, queue))
        proc.start()
        setup, seconds, peak, base, device_mb, t = queue.get()
        proc.join()
        reflected = t["reflected"]
        row = {"heliostats": n, "setup_s": setup, "flux_map_s": seconds, "peak_rss_mb": peak,
               "after_imports_mb": base, "peak_gpu_mb": device_mb, "shaded": t["shaded"] / t["incident"],
               "blocked": t["blocked"] / reflected, "attenuated": t["attenuated"] / reflected,
               "intercept": t["on_receiver"] / reflected, "budget_w": t}
        rows.append(row)
        print(f"{n:>10} {setup:>8.1f} {seconds:>10.1f} {peak:>12.0f} {base:>17.0f}"
              f" {row['shaded']:>7.1%} {row['blocked']:>8.1%} {row['attenuated']:>10.1%} {row['intercept']:>9.1%}"
              + (f" {device_mb:>11.0f}" if device_mb is not None else ""))
    print("shaded: of the incident sunlight; blocked, attenuated and intercept (on the receiver): of the "
          "reflected power")
    if json_path:
        record = {"benchmark": "field", "receiver_pixels": [128, 128], "threads": threads, "device": name,
                  "torch": torch.__version__, "sun_deg": list(FIELD_SUN_DEG), "fields": rows}
        write_text_atomic(json_path, json.dumps(record, indent=1) + "\n")


AIM_SIZES = (1000, 10000)
AIM_BEAM_MRAD = 3.5  # std of a spot's beam spread (sun, slope error): its width grows with the slant range
AIM_TRACKING_MRAD = 1.0  # std of each heliostat's pointing error, which moves its spot off the aim


def aim_scene(n: int, seed: int = 0) -> tuple[SpotPatches, float, float]:
    """(spots, limit W/m^2, receiver side m) of the aim benchmark with n heliostats (module docstring)."""
    facet_w, facet_h, gap = 1.6, 1.25, 0.05
    positions = radial_staggered(n, min_spacing(2 * facet_w + gap, 2 * facet_h + gap, clearance=1.0),
                                 min_radius=40.0, height=2.0)
    tower = torch.tensor([0.0, 0.0, TOWER_M], dtype=torch.float64)
    side = 8.0 * (n / 1000) ** 0.4
    rows = cols = 128
    pixel = side / cols
    ranges = (positions - tower).norm(dim=-1)
    generator = torch.Generator().manual_seed(seed)
    sigma_px = AIM_BEAM_MRAD * 1e-3 * ranges / pixel
    shift_px = torch.randn(n, 2, generator=generator, dtype=torch.float64) * (2 * AIM_TRACKING_MRAD * 1e-3
                                                                               * ranges / pixel)[:, None]
    power = 1000.0 * 4 * facet_w * facet_h * 0.9  # W: DNI x area x reflectivity x cosine (0.9)
    pad = 64
    grid = torch.arange(rows + 2 * pad, dtype=torch.float64) - (rows + 2 * pad) / 2 + 0.5
    parts = []
    for chunk in torch.split(torch.arange(n), 256):
        s, d = sigma_px[chunk, None, None], shift_px[chunk]
        rr = torch.exp(-((grid[None, :] - d[:, :1]) ** 2) / (2 * s[:, :, 0] ** 2))  # (c, H) rows
        cc = torch.exp(-((grid[None, :] - d[:, 1:]) ** 2) / (2 * s[:, :, 0] ** 2))  # (c, W) columns
        maps = rr[:, :, None] * cc[:, None, :]
        maps = maps / maps.sum((1, 2), keepdim=True) * power / pixel**2
        parts.append(SpotPatches.from_maps(maps.float(), (rows, cols), (pixel, pixel)))
    spots = SpotPatches.merge(parts)
    limit = 3.0 * float(spots.power_w().sum()) / side**2  # three times the mean flux of all the power on the receiver
    return spots, limit, side


def _aim_worker(n: int, threads: int, steps: int, queue) -> None:
    torch.set_num_threads(threads)
    base = _rss_mb()
    start = time.perf_counter()
    spots, limit, side = aim_scene(n)
    setup = time.perf_counter() - start
    centre = torch.zeros(n, 2, dtype=torch.float32)
    before = float(render(spots, centre).max())
    start = time.perf_counter()
    result = optimise(spots, centre, limit, region=1.0, steps=steps)
    seconds = time.perf_counter() - start
    patches = {g.shifted.shape[-1] - 1: len(g.members) for g in spots.groups}
    queue.put((setup, seconds, _rss_mb(), base, before / limit, result.peak_over_limit, result.feasible,
               result.on_receiver_w / float(spots.power_w().sum()), side, patches))


def aim(threads: int, sizes: tuple[int, ...] = AIM_SIZES, steps: int = 300) -> None:
    """The `aim` benchmark (module docstring)."""
    print(f"helioflow aim benchmark: 128x128 receiver, {steps} steps, {threads} threads, torch {torch.__version__}")
    print(f"{'heliostats':>10} {'receiver m':>10} {'setup s':>8} {'optimise s':>10} {'peak RSS MB':>12}"
          f" {'after imports MB':>17} {'centre peak':>11} {'peak':>6} {'keeps':>5} {'on receiver':>11}"
          "  patches (px: heliostats)")
    ctx = mp.get_context("spawn")
    for n in sizes:
        queue = ctx.Queue()
        proc = ctx.Process(target=_aim_worker, args=(n, threads, steps, queue))
        proc.start()
        setup, seconds, peak, base, before, after, feasible, kept, side, patches = queue.get()
        proc.join()
        print(f"{n:>10} {side:>10.1f} {setup:>8.1f} {seconds:>10.1f} {peak:>12.0f} {base:>17.0f} {before:>11.2f}"
              f" {after:>6.3f} {'yes' if feasible else 'no':>5} {kept:>11.1%}  {patches}")
    print("peaks as multiples of the limit (three times the mean flux of all the power on the receiver); "
          "on receiver: share of the spots' power the optimised aiming puts on the receiver")


def fit(dataset: str, heliostat: str, threads: int) -> None:
    """The `fit` benchmark (module docstring)."""
    from helioflow.config import load_config, validate_config
    from helioflow.data.hdf5 import read_dataset
    from helioflow.data.surfaces import read_heliostat
    from helioflow.models.physical import drt_effects
    from helioflow.models.physics_fit import FitSettings, Measurements, _Fitter, fit_effects
    from helioflow.physics.scene import dataset_scene
    from helioflow.scoring.recovery import surface_heights
    from helioflow.workflow import model_effects

    torch.set_num_threads(threads)
    ds, true = read_dataset(dataset), read_heliostat(heliostat).to("cpu")
    config = validate_config(load_config("config.yaml"))
    drt = config["networks"]["drt"]
    train = ds.indices("train")
    index = train[torch.linspace(0, len(train) - 1, min(len(train), drt["fit_images"])).round().long().numpy()]
    scale = float(ds.images[train].max())

    def split(i) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        return (torch.tensor(ds.images[i]) / scale, torch.tensor(ds.azimuth_deg[i]).float(),
                torch.tensor(ds.elevation_deg[i]).float())

    data = Measurements(*split(index), scale)
    design = true.ideal()
    shape = ds.images.shape[1:]
    exact = dataset_scene(design, ds.attrs, shape, drt["cells_per_side"], 100_000, fitting=True)
    predicting = dataset_scene(design, ds.attrs, shape, drt["cells_per_side"], 100_000, fitting=False)
    effects = drt_effects(model_effects(config, ds.attrs["dataset"]), design.n_facets)
    settings = FitSettings(steps=drt["fit_steps"], rounds=drt["rounds"], coarse_blur_px=drt["coarse_blur_px"],
                           facet_hops=drt["facet_hops"], pinned_hops=drt["pinned_hops"],
                           gauss_newton_steps=drt["gauss_newton_steps"])
    runs = {"the fit (config.yaml's drt)": (settings, predicting),
            "exact trace, rounds only": (FitSettings(steps=settings.steps, rounds=settings.rounds,
                                                      coarse_blur_px=settings.coarse_blur_px, linearised=False), exact)}
    traced, count = _Fitter.traced, [0]

    def counted(self, *args, **kwargs):
        count[0] += 1
        return traced(self, *args, **kwargs)

    _Fitter.traced = counted  # type: ignore[method-assign]  # counts the fit's traces
    truth = surface_heights(true.control_heights.double() * 1e3)
    print(f"{dataset}: {design.n_facets} facets, {len(index)} fit images, {threads} threads")
    for name, (s, scene_) in runs.items():
        count[0] = 0
        start = time.perf_counter()
        result = fit_effects(scene_, effects, data, s, finish=predicting)
        wall = time.perf_counter() - start
        scores = []
        for name_ in ("interpolation", "extrapolation"):
            images, az, el = split(ds.indices(name_))
            with torch.no_grad():
                predicted = predicting.simulate(result.effects, result.tensors, az, el, seed=1) / scale
            scores.append(f"{name_} {float(np.mean(metric_psnr(predicted.numpy(), images.numpy()))):.2f} dB")
        heights = surface_heights(result.tensors["surface"].double())
        error = float((heights - truth).pow(2).mean().sqrt() / truth.pow(2).mean().sqrt())
        print(f"  {name}: {wall:.0f} s, {count[0]} traces, held-out PSNR {', '.join(scores)}, "
              f"height error {error:.1%}")
    _Fitter.traced = traced  # type: ignore[method-assign]


def write_plant_dir(folder, n: int, template="examples/plant_world", images: int = 2) -> None:
    """A PAINT directory of n heliostats (folders H0000, H0001, ...) of the template's P000 design,
    pivots on a grid 8 m x 10 m north of the tower from 40 m, each with the first `images`
    calibrations of P000 (the PNGs linked, not copied)."""
    import shutil
    from pathlib import Path

    source, folder = Path(template), Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    shutil.copy(source / "tower-measurements.json", folder / "tower-measurements.json")
    tower = json.loads((source / "tower-measurements.json").read_text())
    lat0, lon0, _ = tower["power_plant_properties"]["coordinates"]
    props = json.loads((source / "P000" / "heliostat-properties.json").read_text())
    measured = sorted(source.glob("P000/*-calibration-properties.json"))[:images]
    columns = math.ceil(math.sqrt(n))
    for i in range(n):
        east, north = 8.0 * (i % columns - columns / 2), 40.0 + 10.0 * (i // columns)
        props["heliostat_position"] = [lat0 + north / 111_200.0,
                                       lon0 + east / (111_200.0 * math.cos(math.radians(lat0))),
                                       props["heliostat_position"][2]]
        target = folder / f"H{i:04d}"
        target.mkdir(exist_ok=True)
        (target / "heliostat-properties.json").write_text(json.dumps(props))
        for m in measured:
            shutil.copy(m, target / m.name)
            png = m.with_name(m.name.replace("-calibration-properties.json", "-flux.png"))
            (target / png.name).symlink_to(png.resolve())


def dag(heliostats: int) -> None:
    """The `dag` benchmark (module docstring)."""
    import re
    import subprocess
    import tempfile
    from pathlib import Path

    with tempfile.TemporaryDirectory() as tmp:
        start = time.perf_counter()
        write_plant_dir(Path(tmp) / "plant", heliostats)
        written = time.perf_counter() - start
        config = Path(tmp) / "dag.yaml"
        config.write_text(json.dumps({"experiment": "dag_bench", "datasets": {"plant": {"paint_dir": f"{tmp}/plant"}}}))
        start = time.perf_counter()
        run = subprocess.run(["snakemake", "-n", "all", "--quiet", "rules", "--configfile",
                              "workflow/variants/plant_demo.yaml", str(config)], capture_output=True, text=True)
        seconds = time.perf_counter() - start
    if run.returncode:
        raise SystemExit(f"snakemake -n failed:\n{run.stderr[-3000:]}")
    jobs = re.search(r"^total\s+(\d+)", run.stdout + run.stderr, re.MULTILINE)
    peak = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
    print(f"helioflow dag benchmark: plant_demo with {heliostats} heliostats, 2 images each (PAINT folders "
          f"written in {written:.1f} s)")
    print(f"snakemake -n all: {seconds:.1f} s, peak RSS {peak:.0f} MB, {jobs.group(1) if jobs else '?'} jobs planned")


def main(argv: list[str] | None = None) -> None:
    """`python -m helioflow.bench NAME`: run one benchmark."""
    ap = argparse.ArgumentParser(prog="python -m helioflow.bench", description=__doc__.splitlines()[0])
    ap.add_argument("name", choices=["raytrace", "field", "fit", "dag", "aim"])
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--reference-rays", type=int, default=10**8, help="raytrace: rays per reference image")
    ap.add_argument("--sizes", type=int, nargs="+", help="field, aim: heliostats per field (default: "
                    f"field {' '.join(map(str, FIELD_SIZES))}, aim {' '.join(map(str, AIM_SIZES))})")
    ap.add_argument("--steps", type=int, default=300, help="aim: optimiser steps")
    ap.add_argument("--device", default="cpu", help="field: cpu, cuda or auto")
    ap.add_argument("--json", metavar="PATH", help="field: also write the figures to PATH as JSON")
    ap.add_argument("--heliostats", type=int, default=2000, help="dag: heliostats of the plant")
    ap.add_argument("--dataset", default="results/default/datasets/semi_sphere.h5", help="fit: the dataset")
    ap.add_argument("--heliostat", default="results/default/surfaces/multi_facet.h5",
                    help="fit: the true heliostat the dataset was traced from")
    args = ap.parse_args(argv)
    if args.name == "field":
        field(args.threads, tuple(args.sizes or FIELD_SIZES), args.device, args.json)
    elif args.name == "aim":
        aim(args.threads, tuple(args.sizes or AIM_SIZES), args.steps)
    elif args.name == "fit":
        fit(args.dataset, args.heliostat, args.threads)
    elif args.name == "dag":
        dag(args.heliostats)
    else:
        raytrace(args.threads, args.reference_rays)


if __name__ == "__main__":
    main()
