"""The field section: validation, its expansion into heliostat and dataset entries for the existing
rules, the rule helpers of compose_field, and the DAG (dry run; one real run on the tiny field)."""

import copy
import math
import shutil
from pathlib import Path

import pytest
import yaml
from support.pipeline import _scheduled, _workdir, snakemake

from helioflow.config import load_config, validate_config
from helioflow.errors import ConfigError
from helioflow.physics.layout import min_spacing, nearest_distances
from helioflow.workflow import (
    all_targets,
    compose_field_inputs,
    compose_field_params,
    expand_field,
    field_measured,
    field_positions,
    metrics_paths,
    report_inputs,
    trace_params,
    train_params,
)

HERE = Path(__file__).resolve().parent
REPO = HERE.parents[1]


def tiny_field() -> dict:
    """tests/workflow/tiny_config.yaml with tiny_field.yaml layered over it (as --configfile does)."""
    config = yaml.safe_load((HERE / "tiny_config.yaml").read_text())
    config.update(yaml.safe_load((HERE / "tiny_field.yaml").read_text()))
    return config


@pytest.fixture(scope="module")
def default():
    return load_config(REPO / "config.yaml")


@pytest.fixture
def tiny():
    return validate_config(tiny_field())


def test_the_default_field_expands_into_heliostats_with_their_own_positions_and_seeds(default):
    config = expand_field(default)
    template = default["heliostats"]["square"]
    positions = field_positions(default["field"], template)
    assert len(positions) == 50
    names = [h for h in config["heliostats"] if h.startswith("field_")]
    assert names == field_measured(default)  # only the measured ones need a heliostat file (surfaces rule)
    for name in names:
        i = int(name.removeprefix("field_"))
        entry = config["heliostats"][name]
        assert entry["seed"] == 1000 + i and entry["position_m"] == positions[i]
        assert {k: v for k, v in entry.items() if k not in ("position_m", "seed")} == {
            k: v for k, v in template.items() if k not in ("position_m", "seed")
        }
    params = compose_field_params(config)["heliostats"]
    assert params["names"] == [f"field_{i:03d}" for i in range(50)] and params["positions_m"] == positions
    assert params["seeds"] == [1000 + i for i in range(50)]
    import torch

    pos = torch.tensor(positions, dtype=torch.float64)
    assert (pos[:, 2] == 2.0).all()
    assert (pos[:, :2].norm(dim=-1) >= 45.0 - 1e-3).all()
    assert nearest_distances(pos).min() >= min_spacing(2.0, 2.0, 2.0) - 2e-3  # positions rounded to the mm
    assert config["datasets"].keys() - default["datasets"].keys() == set(field_measured(default))
    assert default == load_config(REPO / "config.yaml")  # expansion works on a copy


def test_measured_heliostats_get_calibration_datasets_with_the_field_world(default):
    config = expand_field(default)
    measured = field_measured(default)
    assert len(measured) == round(0.2 * 50)
    assert measured == field_measured(copy.deepcopy(default))  # seeded
    ds = config["datasets"][measured[0]]
    assert ds["heliostat"] == measured[0] and ds["sun"] == default["field"]["calibration"]["sun"]
    params = trace_params(config, measured[0])
    assert params["world_effects"]["attenuation"] == {"model": "vittitoe_biggs_clear"}
    assert "blocking_shading" not in params["world_effects"]  # acts in field traces only
    assert params["target"] == default["target"]


def test_only_the_field_network_is_trained_on_the_field_datasets(default):
    config = expand_field(default)
    measured = set(field_measured(default))
    network = default["field"]["network"]
    assert not any(p.split("/")[3] in measured for p in metrics_paths(config))
    inputs = report_inputs(config)
    assert not any(
        p.split("/")[3] in measured for p in inputs["samples"] + inputs["psnr"] + inputs["diagnosis"]
    )
    assert {"results/default/field/flux.png", "results/default/field/metrics.json"} <= set(inputs["field"])
    assert all_targets(config) == ["results/default/report.html"]
    models = compose_field_inputs(config)["models"]
    assert models == [f"results/default/models/{m}/{network}.pt" for m in sorted(measured)]
    assert train_params(config, min(measured), network)["network"] == network


