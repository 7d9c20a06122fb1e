"""The diagnosis: a world with an effect the model lacks gets that effect ranked first, and fitting
it cuts the held-out error by at least half; a model that matches the world raises no alarm."""

import itertools
from dataclasses import replace

import numpy as np
import pytest
import torch

from helioflow.diagnosis.candidates import candidates, implausible, separating
from helioflow.diagnosis.criteria import SIGNIFICANCE, THRESHOLD
from helioflow.diagnosis.diagnose import ROUNDING, Diagnosis
from helioflow.diagnosis.ledger import update_ledger
from helioflow.diagnosis.verdict import model_flags, verdict
from helioflow.models.physics_fit import FitSettings, Measurements
from helioflow.physics.heliostat import Heliostat, ideal_heliostat, without_planes
from helioflow.physics.scene import Scene
from helioflow.physics.target import Target

BUIE = {"kind": "buie", "csr": 0.1}
SETTINGS = FitSettings(steps=100, rounds=2, search_iterations=12)


def true_heliostat() -> Heliostat:
    """2 x 2 parallel facets with seeded canting (1.5 mrad) and surface (1 mm) errors. Parallel,
    not focused: the images of focused facets overlap on the target, which facet carries which
    tilt is then ambiguous, and a canting fit finds a permutation of the true tilts."""
    h = ideal_heliostat(rows=2, cols=2, width=1.0, height=1.0, gap=0.05, position=(0.0, 60.0, 0.0),
                        control_points=5, dtype=torch.float32)
    g = torch.Generator().manual_seed(3)
    tilts = torch.randn(4, 2, generator=g) * 1.5e-3
    heights = without_planes(torch.randn(4, 5, 5, generator=g).double()).float() * 1e-3
    return replace(h, canting_error=tilts - tilts.mean(0), control_heights=heights)


def sun_grid() -> tuple[torch.Tensor, torch.Tensor]:
    az, el = torch.meshgrid(torch.linspace(-60.0, 60.0, 6), torch.linspace(20.0, 70.0, 5), indexing="ij")
    return az.flatten(), el.flatten()


def diagnosis(world: dict, model: dict, noise: float = 0.0, max_effects: int = 2) -> Diagnosis:
    """World images traced with the true heliostat (plus Gaussian noise, a fraction of the
    dataset's peak); the model traces the design (ideal) one. The 4 m target holds the 2 m
    heliostat's whole spot, as a calibration target does: a spot cut by the image edge would
    change its shape as it moves."""
    h = true_heliostat()
    target = Target(torch.tensor([0.0, 0.0, 20.0]), torch.tensor([0.0, 1.0, 0.0]), 4.0, 4.0, (32, 32))
    az, el = sun_grid()
    with torch.no_grad():
        images = Scene(h, target, 1000.0, cells_per_side=8).simulate(world, {}, az, el)
    scale = float(images.max())
    images = images + noise * scale * torch.randn(images.shape, generator=torch.Generator().manual_seed(5))
    held = torch.arange(len(az)) % 3 == 0
    train = Measurements(images[~held] / scale, az[~held], el[~held], scale)
    heldout = Measurements(images[held] / scale, az[held], el[held], scale)
    return Diagnosis(Scene(h.ideal(), target, 1000.0, cells_per_side=8), model, train, heldout, SETTINGS,
                     max_effects)


CASES = {
    "sunshape": ({"sunshape": {"kind": "gaussian", "sigma_mrad": 3.0}, "slope_error": {"sigma_mrad": 0.5}},
                 {"slope_error": {"sigma_mrad": 0.5}}),
    "slope_error": ({"sunshape": BUIE, "slope_error": {"sigma_mrad": 2.0}}, {"sunshape": BUIE}),
    "tracking": ({"sunshape": BUIE, "tracking": {"axis1_offset_mrad": 2.0, "pedestal_tilt_east_mrad": -1.5}},
                 {"sunshape": BUIE}),
    "canting": ({"sunshape": BUIE, "canting": {}}, {"sunshape": BUIE}),
    "surface": ({"sunshape": BUIE, "surface": {}}, {"sunshape": BUIE}),
    "camera": ({"sunshape": BUIE, "camera": {"background_w_m2": 3000.0, "blur_px": 1.5}}, {"sunshape": BUIE}),
}


@pytest.mark.slow
@pytest.mark.parametrize("hidden", list(CASES))
def test_a_hidden_effect_is_ranked_first_and_fitting_it_halves_the_heldout_error(hidden):
    world, model = CASES[hidden]
    ranking = diagnosis(world, model, max_effects=1).rank().entries  # the best single change
    top = ranking[0]
    assert top["effect"] == hidden, [(r["effect"], round(r["relative_reduction"], 3)) for r in ranking]
    assert top["relative_reduction"] >= 0.5
    assert top["meaningful"]


