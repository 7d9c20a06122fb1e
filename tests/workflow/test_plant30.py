"""Issue 38's acceptance on an independent plant of 30 heliostats, end to end: tests/support/paint_world.py
draws and writes it (AA39's design, 4 facets, 30 calibration images each, 8-bit, one Gaussian sun and
one camera with background and blur, each heliostat its own hidden effects; not helioflow's tracer),
`snakemake -j2 all` runs the plant demo's settings on it (workflow/variants/plant_demo.yaml, groups of
15), and tests/support/plant_truth.py scores the run against the generator's truth: the named effects right
for at least 90 % of the heliostats, the camera named as shared, the pointing recovered within 0.1
mrad RMS.

About 30 minutes on two cores (27 min 13 s for seed 21 on 2026-11-28: the images 6, the pipeline 21),
too long for every CI run (the 6-heliostat demo's checks run there): it runs where HELIOFLOW_PLANT30=1,
on the plant drawn with HELIOFLOW_PLANT30_SEED (default 21; docs/results.md has seeds 21 and 22).
HELIOFLOW_PLANT30_CANTING="1 2" draws the cantings' RMS from 1-2 mrad instead of 0.5-1 and holds the
plant to issue "Real images"' bars instead of the named-right share: canting named on at least 90 % of
the heliostats that carry one, and the true pointing within 2σ of the fitted one on at least 90 %. Its
named-right share is printed, not held (25 of 30 on seed 21: the cantings widen 28 of the 30 spots, the
shared camera blur lies 0.15 px high and hides half the slope errors; docs/results.md).
"""

import json
import os

import pytest
import yaml
from support.paint_world import plant_worlds, write_plant
from support.pipeline import REPO, _workdir, snakemake
from support.plant_truth import score

HELIOSTATS, IMAGES, RAYS = 30, 30, 500_000
BAR = {"named_right": 0.9, "pointing_recovered_rms_mrad": 0.1}
LARGE_CANTING_BAR = {"canting_named": 0.9, "pointing_covered": 0.9}  # cantings of 1-2 mrad (module doc)


@pytest.mark.skipif(not os.environ.get("HELIOFLOW_PLANT30"), reason="30 minutes: set HELIOFLOW_PLANT30=1 to run")
@pytest.mark.slow
def test_a_plant_of_30_independent_heliostats_is_diagnosed_right_with_its_camera_shared(tmp_path):
    seed = int(os.environ.get("HELIOFLOW_PLANT30_SEED", "21"))
    canting = tuple(float(v) for v in os.environ.get("HELIOFLOW_PLANT30_CANTING", "0.5 1").split())
    paint = tmp_path / "paint"
    write_plant(paint, plant_worlds(HELIOSTATS, seed, canting_rms_mrad=canting), IMAGES, RAYS, seed)
    workdir = _workdir(tmp_path / "run")
    (workdir / "config.yaml").symlink_to(REPO / "config.yaml")
    variant = {"experiment": "plant30", "datasets": {"plant": {"paint_dir": str(paint)}}, "plant": {"group_size": 15}}
    (workdir / "plant30.yaml").write_text(yaml.safe_dump(variant))
    proc = snakemake(workdir, "-j2", "all", "--configfile", str(REPO / "workflow/variants/plant_demo.yaml"),
                     "plant30.yaml", timeout=5400)
    assert proc.returncode == 0, proc.stderr[-3000:]
    out = score(workdir / "results/plant30", paint, "plant", "drt", seed, canting)
    misses = [(r["heliostat"], r["hidden"], r["named"]) for r in out["heliostats"] if not r["right"]]
    print(json.dumps({k: out[k] for k in ("named_right", "canting_named", "pointing_recovered_rms_mrad",
                                          "pointing_over_sigma_median", "pointing_covered", "shared_changes")}), misses)
    print(json.dumps(out["heliostats"]))
    if min(canting) >= 1.0:  # cantings of 1 mrad and more: issue "Real images"
        assert out["canting_named"] >= LARGE_CANTING_BAR["canting_named"], misses
        assert out["pointing_covered"] >= LARGE_CANTING_BAR["pointing_covered"], out["heliostats"]
    else:
        assert out["named_right"] >= BAR["named_right"], misses
    assert "camera" in out["shared_changes"], out["shared_changes"]
    assert out["pointing_recovered_rms_mrad"] <= BAR["pointing_recovered_rms_mrad"], out["heliostats"]
