"""Config validation against workflow/schemas/config.schema.yaml: one clear ConfigError per mistake."""

import copy
from pathlib import Path

import pytest
import yaml

from helioflow.config import MAX_ALIAS_NODES, load_config, read_yaml, validate_config
from helioflow.errors import ConfigError

REPO = Path(__file__).resolve().parents[1]
TINY = REPO / "tests" / "workflow" / "tiny_config.yaml"


@pytest.fixture(scope="module")
def raw():
    return yaml.safe_load((REPO / "config.yaml").read_text())


@pytest.fixture
def config(raw):
    return copy.deepcopy(raw)


@pytest.mark.parametrize("path", [REPO / "config.yaml", TINY], ids=["config.yaml", "tiny_config.yaml"])
def test_shipped_configs_validate(path):
    config = load_config(path)
    assert config["datasets"] and config["heliostats"]


def _set(path: str, value):
    def edit(c):
        *keys, last = path.split(".")
        node = c
        for k in keys:
            node = node[k]
        node[last] = value
    return edit


# (edit, substrings the message must contain: key path, bad value, what is allowed)
CASES = {
    "unknown top-level key": (_set("colour", "red"),
                              ["(top level)", "'colour'", "allowed keys:", "datasets"]),
    "unknown heliostat key": (_set("heliostats.square.height", 2.0),
                              ["heliostats.square", "'height'", "allowed keys:", "position_m"]),
    "unknown facets key": (_set("heliostats.square.facets.depth_m", 0.1),
                           ["heliostats.square.facets", "'depth_m'", "width_m"]),
    "mount enum": (_set("heliostats.square.mount", "foo"),
                   ["heliostats.square.mount", "'foo'", "az_el, juelich"]),
    "device enum": (_set("device", "gpu"), ["device", "'gpu'", "cpu, cuda, auto"]),
    "splat enum": (_set("datasets.semi_sphere.trace.splat", "nearest"),
                   ["datasets.semi_sphere.trace.splat", "'nearest'", "bilinear, kernel"]),
    "negative facet width": (_set("heliostats.multi_facet.facets.width_m", -0.8),
                             ["heliostats.multi_facet.facets.width_m", "-0.8", "> 0"]),
    "scan below the horizon": (_set("datasets.sanity_check.sun.elevation_deg", [-5.0, 80.0]),
                               ["datasets.sanity_check.sun.elevation_deg", "-5.0", "> 0", "horizon"]),
    "list position below the horizon": (
        _set("datasets.sanity_check.sun", {"kind": "list", "positions_deg": [[0.0, 30.0], [10.0, -2.0]]}),
        ["datasets.sanity_check.sun.positions_deg.1.1", "-2.0", "> 0", "horizon"]),
    "elevation above zenith": (_set("datasets.semi_sphere.sun.elevation_deg", [10.0, 95.0]),
                               ["datasets.semi_sphere.sun.elevation_deg.1", "95.0", "<= 90"]),
    "unknown heliostat in a dataset": (_set("datasets.sanity_check.heliostat", "round"),
                                       ["datasets.sanity_check.heliostat", "'round'", "square, multi_facet"]),
    "unknown effect": (_set("world.effects.wind", {}), ["world.effects", "'wind'", "sunshape", "camera"]),
    "unknown effect in a dataset": (_set("datasets.semi_sphere.world_effects.dust", {}),
                                    ["datasets.semi_sphere.world_effects", "'dust'", "attenuation"]),
    "unknown effect of the plant's flux maps": (_set("plant", {"flux": {"effects": {"wind": {}}}}),
                                                ["plant.flux.effects", "'wind'", "attenuation"]),
    "plant flux receiver not a name": (_set("plant", {"flux": {"receiver": 3}}), ["plant.flux.receiver", "3"]),
    "unknown effect parameter": (_set("world.effects.slope_error.rms_mrad", 1.0),
                                 ["world.effects.slope_error", "'rms_mrad'", "sigma_mrad"]),
    "effect parameter out of range": (_set("world.effects.slope_error.sigma_mrad", 50.0),
                                      ["world.effects.slope_error.sigma_mrad", "50.0", "20.0"]),
    "fit in world effects": (_set("world.effects.slope_error.sigma_mrad", "fit"),
                             ["world.effects.slope_error.sigma_mrad", "'fit'", "model"]),
    "fit in dataset world effects": (_set("datasets.sanity_check.world_effects.sunshape.csr", "fit"),
                                     ["datasets.sanity_check.world_effects.sunshape.csr", "'fit'", "model"]),
    "wrong type": (_set("seed", "forty-two"), ["seed", "'forty-two'", "integer"]),
    "a plan for a dataset the config lacks": (_set("plan.datasets", ["aa39"]),
                                              ["plan.datasets", "'aa39'", "sanity_check, semi_sphere", "plan: null"]),
    "a plan without drt": (_set("networks.drt", None), ["plan.datasets", "'sanity_check'", "drt"]),
}