def test_indices_choose_the_measured_heliostats_and_a_list_layout_its_positions(tiny):
    config = expand_field(tiny)
    assert field_measured(tiny) == ["field_001", "field_003"]
    assert config["heliostats"]["field_003"]["position_m"] == [-2.0, 31.0, 1.0]
    spec = compose_field_params(config)
    assert spec["heliostats"]["names"] == [f"field_{i:03d}" for i in range(5)]
    assert spec["heliostats"]["seeds"] == [20, 21, 22, 23, 24]
    assert spec["measured"] == ["field_001", "field_003"]
    assert spec["world_effects"]["sunshape"] == tiny["world"]["effects"]["sunshape"]
    assert spec["model_effects"]["blocking_shading"] == {}


def test_a_csv_layout_reads_its_file(tiny, tmp_path):
    (tmp_path / "field.csv").write_text("east,north\n-3,25\n3,25\n0,30\n")
    tiny["field"]["layout"] = {"kind": "csv", "csv": str(tmp_path / "field.csv")}
    tiny["field"]["measured"] = {"fraction": 0.5, "seed": 1}
    config = expand_field(tiny)
    assert compose_field_params(config)["heliostats"]["positions_m"] == [
        [-3.0, 25.0, 0.0],
        [3.0, 25.0, 0.0],
        [0.0, 30.0, 0.0],
    ]
    assert len(field_measured(tiny)) == 2
    tiny["field"]["layout"]["csv"] = str(tmp_path / "missing.csv")
    with pytest.raises(ConfigError, match="field.layout.csv: .*missing.csv"):
        expand_field(tiny)


def test_editing_a_design_point_changes_only_compose_field(tiny):
    config = expand_field(tiny)
    before = {"compose": compose_field_params(config), "trace": trace_params(config, "field_001")}
    tiny["field"]["sun"]["noon"]["elevation_deg"] = 50.0
    config = expand_field(tiny)
    assert compose_field_params(config) != before["compose"]
    assert trace_params(config, "field_001") == before["trace"]


def _edit(path: str, value):
    def edit(c):
        *keys, last = path.split(".")
        node = c
        for k in keys:
            node = node[k]
        if value is None:
            del node[last]
        else:
            node[last] = value

    return edit


BAD = {
    "unknown field key": (_edit("field.colour", "red"), ["field", "'colour'", "allowed keys:", "layout"]),
    "unknown layout kind": (
        _edit("field.layout.kind", "spiral"),
        ["field.layout.kind", "'spiral'", "fermat"],
    ),
    "layout key of another kind": (_edit("field.layout.n", 5), ["field.layout", "'n'", "kind 'list'"]),
    "layout without its key": (
        _edit("field.layout", {"kind": "fermat", "n": 5}),
        ["field.layout", "'min_radius_m'"],
    ),
    "unknown template": (_edit("field.heliostat", "round"), ["field.heliostat", "'round'", "small"]),
    "network not configured": (_edit("field.network", "nerf"), ["field.network", "'nerf'", "nearest"]),
    "network not steerable": (
        lambda c: c.update(networks={"gan": {}}) or c["field"].update(network="gan"),
        ["field.network", "'gan'", "controllable"],
    ),
    "indices and fraction": (_edit("field.measured.fraction", 0.5), ["field.measured", "exactly one"]),
    "zero receiver normal": (
        _edit("field.receiver.normal", [0, 0, 0]),
        ["field.receiver.normal", "non-zero"],
    ),
    "design sun below the horizon": (
        _edit("field.sun.noon.elevation_deg", -5.0),
        ["field.sun.noon.elevation_deg", "-5.0", "horizon"],
    ),
    "bad calibration trace": (
        _edit("field.calibration.trace", {"splat": "bilinear", "rays": 0}),
        ["field.calibration.trace.rays", "rays > 0"],
    ),
    "unknown field effect": (_edit("field.world_effects", {"smog": {}}), ["field.world_effects", "'smog'"]),
    "receiver too small": (_edit("field.receiver.resolution", [4, 4]), ["field.receiver.resolution.0", "4"]),
}


