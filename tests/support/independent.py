"""The diagnosis on data it was not made for (tests/diagnosis/test_diagnose_independent.py and
test_diagnose_independent_pairs.py, one file each for the single and the combined cases so that
two workers share them): the cases, their runner and the assertions every case makes."""

from pathlib import Path

import numpy as np

from helioflow.data.paint import import_paint
from helioflow.diagnosis.diagnose import diagnose_dataset
from helioflow.workflow import DIAGNOSIS_DEFAULTS
from support.paint_world import World, write_paint_folder

N_IMAGES, HELD_OUT, RAYS = 24, 6, 400_000
BELIEVED = {"sunshape": {"kind": "gaussian", "sigma_mrad": 2.51}}  # the world's sun unless a case changes it
SETTINGS = {**DIAGNOSIS_DEFAULTS, "fit_images": N_IMAGES - HELD_OUT, "heldout_images": HELD_OUT}
_tilts = np.random.default_rng(5).normal(0.0, 2.0, (2, 4, 2))  # facet tilts (mrad) of the canting cases

CASES = {  # name: (world, the registry effects the diagnosis must name; None: an effect outside the registry)
    "none": (World(), set()),
    "tracking": (World(tracking_mrad=(1.2, -0.9)), {"tracking"}),
    "sun shape": (World(sun=("buie", 0.2)), {"sunshape"}),
    "slope error": (World(slope_mrad=1.5), {"slope_error"}),
    "canting": (World(canting_mrad=_tilts[0] - _tilts[0].mean(0)), {"canting"}),  # a mean tilt is tracking
    "surface": (World(bump=(1, 1.0, 0.25)), {"surface"}),
    "focusing facets": (World(focal_length_m=100.0), {"surface"}),  # curved facets, believed flat
    "camera": (World(camera=(0.03, 1.5)), {"camera"}),
    "camera blur": (World(camera=(0.0, 1.5)), {"camera"}),
    "camera blur after the counting": (World(counted_blur_px=1.5), {"camera"}),  # the noise smooth over pixels
    "none, rectified": (World(rectified=True), set()),  # resampled: noise correlated, nothing to find
    "canting + tracking": (World(canting_mrad=_tilts[1], tracking_mrad=(1.0, 0.8)),
                           {"canting", "tracking"}),
    "surface + camera": (World(bump=(2, 1.0, 0.25), camera=(0.03, 1.5)), {"surface", "camera"}),
    "tracking + slope error": (World(tracking_mrad=(1.0, -0.8), slope_mrad=1.5), {"tracking", "slope_error"}),
    "canting + camera": (World(canting_mrad=_tilts[1] - _tilts[1].mean(0), camera=(0.03, 1.5)),
                         {"canting", "camera"}),
    "neighbour shading": (World(neighbour_enu_m=(0.0, -3.5, 0.0)), None),  # 3.5 m south: shades at low sun
    "neighbour shading, position known": (World(neighbour_enu_m=(0.0, -3.5, 0.0)), {"neighbour_shading"}),
}
PUBLISHED = {"neighbour shading, position known"}  # the neighbour's folder is in the PAINT directory


COMBINED = {case for case, (_, hidden) in CASES.items() if hidden is not None and len(hidden) > 1}


def case_runner(root: Path):
    """case -> the diagnosis JSON of that case of CASES, made in a folder under `root` on first use."""
    done = {}

    def run(case: str) -> dict:
        if case not in done:
            folder = root / case.replace(" ", "_").replace("+", "and").replace(",", "")
            write_paint_folder(folder, CASES[case][0], n_images=N_IMAGES, rays=RAYS, seed=1,
                               neighbour="AA40" if case in PUBLISHED else None)
            ids = [str(100_000 + i) for i in range(N_IMAGES)]
            held = list(np.random.default_rng(0).choice(ids, HELD_OUT, replace=False))
            import_paint(folder, "AA39", folder / "data.h5", folder / "aa39.h5", holdout=held, dataset=case)
            settings = {**SETTINGS, "max_effects": max(1, len(CASES[case][1] or ()))}  # as many as are hidden
            done[case] = diagnose_dataset(folder / "data.h5", folder / "aa39.h5", BELIEVED, settings,
                                          folder / "diagnosis.json", None, folder / "ledger.json")
        return done[case]

    return run


def check_case(case: str, result: dict) -> None:
    """The assertions every case makes (tests/diagnosis/test_diagnose_independent*.py: module doc there)."""
    hidden, remaining = CASES[case][1], result["remaining"]
    named = [r for r in result["ranking"] if r["meaningful"]]
    summary = ([(r["effect"], round(r["relative_reduction"], 3), [c["effect"] for c in r["confounded_with"]])
                for r in result["ranking"][:4]], remaining, result["noise_floor"])
    if hidden is None:  # outside the registry
        assert not remaining["explained"] and remaining["over_noise"] >= 2.0, summary
        assert result["verdict"].startswith(f"A residual {remaining['over_noise']:.1f} times the noise"), \
            result["verdict"]
        location = result["location"]
        mirror = location["mirror"]
        assert "the lower third of every facet" in mirror["where"], mirror["where"]  # the lower part sends less
        rows = {r["row"]: [] for r in mirror["regions"][:9]}
        for r, w in zip(mirror["regions"][:9], mirror["pattern"]["affected"]):
            rows[r["row"]].append(w)
        assert np.mean(rows["lower"]) < np.mean(rows["upper"]) - 0.2, rows
        low, high = location["sun_position"]["elevation_deg"][0], location["sun_position"]["elevation_deg"][-1]
        assert low["over_noise"] > 2.0 * high["over_noise"], location["sun_position"]  # at low sun
        return
    assert remaining["explained"], summary
    if not hidden:
        assert not named, summary
        assert result["verdict"].startswith("Explained down to the noise"), result["verdict"]
        assert result["heldout_error"] / 1.5 <= result["noise_floor"] <= 1.5 * result["heldout_error"], summary
        return
    alike = {c["effect"] for r in named for c in r["confounded_with"]}
    assert hidden <= {r["changes"] for r in named} | {a.split(":")[0] for a in alike}, summary
    assert named[-1]["heldout_error_after"] <= 0.5 * result["heldout_error"], summary
    for r in named:
        for c in r["confounded_with"]:  # a confounded pair: the verdict names both and what separates them
            assert c["effect"].replace("_", " ") in result["verdict"] and c["separated_by"] in result["verdict"]