@pytest.mark.slow
def test_two_hidden_effects_take_the_top_two_places():
    """Tracking and canting: one moves the whole spot, the other the facets' images apart. Fitted
    alone, the flexible surface mimics both in part and wins; the best pair, both needed, beats it,
    and adding the two cuts the held-out error by at least half."""
    world = {"sunshape": BUIE, "tracking": {"axis2_offset_mrad": 2.5}, "canting": {}}
    ranked = diagnosis(world, {"sunshape": BUIE}).rank()
    before, ranking = ranked.before, ranked.entries
    summary = [(r["effect"], round(r["relative_reduction"], 3), r["meaningful"]) for r in ranking]
    assert {r["effect"] for r in ranking[:2]} == {"canting", "tracking"}, summary
    assert ranking[0]["meaningful"] and ranking[1]["meaningful"], summary
    assert ranking[1]["added_to"] == [ranking[0]["effect"]]
    assert ranking[1]["heldout_error_after"] <= 0.5 * before, summary


@pytest.mark.slow
def test_a_model_that_matches_the_world_raises_no_alarm():
    """The measurements carry 2 % noise: fitting more parameters must not pass as a finding."""
    world = {"sunshape": BUIE, "slope_error": {"sigma_mrad": 1.0}}
    d = diagnosis(world, world, noise=0.02)
    ranking = d.rank().entries
    assert not any(r["meaningful"] for r in ranking), [(r["effect"], r["relative_reduction"]) for r in ranking]
    assert all(len(key) <= 1 for key in d.scores)  # no single change helps alone: no pair is fitted
    remaining = d.remaining([])  # what is left is the noise, and the noise floor says so
    assert remaining["explained"], remaining
    assert remaining["error"] / 1.5 <= remaining["noise_floor"] <= 1.5 * remaining["error"], remaining


def test_scale_effects_are_not_identifiable_and_ranked_last():
    world = {"sunshape": BUIE, "reflectivity": {"value": 0.8}}
    d = diagnosis(world, {"sunshape": BUIE})
    d.tried = [c for c in d.tried if c.label in ("reflectivity", "slope_error")]
    ranking = d.rank().entries
    assert [r["effect"] for r in ranking] == ["slope_error", "reflectivity"]
    assert ranking[1]["identifiable"] is False and not ranking[1]["meaningful"]
    assert ranking[1]["fitted"]["value"] == pytest.approx(0.8, abs=0.01)  # the scale is still measured


@pytest.mark.slow
def test_adding_a_candidate_never_raises_the_training_loss():
    """Nested fits: a model with one change more starts from the smaller model's optimum (the added
    effect at values that do nothing, a freed value at the model's) and ends no worse on the train
    split; a pair ends no worse than either of its members alone."""
    world = {"sunshape": BUIE, "slope_error": {"sigma_mrad": 1.0}, "tracking": {"axis1_offset_mrad": 1.0}}
    d = diagnosis(world, {"sunshape": BUIE})

    def loss(labels) -> float:
        return d.fit(labels).history[-1]

    nested = [c.label for c in d.tried if c.neutral is not None]
    assert {"tracking", "slope_error", "camera", "sunshape: fit csr"} <= set(nested)
    for label in nested:
        assert loss([label]) <= loss([]) * (1.0 + ROUNDING), label  # no worse, up to rounding
    assert loss(["tracking", "slope_error"]) <= min(loss(["tracking"]), loss(["slope_error"])) * (1.0 + ROUNDING)


def test_the_ledger_keeps_revisions_in_order_replaces_a_rerun_and_marks_the_current(tmp_path):
    path = tmp_path / "ledger.json"
    update_ledger(path, "d1", {"sunshape": BUIE}, 0.2)
    update_ledger(path, "d1", {"sunshape": BUIE, "tracking": {"axis1_offset_mrad": "fit"}}, 0.1)
    ledger = update_ledger(path, "d1", {"sunshape": BUIE}, 0.19)  # back to the first model: a new revision
    assert [(e["revision"], e["heldout_error"], e["current"]) for e in ledger] == [
        (1, 0.2, False), (2, 0.1, False), (3, 0.19, True)]
    assert update_ledger(path, "d2", {}, 0.5)[0]["revision"] == 1  # other measurements, own ledger
    rerun = update_ledger(path, "d1", {"sunshape": BUIE}, 0.18)  # the same model again: replaces revision 3
    assert [(e["revision"], e["heldout_error"]) for e in rerun][-1] == (3, 0.18) and len(rerun) == 3
    assert np.isclose(rerun[-1]["heldout_error"], 0.18)