@pytest.mark.parametrize("case", list(CASES))
def test_a_bad_value_gives_one_clear_config_error(config, case):
    edit, expected = CASES[case]
    edit(config)
    with pytest.raises(ConfigError) as exc:
        validate_config(config)
    message = str(exc.value)
    assert "\n" not in message
    for text in expected:
        assert text in message, f"{text!r} not in {message!r}"


def test_fit_is_allowed_in_the_model(config):
    config["model"]["effects"] = {"sunshape": {"kind": "buie", "csr": "fit"},
                                  "slope_error": {"sigma_mrad": "fit"}}
    validate_config(config)
    config["model"]["effects"]["sunshape"]["kind"] = "fit"  # not a fittable parameter
    with pytest.raises(ConfigError, match="model.effects.sunshape.kind"):
        validate_config(config)


def test_defaults_are_filled_and_the_input_is_not_changed(config):
    h = config["heliostats"]["square"]
    del h["facets"]["gap_m"], h["seed"], h["control_points"], h["deformation_mm"]
    del config["datasets"]["semi_sphere"]["window_m"]
    before = copy.deepcopy(config)
    filled = validate_config(config)
    assert config == before
    fh = filled["heliostats"]["square"]
    assert fh["facets"]["gap_m"] == 0.0
    assert (fh["seed"], fh["control_points"], fh["deformation_mm"]) == (0, 6, 0.0)
    assert filled["datasets"]["semi_sphere"]["window_m"] == "auto"
    assert filled["heliostats"]["multi_facet"]["facets"]["gap_m"] == 0.02  # given values kept


def test_load_config_names_the_file(tmp_path):
    with pytest.raises(ConfigError, match="missing.yaml"):
        load_config(tmp_path / "missing.yaml")
    broken = tmp_path / "broken.yaml"
    broken.write_text("experiment: [unclosed\n")
    with pytest.raises(ConfigError, match="broken.yaml"):
        load_config(broken)
    bad = tmp_path / "bad.yaml"
    bad.write_text((REPO / "config.yaml").read_text().replace("device: cpu", "device: gpu"))
    with pytest.raises(ConfigError, match=r"bad.yaml: device = 'gpu'"):
        load_config(bad)


def _laughs(levels: int = 8, mapping: bool = False) -> str:
    """Nested aliases ("billion laughs"): nine of the level below on each of `levels` levels."""
    if mapping:
        lines = ["m0: &m0 {" + ", ".join(f"k{j}: x" for j in range(9)) + "}"]
        lines += [f"m{i}: &m{i} {{<<: [" + ", ".join([f"*m{i - 1}"] * 9) + "]}" for i in range(1, levels + 1)]
    else:
        lines = ["a0: &a0 [x, x, x, x, x, x, x, x, x]"]
        lines += [f"a{i}: &a{i} [" + ", ".join([f"*a{i - 1}"] * 9) + "]" for i in range(1, levels + 1)]
    return "\n".join(lines) + "\n"


