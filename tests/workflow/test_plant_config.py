"""A plant's calibration data in one config entry (source: paint with heliostats: all, a glob or a
list), expanded after validation into one dataset per heliostat, and its errors."""

import re
import shutil
from pathlib import Path

import pytest
import yaml

from helioflow.config import validate_config
from helioflow.errors import ConfigError
from helioflow.workflow import (
    FOLD_KEY,
    PLANT_KEY,
    expand_config,
    import_paint_params,
    leave_one_out_groups,
    paint_heliostat_params,
    plant_groups,
)

REPO = Path(__file__).resolve().parents[2]
PAINT = REPO / "tests" / "data" / "paint"
# tests/data/paint: AA23 has measurements but no geometry, AA28 geometry but no measurements
CALIBRATABLE = ["AA31", "AA39", "AC43", "AD37", "AU46"]


def _config(plant: dict | None = None, **extra_datasets) -> dict:
    config = yaml.safe_load((REPO / "tests" / "workflow" / "tiny_config.yaml").read_text())
    config["datasets"]["jul"] = {"source": "paint", "paint_dir": str(PAINT), "resolution": [64, 64],
                                 **({"heliostats": "all"} if plant is None else plant)}
    config["datasets"].update(extra_datasets)
    return config


@pytest.mark.parametrize("selection, expected", [("all", CALIBRATABLE), ("AA*", ["AA31", "AA39"]),
                                                 (["AA39", "AA31"], ["AA39", "AA31"])])
def test_one_entry_becomes_one_dataset_per_heliostat_with_its_own_folder(selection, expected):
    config = expand_config(validate_config(_config({"heliostats": selection})))
    names = [f"jul_{h}" for h in expected]
    assert list(config["datasets"]) == ["scan", "sky", *names]  # in place of the entry, in order
    for name, heliostat in zip(names, expected):
        ds = config["datasets"][name]
        assert ds["heliostat"] == heliostat and ds[PLANT_KEY] == "jul" and "heliostats" not in ds
        assert import_paint_params(config, name)["heliostat"] == heliostat
    assert plant_groups(config) == {"jul": names}
    for heliostat in expected:  # each heliostat's geometry comes from its own folder (rule paint_heliostat)
        assert paint_heliostat_params(config, heliostat) == {"paint_dir": str(PAINT), "heliostat": heliostat}


def test_leave_one_out_splits_each_heliostat_of_the_plant():
    config = expand_config(validate_config(_config({"heliostats": ["AA31", "AC43"], "holdout": "leave_one_out"})))
    groups = leave_one_out_groups(config)
    assert sorted(groups) == ["jul_AA31", "jul_AC43"] and [len(groups[g]) for g in sorted(groups)] == [7, 2]
    assert all(config["datasets"][f][FOLD_KEY] == "jul_AA31" for f in groups["jul_AA31"])
    # each heliostat's whole dataset (every image: its calibration) stays in the plant; the folds score it
    assert plant_groups(config) == {"jul": ["jul_AA31", "jul_AC43"]}
    assert not any(FOLD_KEY in config["datasets"][d] for d in plant_groups(config)["jul"])


def test_a_plant_entry_without_heliostats_is_the_single_heliostat_entry_as_before():
    config = validate_config(_config({"heliostat": "AA39"}))
    assert expand_config(config)["datasets"]["jul"]["heliostat"] == "AA39"


@pytest.mark.parametrize("plant, message", [
    ({"heliostats": "ZZ*"}, "datasets.jul.heliostats: 'ZZ*' selects no heliostat folder of"),
    ({"heliostats": ["AA39", "XX99"]}, "datasets.jul.heliostats: 'XX99': no such heliostat folder in"),
    ({"heliostats": "all", "heliostat": "AA39"}, "takes heliostat (one folder of paint_dir) or heliostats"),
    ({}, "takes heliostat (one folder of paint_dir) or heliostats (a plant: all, a glob over the folders or a "
         "list of them), one of them"),
    ({"heliostats": []}, "datasets.jul.heliostats"),
])
def test_a_bad_plant_entry_names_the_key_and_what_was_expected(plant, message):
    with pytest.raises(ConfigError, match=message.replace("(", r"\(").replace(")", r"\)").replace("*", r"\*")
                       .replace("?", r"\?")):
        validate_config(_config(plant))