@pytest.mark.parametrize("case", BAD, ids=list(BAD))
def test_a_bad_field_key_gives_a_config_error_naming_it(case):
    edit, expected = BAD[case]
    config = tiny_field()
    edit(config)
    with pytest.raises(ConfigError) as exc:
        expand_field(validate_config(config))
    for text in expected:
        assert text in str(exc.value), (text, str(exc.value))


def test_indices_beyond_the_field_and_taken_names_are_config_errors(tiny):
    tiny["field"]["measured"] = {"indices": [1, 5]}
    with pytest.raises(ConfigError, match=r"field.measured.indices has 5, but the field has 5 heliostats"):
        expand_field(tiny)
    tiny["field"]["measured"] = {"indices": [1]}
    tiny["heliostats"]["field_002"] = copy.deepcopy(tiny["heliostats"]["small"])
    with pytest.raises(ConfigError, match="'field_002' is already in heliostats"):
        expand_field(tiny)


def test_the_equivalent_sun_is_within_the_default_calibration_scan(default):
    """Each design point of the default config asks the measured heliostats' models for a sun
    position above the horizon and inside the calibration scan's elevation range."""
    import torch

    from helioflow.field.compose import build_scene
    from helioflow.physics.carry import equivalent_sun
    from helioflow.physics.geometry import azimuth_elevation, sun_vector

    config = expand_field(default)
    scene = build_scene(compose_field_params(config), torch.device("cpu"))
    target = torch.tensor(default["target"]["center_m"], dtype=torch.float64)
    low, high = default["field"]["calibration"]["sun"]["elevation_deg"]
    for k in scene.measured:
        for sun in sun_vector(scene.azimuth, scene.elevation):
            _, el = azimuth_elevation(equivalent_sun(scene.true[k].position, scene.aims[k], sun, target))
            assert low <= math.degrees(el) <= high


def _field_workdir(path: Path) -> Path:
    workdir = _workdir(path)
    for name in ("tiny_config.yaml", "tiny_field.yaml"):
        shutil.copy(HERE / name, workdir / name)
    return workdir


def test_the_dag_builds_the_measured_heliostats_through_the_existing_rules(tmp_path):
    workdir = _field_workdir(tmp_path / "dry")
    proc = snakemake(
        workdir,
        "-n",
        "results/tinyfield/field/flux.h5",
        "--configfile",
        "tiny_config.yaml",
        "tiny_field.yaml",
    )
    r = "results/tinyfield"
    field_outputs = {f"{r}/field/{f}" for f in ("flux.h5", "flux.png", "metrics.json")}
    assert _scheduled(proc) == field_outputs | {f"{r}/specs/compose_field.json"} | {
        f"{r}/{f}"
        for m in ("field_001", "field_003")
        for f in (
            f"surfaces/{m}.h5",
            f"datasets/{m}.h5",
            f"models/{m}/nearest.pt",
            f"models/{m}/nearest_curve.csv",
            f"models/{m}/nearest_curve.png",
        )
    }


@pytest.mark.slow
def test_compose_field_runs_in_the_dag(tmp_path):
    workdir = _field_workdir(tmp_path / "run")
    proc = snakemake(
        workdir,
        "-j2",
        "results/tinyfield/field/flux.h5",
        "--configfile",
        "tiny_config.yaml",
        "tiny_field.yaml",
    )
    assert proc.returncode == 0, proc.stderr[-4000:]
    r = workdir / "results/tinyfield"
    assert (r / "field/flux.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "wrote" in (r / "logs/compose_field/compose_field.log").read_text()
    assert (r / "benchmarks/compose_field/compose_field.tsv").read_text().startswith("s\th:m:s")
    assert sorted(p.name for p in (r / "surfaces").iterdir()) == ["field_001.h5", "field_003.h5"]