def test_candidates_free_a_present_effect_and_switch_the_sun():
    """A fixed slope error is freed, a Gaussian sun gets its width freed and a Buie sun tried; an
    absent effect is added; a one-facet heliostat gets no canting."""
    tried, skipped = candidates({"sunshape": {"kind": "gaussian", "sigma_mrad": 2.5},
                                 "slope_error": {"sigma_mrad": 0.5}}, n_facets=1)
    by_label = {c.label: c for c in tried}
    assert by_label["slope_error: fit sigma_mrad"].change == "free"
    assert by_label["slope_error: fit sigma_mrad"].neutral == {"sigma_mrad": 0.5}
    assert by_label["sunshape: fit sigma_mrad"].params == {"kind": "gaussian", "sigma_mrad": "fit"}
    assert by_label["sunshape: buie"].change == "switch" and by_label["sunshape: buie"].neutral is None
    assert by_label["tracking"].change == "add"
    assert "canting" not in by_label
    assert {s["effect"] for s in skipped} == {"canting", "blocking_shading", "neighbour_shading"}  # no neighbours known


def test_implausible_values_are_flagged_and_confounded_pairs_get_their_separating_measurement():
    assert implausible({"slope_error.sigma_mrad": 5.0, "camera.blur_px": 1.0, "tracking.axis1_offset_mrad": -12.0}) \
        == ["slope_error.sigma_mrad = 5 (a slope error of several mrad (heliostat mirrors: ~1-2.5 mrad))",
            "tracking.axis1_offset_mrad = -12 (tracking offsets of more than 10 mrad)"]
    assert "target distance" in separating("camera", "slope_error") == separating("slope_error", "camera")
    assert "sun shape" in separating("sunshape", "slope_error")


@pytest.mark.slow
def test_a_slope_error_and_a_wider_sun_are_confounded_by_their_correlation_with_sun_positions_that_separate_them():
    """Both widen the spot alike (a Gaussian sun and Gaussian slope errors add in quadrature; only
    the incidence angle's foreshortening of the slope error tells them apart): at their joint fit
    the two parameters correlate almost fully, and the separating measurement names sun positions."""
    world = {"sunshape": {"kind": "gaussian", "sigma_mrad": 2.5}, "slope_error": {"sigma_mrad": 1.5}}
    d = diagnosis(world, {"sunshape": {"kind": "gaussian", "sigma_mrad": 2.5}}, noise=0.01)
    ranked = d.rank()
    ranking, selected = ranked.entries, ranked.selected
    top = ranking[0]
    assert top["meaningful"] and top["changes"] in ("slope_error", "sunshape"), ranking[:2]
    partner = "sunshape: fit sigma_mrad" if top["changes"] == "slope_error" else "slope_error"
    alike = {c["effect"]: c for c in top["confounded_with"]}
    assert partner in alike, top["confounded_with"]
    assert alike[partner]["correlation"] > 0.95
    words = alike[partner]["separated_by"]  # the best sun positions, and whether they separate the two
    assert words.startswith(("images at the sun positions (azimuth", "no calibration image separates them")), words
    assert "correlation" in words
    found = d.correlation(top["effect"], partner, selected)
    assert found is not None and found[0] == pytest.approx(alike[partner]["correlation"], abs=1e-3)


@pytest.mark.parametrize("surface_pair, named", [(0.0136, "canting"), (0.0060, "surface")])
def test_a_surface_gives_way_to_a_rigid_change_the_images_do_not_tell_from_it(surface_pair, named):
    """The held-out errors of the 30-heliostat plant's P012 (a canting error): surface + tracking
    0.0136, canting + tracking 0.0137, a noise floor of 0.0077. Half a floor apart or less, the
    images do not tell the two apart and the rigid canting is named; a surface a floor below it (a
    bump) stays named. The errors are set, not fitted: this is the selection rule alone."""
    d = diagnosis({"sunshape": BUIE}, {"sunshape": BUIE})
    labels = [c.label for c in d.tried]
    d.scores = {frozenset(s): 0.03 for k in (1, 2) for s in itertools.combinations(labels, k)}
    d.scores |= {frozenset(): 0.1, frozenset({"tracking"}): 0.02, frozenset({"canting", "tracking"}): 0.0137,
                 frozenset({"surface", "tracking"}): surface_pair}
    d.floors = {key: (0.0077, 0.0) for key in d.scores}
    d.covariances = {key: None for key in d.scores}  # no significance test: the held-out errors decide
    assert d.free_parameters(["surface"]) > 64 >= d.free_parameters(["canting", "tracking"], with_model=True)
    assert d.select() == ["tracking", named]