def test_a_heliostat_taken_from_two_paint_directories_or_a_name_taken_twice_is_refused(tmp_path):
    other = tmp_path / "paint"
    shutil.copytree(PAINT, other)
    clash = {"source": "paint", "paint_dir": str(other), "heliostat": "AA31"}
    with pytest.raises(ConfigError, match="one heliostat, one PAINT directory"):
        validate_config(_config(aa31=clash))
    taken = {"source": "paint", "paint_dir": str(PAINT), "heliostat": "AA39"}
    with pytest.raises(ConfigError, match="the generated name 'jul_AA39' is already a dataset"):
        expand_config(validate_config(_config(jul_AA39=taken)))


def test_a_traced_dataset_with_heliostats_is_told_the_key_is_for_paint():
    config = _config({"heliostat": "AA39"})
    config["datasets"]["scan"]["heliostats"] = "all"
    with pytest.raises(ConfigError, match="datasets.scan: key 'heliostats' is for PAINT datasets"):
        validate_config(config)


def test_every_heliostat_of_a_plant_takes_the_plant_fits_shared_effects():
    from helioflow.workflow import (
        diagnose_params,
        plant_shared_spec,
        results_dir,
        shared_inputs,
        train_inputs,
        train_params,
    )

    config = expand_config(validate_config(_config({"heliostats": ["AA31", "AA39"]})))
    config["networks"] = {"drt": {}, "gan": {}}
    spec = plant_shared_spec(config)
    assert [h["heliostat"] for h in spec["plants"]["jul"]] == ["AA31", "AA39"] and spec["sizes"] == {"jul": 2}
    assert spec["settings"]["heliostats"] == 30 and spec["plants"]["jul"][0]["effects"] == config["model"]["effects"]
    path = shared_inputs(config, "jul_AA31")[0]
    assert path == f"{results_dir(config)}/plant/shared.json"
    assert diagnose_params(config, "jul_AA39")["shared"] == {"path": path, "plant": "jul"}
    assert train_params(config, "jul_AA39", "drt")["shared"] == {"path": path, "plant": "jul"}
    assert train_inputs(config, "jul_AA39", "drt")["shared"] == [path]
    assert "shared" not in train_params(config, "jul_AA39", "gan")  # a network learns the images as they are
    assert "shared" not in diagnose_params(config, "sky") and shared_inputs(config, "sky") == []
    config["plant"] = {"shared": False}  # each heliostat alone: no plant fit
    assert shared_inputs(config, "jul_AA39") == [] and plant_shared_spec(config)["plants"] == {}
    assert "shared" not in diagnose_params(config, "jul_AA39")
    assert "shared" not in train_inputs(config, "jul_AA39", "drt")


def test_dry_run_fits_the_shared_effects_once_before_every_heliostats_fit_and_diagnosis(dry_run):
    config = _config({"heliostats": ["AA31", "AA39"]})
    config.update(networks={"drt": {}}, diagnosis={}, plant={"group_size": 1})  # the per-heliostat rules
    output = dry_run(config)
    inputs: dict[str, list[str]] = {}
    for rule, lines in re.findall(r"^rule (\w+):\n((?:\s+.*\n)+?)\s+output:", output, re.MULTILINE):
        found = re.search(r"input: (.+)", lines)
        inputs.setdefault(rule, []).append(found.group(1) if found else "")
    shared = "results/tiny/plant/shared.json"
    assert len(inputs["plant_shared"]) == 1  # one plant fit for the plant's heliostats
    assert all(shared in i for i in inputs["diagnose"] if "jul_" in i) and len(inputs["diagnose"]) == 4
    assert sum(shared in i for i in inputs["train"]) == 2  # the drt of each plant heliostat, not of scan / sky
    assert all(shared not in i for i in inputs["diagnose"] if "jul_" not in i)
    (flux,) = inputs["plant_flux"]  # the plant's flux map after both heliostats' fits
    assert "models/jul_AA31/drt.pt" in flux and "models/jul_AA39/drt.pt" in flux and "AA28/heliostat-properties" in flux