@pytest.mark.parametrize("mapping", [False, True], ids=["lists", "merge keys"])
def test_read_yaml_refuses_aliases_that_expand_past_the_bound_in_one_line(tmp_path, mapping):
    laughs = tmp_path / "laughs.yaml"
    laughs.write_text(_laughs(mapping=mapping))
    with pytest.raises(ConfigError) as caught:
        read_yaml(laughs)
    message = str(caught.value)
    assert "\n" not in message and message.startswith(f"{laughs}: its aliases expand to ")
    assert message.endswith(f"more than the bound {MAX_ALIAS_NODES:,}; write the values out")
    if not mapping:  # level i: a list of nine of level i - 1, (9^(i + 2) - 1) / 8 nodes; the nine keys, the top
        expanded = 1 + 9 + sum((9 ** (i + 2) - 1) // 8 for i in range(9))
        assert f" {expanded - 28:,} nodes beyond the 28 written" in message


def test_read_yaml_refuses_an_alias_inside_the_collection_it_names(tmp_path):
    loop = tmp_path / "loop.yaml"
    loop.write_text("experiment: x\nnetworks: &n {cgan: *n}\n")
    with pytest.raises(ConfigError, match=r"loop.yaml: line 2: an alias inside the collection it names \(line 2\)"):
        read_yaml(loop)


def test_read_yaml_reads_a_few_aliases_and_merge_keys(tmp_path):
    few = tmp_path / "few.yaml"
    few.write_text("defaults: &d {steps: 3, lr: 0.01}\nnetworks:\n  cgan: {<<: *d, steps: 5}\n  nerf: *d\n"
                   "sun: &sun [[180.0, 45.0], [200.0, 30.0]]\nagain: *sun\n" + _laughs(levels=3))
    data = read_yaml(few)
    assert data["networks"] == {"cgan": {"steps": 5, "lr": 0.01}, "nerf": {"steps": 3, "lr": 0.01}}
    assert data["again"] == [[180.0, 45.0], [200.0, 30.0]] and len(data["a3"]) == 9
    with pytest.raises(ConfigError, match="the key 'steps' appears twice"):  # merge keys aside, still strict
        few.write_text("defaults: &d {lr: 0.01}\ncgan: {<<: *d, steps: 5, steps: 6}\n")
        read_yaml(few)


@pytest.mark.parametrize("path", [REPO / "config.yaml", *sorted((REPO / "workflow" / "variants").glob("*.yaml"))],
                         ids=lambda p: p.name)
def test_the_shipped_configs_are_far_below_the_alias_bound(path):
    assert read_yaml(path) == yaml.safe_load(path.read_text())


def test_a_variant_removes_default_entries_and_sections_with_null():
    config = yaml.safe_load(open("config.yaml"))
    config["datasets"]["semi_sphere"] = None
    config["networks"]["nerf"] = None
    config["field"] = None
    checked = validate_config(config)
    assert list(checked["datasets"]) == ["sanity_check"]
    assert "nerf" not in checked["networks"] and "gan" in checked["networks"]
    assert "field" not in checked


def test_the_defaults_the_code_keeps_are_valid_by_the_schema():
    """DIAGNOSIS_DEFAULTS and LAYOUT_DEFAULTS stay in the code (the schema cannot hold them: see their
    comments); each is checked against the schema part it fills, and covers every key with a
    meaning of its own there (a layout's positions and csv belong to other kinds)."""
    import jsonschema

    from helioflow.schema import load_schema
    from helioflow.workflow import DIAGNOSIS_DEFAULTS, LAYOUT_DEFAULTS

    schema = load_schema()
    diagnosis = schema["definitions"]["diagnosis"]
    jsonschema.Draft7Validator(diagnosis).validate(DIAGNOSIS_DEFAULTS)
    assert set(DIAGNOSIS_DEFAULTS) == set(diagnosis["properties"])
    layout = schema["properties"]["field"]["properties"]["layout"]
    resolvable = jsonschema.Draft7Validator({**layout, "definitions": schema["definitions"]})  # its $refs resolve
    for kind in ("fermat", "radial"):
        resolvable.validate({"kind": kind, "n": 10, "min_radius_m": 20.0, **LAYOUT_DEFAULTS})
    assert set(LAYOUT_DEFAULTS) == set(layout["properties"]) - {"kind", "n", "min_radius_m", "positions", "csv"}


def test_the_constants_the_code_keeps_agree_with_the_schema():
    """CENTERED_DEFAULT and SITE_ALTITUDE_M stay in the code (see their comments): `centered`'s is
    the value the schema's description calls the default, of the values it allows (CENTERED_MODES),
    and no schema default; a site's altitude is the schema's default of datasets.<name>.site."""
    from helioflow.data.images import SITE_ALTITUDE_M
    from helioflow.data.paint import CENTERED_DEFAULT, CENTERED_MODES
    from helioflow.schema import load_schema

    dataset = load_schema()["properties"]["datasets"]["additionalProperties"]["properties"]
    centered = dataset["centered"]
    assert tuple(centered["enum"]) == CENTERED_MODES and "default" not in centered
    assert f"({CENTERED_DEFAULT}, the default)" in centered["description"]
    assert dataset["site"]["properties"]["altitude_m"]["default"] == SITE_ALTITUDE_M


def test_a_named_entry_is_filled_with_the_schema_defaults():
    """with_defaults reaches a named entry (`heliostats.<name>`), as HeliostatSpec.from_config fills an
    inline heliostat or a spec written by hand."""
    from helioflow.data.surfaces import HeliostatSpec
    from helioflow.schema import with_defaults

    section = {"position_m": [0.0, 30.0, 1.0], "mount": "az_el",
               "facets": {"rows": 1, "cols": 2, "width_m": 1.0, "height_m": 1.0}}
    filled = with_defaults(section, "heliostats", "h")
    assert filled["facets"]["gap_m"] == 0.0 and filled["control_points"] == 6 and filled["seed"] == 0
    assert filled["canting_focal_distance_m"] is None and "gap_m" not in section["facets"]  # a copy
    spec = HeliostatSpec.from_config("h", section)
    assert (spec.gap_m, spec.control_points, spec.deformation_mm, spec.tracking_error_mrad, spec.canting_error_mrad,
            spec.seed, spec.facet_focal_length_m) == (0.0, 6, 0.0, 0.0, 0.0, 0, None)
