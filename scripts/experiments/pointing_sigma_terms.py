"""The fitted pointing's sigma of heliostats of a plant30 run (tests/support/plant_truth.pointing_sigma),
as stored and with the fit's covariance recomputed (models/uncertainty.py) without the facets'
systematic term, at unit misfit (no inflation of the residual's spectrum by the misfit), and with
neither: which term makes the sigma.

Run: python scripts/experiments/pointing_sigma_terms.py RUN/results/plant30 P010 P006   (about a minute each)
"""

from __future__ import annotations

import argparse
import sys
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "tests"))
from support.plant_truth import pointing_sigma  # noqa: E402

from helioflow.data.hdf5 import read_dataset  # noqa: E402
from helioflow.models import uncertainty  # noqa: E402
from helioflow.models.physics_fit import Measurements, with_uncertainty  # noqa: E402
from helioflow.models.registry import load_model  # noqa: E402


@contextmanager
def without(systematic: bool, misfit: bool):
    """models/uncertainty.py with the facets' systematic term and / or the misfit's inflation switched off."""
    kept = uncertainty._systematic, uncertainty.ring_spectrum
    if systematic:
        uncertainty._systematic = lambda h, *args, **kwargs: np.zeros_like(h)
    if misfit:
        uncertainty.ring_spectrum = lambda whitened, unit_mean=1.0: kept[1](whitened, unit_mean=1.0)
    try:
        yield
    finally:
        uncertainty._systematic, uncertainty.ring_spectrum = kept


def terms(results: Path, heliostat: str) -> dict[str, float]:
    """{term switched off: the pointing's sigma (mrad)} of one heliostat's drt fit."""
    model, _ = load_model(results / "models" / f"plant_{heliostat}" / "drt.pt")
    ds = read_dataset(results / "datasets" / f"plant_{heliostat}.h5")
    train = ds.indices("train")
    index = train[np.linspace(0, len(train) - 1, min(len(train), model.config.fit_images)).round().astype(int)]
    measured = Measurements(torch.as_tensor(ds.images[index]).float() / model.scale,
                            torch.as_tensor(ds.azimuth_deg[index]).float(),
                            torch.as_tensor(ds.elevation_deg[index]).float(), model.scale)
    stored = model.fitted
    out = {"misfit": stored.uncertainty.misfit}
    for label, switched in [("as stored", None), ("no systematic", (True, False)), ("unit misfit", (False, True)),
                            ("neither", (True, True))]:
        if switched is not None:
            with without(*switched):
                model.fitted = with_uncertainty(model.scene(), stored, measured, model.fit_settings().loss)
        out[label] = pointing_sigma(model, ds.azimuth_deg, ds.elevation_deg, ds.attrs["target_center_m"])
        model.fitted = stored
    return out


def main() -> None:
    """Parse the command line and print each heliostat's terms."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("results", type=Path)
    ap.add_argument("heliostats", nargs="+")
    args = ap.parse_args()
    torch.set_num_threads(1)
    for heliostat in args.heliostats:
        print(heliostat, {k: round(v, 4) for k, v in terms(args.results, heliostat).items()}, flush=True)


if __name__ == "__main__":
    main()
