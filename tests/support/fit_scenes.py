"""Small fit problems that the physics-model tests share (tests/models: test_physical, test_uncertainty,
test_planning): a one-facet scene before a 2 m target, a grid of sun positions, the images a world makes,
a surface problem with facets turned over, and photon-like noise."""

import torch

from helioflow.models.physics_fit import Measurements
from helioflow.physics.effects import REGISTRY
from helioflow.physics.heliostat import ideal_heliostat, without_planes
from helioflow.physics.scene import Scene
from helioflow.physics.target import Target

BUIE = {"kind": "buie", "csr": 0.1}


def scene(rows: int = 1, cols: int = 1, dtype=torch.float32, **kw) -> Scene:
    h = ideal_heliostat(rows=rows, cols=cols, width=1.0, height=1.0, gap=0.05, position=(0.0, 60.0, 0.0),
                        control_points=5, dtype=dtype)
    target = Target(torch.tensor([0.0, 0.0, 20.0], dtype=dtype), torch.tensor([0.0, 1.0, 0.0], dtype=dtype), 2.0, 2.0,
                    (32, 32))
    return Scene(h, target, 1000.0, cells_per_side=8, **kw)


def suns(n: int = 12, elevations: int = 3) -> tuple[torch.Tensor, torch.Tensor]:
    """n sun positions on a grid: azimuth -90..90 deg, elevation 15..80 deg."""
    az, el = torch.meshgrid(torch.linspace(-90.0, 90.0, n // elevations), torch.linspace(15.0, 80.0, elevations),
                            indexing="ij")
    return az.flatten(), el.flatten()


def measured(s: Scene, world: dict, tensors: dict | None = None, n: int = 12) -> Measurements:
    az, el = suns(n, 4 if n % 4 == 0 else 3)
    with torch.no_grad():
        images = s.simulate(world, tensors or {}, az, el)
    scale = float(images.max())
    return Measurements(images / scale, az, el, scale)


def negated_facets(rows: int, cols: int,
                   negated: int) -> tuple[Scene, torch.Tensor, Measurements, dict, torch.Tensor]:
    """A surface-only problem on rows x cols facets: (scene, true control heights (F, 5, 5) mm,
    plane-free, RMS about 0.5 mm, the images they make, the effect list that fits the surface, a start
    that is the truth with the heights of the first `negated` facets negated)."""
    s = scene(rows, cols)
    truth = without_planes(torch.randn(rows * cols, 5, 5, generator=torch.Generator().manual_seed(5))) * 0.5
    data = measured(s, {"sunshape": BUIE, "surface": {}}, {"surface": truth})
    start = truth.clone()
    start[:negated] = -truth[:negated]
    return s, truth, data, {"sunshape": BUIE, "surface": {"control_heights_mm": "fit"}}, start


TRACKING = {p.name: "fit" for p in REGISTRY["tracking"].parameters}


def noisy(clean: torch.Tensor, seed: int) -> torch.Tensor:
    """Images (peak 1) with noise growing with the signal (photon-like) over a read-noise floor."""
    g = torch.Generator().manual_seed(seed)
    return clean + torch.randn(clean.shape, generator=g) * (0.003 + 0.02 * clean.clamp_min(0).sqrt())