def test_the_plant_flux_map_takes_every_heliostat_with_geometry_and_each_calibrated_ones_fit():
    from helioflow.workflow import plant_flux_inputs, plant_flux_paths, plant_flux_spec, results_dir

    config = expand_config(validate_config(_config({"heliostats": ["AA31", "AA39"]})))
    config.update(networks={"drt": {}}, diagnosis={})
    r = results_dir(config)
    spec = plant_flux_spec(config)["jul"]
    assert spec["calibrated"] == [{"heliostat": h, "model_path": f"{r}/models/jul_{h}/drt.pt"}
                                  for h in ("AA31", "AA39")]
    assert spec["settings"]["receiver"] == "receiver" and spec["settings"]["aim"]["kind"] == "center"
    inputs = plant_flux_inputs(config, "jul")
    assert inputs[0] == str(PAINT / "tower-measurements.json")
    assert [Path(p).parent.name for p in inputs[1:5]] == ["AA28", "AA31", "AA39", "AC43"]  # AA28 raytraced ideal
    assert plant_flux_paths(config, "json") == [f"{r}/plant/flux/jul.json"]
    raw = _config({"heliostats": ["AA31", "AA39"]})
    raw.update(networks={"drt": {}}, diagnosis={}, plant={"flux": {
        "sun": {"dawn": {"azimuth_deg": 90.0, "elevation_deg": 5.0}}, "aim": {"kind": "vertical"}}})
    settings = plant_flux_spec(expand_config(validate_config(raw)))["jul"]["settings"]  # the aim's defaults: schema
    assert list(settings["sun"]) == ["dawn"] and settings["aim"] == {"kind": "vertical", "spread": 0.5, "levels": 3}
    config["plant"] = {"flux": False}
    assert plant_flux_spec(config) == {} and plant_flux_paths(config) == []
    with pytest.raises(ConfigError, match="no plant flux map for 'jul'"):
        plant_flux_inputs(config, "jul")


def test_the_plant_fit_takes_its_heliostats_evenly_and_reads_only_theirs():
    from helioflow.data.splits import evenly
    from helioflow.workflow import plant_shared_inputs, plant_shared_spec

    assert evenly(list(range(10)), 4) == [0, 3, 6, 9] and evenly([1, 2], 8) == [1, 2] and evenly([5, 6, 7], 1) == [5]
    config = expand_config(validate_config(_config({"heliostats": "all"})))
    config.update(networks={"drt": {}}, diagnosis={}, plant={"shared": {"heliostats": 2}})
    spec = plant_shared_spec(config)
    assert [h["heliostat"] for h in spec["plants"]["jul"]] == ["AA31", "AU46"] and spec["sizes"] == {"jul": 5}
    assert not any("AA39" in p for p in plant_shared_inputs(config))  # not taken: not an input


def test_a_plant_entry_without_fit_settings_of_its_own_takes_the_plants():
    """A plant's heliostats have few images each and the plant many heliostats: without settings of
    its own, every heliostat's drt fit and diagnosis take plant.fit's (workflow/variants/plant_demo's,
    which kept 85 heliostats an hour where config.yaml's gave 25), in groups of 3; the other datasets
    keep networks.drt and diagnosis as they are."""
    from helioflow.batch import plant_batches
    from helioflow.workflow import diagnose_params, train_params

    raw = _config({"heliostats": ["AA31", "AA39"]})
    raw.update(networks={"drt": {"fit_steps": 150, "rounds": 8, "facet_hops": 12}}, diagnosis={"fit_steps": 80})
    config = expand_config(validate_config(raw))
    drt = train_params(config, "jul_AA39", "drt")["settings"]
    assert {k: drt[k] for k in ("fit_steps", "rounds", "fit_images", "facet_hops", "pinned_hops")} == {
        "fit_steps": 40, "rounds": 2, "fit_images": 12, "facet_hops": 0, "pinned_hops": 0}
    assert {k: diagnose_params(config, "jul_AA39")["settings"][k] for k in ("fit_steps", "rounds")} == {
        "fit_steps": 30, "rounds": 1}
    assert train_params(config, "sky", "drt")["settings"]["fit_steps"] == 150  # not a plant's heliostat
    assert diagnose_params(config, "sky")["settings"]["fit_steps"] == 80
    assert plant_batches(config) == {"jul_g0": ["jul_AA31", "jul_AA39"]}

    raw["plant"] = {"fit": {"drt": {"fit_steps": 60}, "diagnosis": {}}, "group_size": 1}  # the plant's own
    config = expand_config(validate_config(raw))
    drt = train_params(config, "jul_AA39", "drt")["settings"]
    assert (drt["fit_steps"], drt["rounds"], drt["facet_hops"]) == (60, 8, 12)
    assert diagnose_params(config, "jul_AA39")["settings"]["fit_steps"] == 80 and plant_batches(config) == {}

    raw["plant"] = {"fit": {"drt": {"fit_step": 60}}}
    with pytest.raises(ConfigError, match=r"plant\.fit\.drt \(over networks\.drt\).*fit_step"):
        validate_config(raw)