@pytest.mark.slow
def test_a_slope_error_that_hardly_moves_the_misplaced_flux_is_named_by_its_fitted_value():
    """Under a camera blur of 1.5 px a slope error of 0.5 mrad widens the spot's edges by a few per
    cent: its held-out cut of the misplaced flux (averaged with 2 % noise over every pixel) is far
    below THRESHOLD, yet its fitted value stands many sigma from 0 (the Wald test), so it is named,
    and the verdict says why; a candidate that does nothing (soiling here) is not listed as standing
    in for it, although it ends as close (canting, itself significant beside tracking, may be). The
    same world without it names tracking alone."""
    camera = {"blur_px": 1.5, "background_w_m2": 0.0}
    for slope in (0.5, 0.0):
        world = {"sunshape": BUIE, "camera": camera, "tracking": {"axis1_offset_mrad": 2.0},
                 **({"slope_error": {"sigma_mrad": slope}} if slope else {})}
        d = diagnosis(world, {"sunshape": BUIE, "camera": camera}, noise=0.02)
        d.tried = [c for c in d.tried if c.label in ("tracking", "slope_error", "canting", "soiling")]
        ranked = d.rank()
        ranking, selected = ranked.entries, ranked.selected
        summary = [(r["effect"], round(r["relative_reduction"], 3), r["significance"]) for r in ranking]
        if not slope:
            assert selected == ["tracking"], summary
            continue
        assert selected == ["tracking", "slope_error"], summary
        entry = ranking[1]
        assert entry["relative_reduction"] < THRESHOLD and entry["significance"]["p"] < SIGNIFICANCE, summary
        alike = {c["effect"] for c in entry["confounded_with"]}
        assert "soiling" not in alike, entry["confounded_with"]  # ends as close, doing nothing: no stand-in
        assert 0.5 * slope < entry["fitted"]["sigma_mrad"] < 1.5 * slope, entry["fitted"]  # 0.34 here: the short
        #                                                       fit ends low (not investigated)
        remaining = d.remaining(selected)
        text = verdict(ranking, {"width": "3% wider", "centroid": 2.0}, remaining, {})
        assert "slope error" in text and "too little to count alone" in text and "Wald" in text, text
        assert entry["named_for"] == "significance" and ranking[0]["named_for"] == "cut", summary
        assert ("does not determine" in text) == (not entry["significance"]["determined"]), text


def test_the_verdict_names_a_model_value_stretched_beyond_its_physical_range():
    """The real heliostats' model ends with the Buie sun's circumsolar ratio at its bound (0.3995):
    the verdict says it stands in for something the model lacks; a value in range says nothing."""
    words = model_flags({"sunshape.csr": 0.3995, "camera.gain": 0.0005})
    assert words == (" The model's own fitted sunshape.csr = 0.3995 (a circumsolar ratio beyond that of the haziest "
                     "measured skies (~0.35)) is implausible: it likely stands in for what the model lacks.")
    assert model_flags({"sunshape.csr": 0.1, "slope_error.sigma_mrad": 1.5}) == ""



def test_the_verdict_judges_the_named_changes_at_their_joint_fit_not_each_alone():
    """A surface fitted alone to a spot moved by a tracking error bends far (the README's first run:
    3.2 mm RMS against the true 0.44 mm) and is then needed beside tracking; the config lines make the
    joint model, whose values are the ones judged: plausible there, no flag; implausible there, flagged."""
    def entry(effect: str, base: list[str], fitted: dict) -> dict:
        return {"effect": effect, "changes": effect, "change": "add", "fitted": fitted, "added_to": base,
                "heldout_error_before": 0.19, "heldout_error_after": 0.06, "relative_reduction": 0.68,
                "meaningful": True, "named_for": "cut", "confounded_with": [], "config": f"{effect}: {{}}"}

    ranking = [entry("surface", [], {"control_heights_mm_rms": 3.19}),
               entry("tracking", ["surface"], {"axis1_offset_mrad": -0.53})]
    remaining = {"explained": True, "error": 0.002, "over_noise": 1.1, "noise_floor": 0.002, "model_resolution": None}
    joint = {"surface.control_heights_mm_rms": 0.45, "tracking.axis1_offset_mrad": -0.53}
    assert "implausible" not in verdict(ranking, {}, remaining, {}, joint)
    text = verdict(ranking, {}, remaining, {}, {**joint, "surface.control_heights_mm_rms": 3.4})
    assert "The fitted surface.control_heights_mm_rms = 3.4 (surface deformations of more than 3 mm RMS) is " \
           "implausible" in text
