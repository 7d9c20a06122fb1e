"""Config: validation with clear messages, and the typed sections the rules work with.

`validate_config` is what the Snakefile calls at parse time: JSON-schema checks (a wrong key or
value names the key, the value and what is allowed) plus the cross-references a schema cannot
express (a dataset's heliostat exists, effect names and parameters are in the registry).
"""

from __future__ import annotations

import copy
import math
import re
from pathlib import Path

import yaml

from helioflow.data.paint import plant_heliostats
from helioflow.errors import ConfigError, DataError, HelioflowError
from helioflow.physics.effects import check_effects
from helioflow.schema import SCHEMA_PATH, fill_defaults, load_schema
from helioflow.workflow import facing


class _StrictLoader(yaml.SafeLoader):
    """YAML's safe loader that refuses a mapping holding one key twice (plain YAML keeps the last
    silently: a variant with two `networks:` blocks would run with the second alone)."""

    def construct_mapping(self, node, deep=False):
        seen: dict = {}
        for key_node, _ in node.value:
            if key_node.tag == "tag:yaml.org,2002:merge":  # `<<`: what it brings in may be overridden, as
                continue  # YAML means (and the merge tag has no constructor of its own)
            key = self.construct_object(key_node, deep=True)
            if key in seen:
                raise ConfigError(f"{self.name}: the key '{key}' appears twice in one mapping (lines "
                                  f"{seen[key] + 1} and {key_node.start_mark.line + 1}): keep one")
            seen[key] = key_node.start_mark.line
        return super().construct_mapping(node, deep)


# nodes that a config file's aliases (`*name`, `<<: *name`) may add when written out: a real config
# adds a few hundred; nested aliases ("billion laughs") add 9^9 from a 500-byte file, which the
# config's checks would then walk for minutes (a file's own nodes are not bounded here: a list layout
# of 200,000 heliostats is 800,000 of them)
MAX_ALIAS_NODES = 100_000


def _alias_expansion(root: yaml.Node, name: str) -> tuple[int, int]:
    """(nodes written, nodes the composed graph `root` becomes with every alias written out): each
    node counted once per path to it, memoised per node, so that nested aliases are counted in time
    linear in the nodes written. A ConfigError for an alias inside the collection it names (YAML
    allows it; written out it never ends)."""
    sizes: dict[int, int] = {}
    open_nodes: set[int] = set()  # expanded, not yet sized: the ancestors of the node on top
    stack = [root]
    while stack:
        node = stack[-1]
        if id(node) in sizes:
            stack.pop()
            continue
        if isinstance(node, yaml.MappingNode):
            children = [child for pair in node.value for child in pair]
        else:
            children = node.value if isinstance(node, yaml.SequenceNode) else []
        if id(node) not in open_nodes:
            open_nodes.add(id(node))
            for child in children:
                if id(child) in open_nodes:
                    raise ConfigError(f"{name}: line {child.start_mark.line + 1}: an alias inside the collection "
                                      f"it names (line {node.start_mark.line + 1}) never ends: write the values out")
                if id(child) not in sizes:
                    stack.append(child)
            continue
        sizes[id(node)] = 1 + sum(sizes[id(child)] for child in children)
        open_nodes.discard(id(node))
        stack.pop()
    return len(sizes), sizes[id(root)]


def read_yaml(path: str | Path):
    """A config YAML file's content, read strictly (`_StrictLoader`): a key twice in one mapping is
    a ConfigError naming the file, the key and both lines; so are aliases that add more than
    MAX_ALIAS_NODES nodes when written out (counted before they are, `_alias_expansion`)."""
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read the config: {exc}") from None
    loader = _StrictLoader(text)
    loader.name = str(path)
    try:
        node = loader.get_single_node()
        if node is None:
            return None
        written, expanded = _alias_expansion(node, str(path))
        if expanded - written > MAX_ALIAS_NODES:
            raise ConfigError(f"{path}: its aliases expand to {expanded - written:,} nodes beyond the {written:,} "
                              f"written, more than the bound {MAX_ALIAS_NODES:,}; write the values out")
        return loader.construct_document(node)
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path}: cannot read the config: {exc}") from None
    finally:
        loader.dispose()


def load_config(path: str | Path) -> dict:
    """Read (strictly, `read_yaml`) and validate a config YAML file; returns the config with schema
    defaults filled in."""
    return validate_config(read_yaml(path), source=str(path))


def validate_config(config: dict, schema_path: str | Path = SCHEMA_PATH, source: str = "config") -> dict:
    """Check a config dict; raise one ConfigError naming key, value and what is allowed.

    Returns a deep copy with the schema's defaults filled in. A key set to null is removed,
    anywhere: how a `--configfile` variant, which snakemake merges into config.yaml key by key, leaves
    out a default dataset, network, stage, effect or setting (a key whose default is null keeps its
    meaning). PAINT measurement ids given as numbers become strings.
    """
    config = _without_nulls(copy.deepcopy(config))
    _check_finite(config, source)
    import jsonschema  # here: the commands that take a spec from the Snakefile start without it

    schema = load_schema(str(schema_path))
    validator = jsonschema.Draft7Validator(schema)
    errors = sorted(validator.iter_errors(config),
                    key=lambda e: (len(e.absolute_path), list(map(str, e.absolute_path))))
    if errors:
        raise ConfigError(f"{source}: {_describe(errors[0])}")
    config = copy.deepcopy(config)
    fill_defaults(config, schema, schema)
    for ds in config["datasets"].values():
        if isinstance(ds.get("holdout"), list):
            ds["holdout"] = [str(i) for i in ds["holdout"]]
    _check_references(config, source)
    _check_device(config["device"], source)
    return config


def follow_variant(config: dict, written: dict) -> list[str]:
    """Fit config.yaml's sections that name datasets, networks or heliostats to what a variant keeps.

    `config` is the merged config as snakemake builds it (config.yaml, then the variants and
    `--config`; null entries not yet removed), changed in place; `written` is the part the user wrote
    (snakemake's `config_settings.overwrite_config`). A named key the user did not write follows the
    experiment: `plan.datasets` keeps the datasets that remain, and `plan` (without those, or without
    the drt network its fit comes from) or `field` (without its template heliostat or its network)
    falls away. A key the user wrote is left as written, for `validate_config` to check. Returns one
    line per change, for the log.
    """
    kept = {section: {k for k, v in (config.get(section) or {}).items() if v is not None}
            for section in ("datasets", "networks", "heliostats")}
    notes = []
    plan, wrote_plan = config.get("plan"), written.get("plan")
    if isinstance(plan, dict) and plan.get("datasets") and "datasets" not in (wrote_plan or {}):
        named = list(plan["datasets"])
        remaining = [name for name in named if name in kept["datasets"]]
        missing = "drt" not in kept["networks"]
        if missing or not remaining:
            config["plan"] = None
            why = "this experiment has no drt network, whose fit a plan is made from" if missing else \
                f"this experiment has none of its datasets ({', '.join(named)})"
            notes.append(f"config.yaml's plan falls away: {why}")
        elif remaining != named:
            plan["datasets"] = remaining
            notes.append(f"config.yaml's plan.datasets follows the experiment: {', '.join(remaining)} "
                         f"(not {', '.join(sorted(set(named) - set(remaining)))})")
    field, wrote_field = config.get("field"), written.get("field")
    for key, section in (("heliostat", "heliostats"), ("network", "networks")):
        if isinstance(field, dict) and key in field and key not in (wrote_field or {}) \
                and field[key] not in kept[section]:
            config["field"] = None
            notes.append(f"config.yaml's field falls away: its {key} {field[key]!r} is not in this "
                         f"experiment's {section}")
            break
    return notes


def _without_nulls(node):
    """`node` with every mapping entry whose value is null removed, at any depth."""
    if isinstance(node, dict):
        return {k: _without_nulls(v) for k, v in node.items() if v is not None}
    return node


def _check_finite(node, source: str, path: tuple = ()) -> None:
    """ConfigError naming the key of the first number that is NaN or infinite (YAML's .nan, .inf):
    no config number may be either (the schema's minimum / maximum let NaN through)."""
    if isinstance(node, dict):
        for key, value in node.items():
            _check_finite(value, source, (*path, key))
    elif isinstance(node, list):
        for i, value in enumerate(node):
            _check_finite(value, source, (*path, i))
    elif isinstance(node, float) and not math.isfinite(node):
        raise ConfigError(f"{source}: {'.'.join(map(str, path))} = {node!r}: expected a finite number")


def _check_device(device: str, source: str) -> None:
    import torch

    if device == "cuda" and not torch.cuda.is_available():
        raise ConfigError(f"{source}: device = 'cuda', but torch sees no CUDA device on this machine "
                          f"(torch {torch.__version__}); use device: cpu, or auto (CUDA where there is one)")


def _describe(error) -> str:
    """'key.path = value: what is allowed' for one schema error."""
    key = ".".join(str(p) for p in error.absolute_path) or "(top level)"
    rule, expected = error.validator, error.validator_value
    if rule == "additionalProperties":
        known = sorted(error.schema.get("properties", {}))
        extra = sorted(set(error.instance) - set(known))
        allowed = ", ".join(known) if known else "any name"
        return f"{key}: unknown key {extra[0]!r}; allowed keys: {allowed}"
    if rule == "required":
        return f"{key}: missing key {error.message.split(' ')[0]}; required: {', '.join(expected)}"
    value = f"{key} = {error.instance!r}"
    if rule == "pattern":
        name = f"{key}: name {error.instance!r}" if "propertyNames" in error.schema_path else value
        return (f"{name}: a name that becomes a file path: expected letters, digits, '_', '.' and '-', "
                "starting with a letter or digit, without '..'")
    if rule == "enum":
        return f"{value}: allowed values are {', '.join(map(str, expected))}"
    if rule in ("minimum", "exclusiveMinimum", "maximum", "exclusiveMaximum"):
        sign = {"minimum": ">=", "exclusiveMinimum": ">", "maximum": "<=", "exclusiveMaximum": "<"}[rule]
        path = list(error.absolute_path)
        elevation = "elevation" in key or (len(path) >= 3 and path[-3] == "positions_deg" and path[-1] == 1)
        hint = " (the sun must be above the horizon)" if elevation and "Minimum" in rule else ""
        return f"{value}: expected a value {sign} {expected}{hint}{_why(error)}"
    if rule == "type":
        return f"{value}: expected {expected if isinstance(expected, str) else ' or '.join(expected)}"
    if rule in ("minItems", "maxItems"):
        shown = value if rule == "minItems" else f"{key} ({len(error.instance)} items)"
        return f"{shown}: expected {'at least' if rule == 'minItems' else 'at most'} {expected} items{_why(error)}"
    if rule == "maxProperties":
        return f"{key} ({len(error.instance)} entries): expected at most {expected}{_why(error)}"
    if rule == "maxLength":
        name = f"{key}: name" if "propertyNames" in error.schema_path else key
        return (f"{name} {error.instance[:20]!r}... ({len(error.instance)} characters): expected at most {expected} "
                f"characters{_why(error)}")
    if rule == "oneOf":
        inner = [e for e in error.context if e.validator not in ("type", "const", "enum", "oneOf")]
        if len(inner) == 1:  # one alternative is of the value's type: why that one refuses it
            return _describe(inner[0])
        return f"{value}: expected one of: " + "; ".join(_schema_text(s) for s in expected)
    return f"{value}: {error.message}"


def _why(error) -> str:
    """' (the reason)' of a bound: the `bound` annotation of the schema that sets it."""
    return f" ({error.schema['bound']})" if "bound" in error.schema else ""


def _schema_text(schema: dict) -> str:
    if "const" in schema:
        return repr(schema["const"])
    if "$ref" in schema:
        name = schema["$ref"].rsplit("/", 1)[-1]
        definition = load_schema()["definitions"].get(name, {})
        if "minimum" in definition or "exclusiveMinimum" in definition:
            low = (f">= {definition['minimum']}" if "minimum" in definition else f"> {definition['exclusiveMinimum']}")
            high = f" and <= {definition['maximum']}" if "maximum" in definition else ""
            return f"a number {low}{high}"
        return name
    return schema.get("type", "value")


_SUN_KEYS = {"scan": ("azimuth_deg", "elevation_deg", "n"), "hemisphere": ("azimuth_deg", "elevation_deg", "n"),
             "list": ("positions_deg",)}


def _check_references(config: dict, source: str) -> None:
    check_effects(config["world"].get("effects"), f"{source}: world.effects", allow_fit=False)
    check_effects(config["model"].get("effects"), f"{source}: model.effects", allow_fit=True)
    if not any(abs(x) > 0 for x in config["target"]["normal"]):
        raise ConfigError(f"{source}: target.normal = {config['target']['normal']}: expected a non-zero vector")
    from helioflow.models.registry import split_settings

    for network, settings in (config.get("networks") or {}).items():
        split_settings(network, settings or {}, config["seed"], where=f"{source}: networks.{network}")
    plant_drt = config["plant"]["fit"]["drt"]  # over networks.drt, for every plant heliostat
    split_settings("drt", {**(config.get("networks") or {}).get("drt", {}), **plant_drt}, config["seed"],
                   where=f"{source}: plant.fit.drt (over networks.drt)")
    for network in (config.get("data_efficiency") or {}).get("networks", []):
        if network not in (config.get("networks") or {}):
            raise ConfigError(f"{source}: data_efficiency.networks has {network!r}, which is not in networks")
    for name, ds in config["datasets"].items():
        where = f"{source}: datasets.{name}"
        check_effects(ds.get("model_effects"), f"{where}.model_effects", allow_fit=True)
        if ds["source"] == "paint":
            _check_paint_dataset(config, name, where)
            continue
        if ds["source"] == "images":
            _check_images_dataset(config, name, where)
            continue
        extra = sorted(_PAINT_KEYS & set(ds))
        if extra:
            raise ConfigError(f"{where}: key {extra[0]!r} is for PAINT datasets or own images; add source: paint "
                              "or source: images, or remove it")
        extra = sorted(_IMAGES_KEYS & set(ds))
        if extra:
            raise ConfigError(f"{where}: key {extra[0]!r} is for own images; add source: images or remove it")
        if ds["heliostat"] not in config["heliostats"]:
            known = ", ".join(config["heliostats"])
            raise ConfigError(f"{where}.heliostat = {ds['heliostat']!r} is not a heliostat in config; known: {known}")
        _check_traced(ds, where)
        _check_sees_target(config["heliostats"][ds["heliostat"]]["position_m"], config["target"],
                           f"heliostat {ds['heliostat']!r}", where)
    for name in (config.get("plan") or {}).get("datasets") or []:
        if name not in config["datasets"]:
            raise ConfigError(f"{source}: plan.datasets has {name!r}, which is not in datasets (known: "
                              f"{', '.join(config['datasets'])}); a variant without it sets plan: null or its own "
                              "datasets")
        if "drt" not in (config.get("networks") or {}):
            raise ConfigError(f"{source}: plan.datasets has {name!r}, but networks has no drt, whose fit a plan is "
                              "made from")
    if config.get("field"):
        _check_field(config, f"{source}: field")
        _check_aim_maps(config["field"].get("optimise_aim"), f"{source}: field.optimise_aim")
    flux = (config.get("plant") or {}).get("flux")
    if isinstance(flux, dict):
        check_effects(flux.get("effects"), f"{source}: plant.flux.effects", allow_fit=False)
        _check_aim_maps(flux.get("optimise_aim"), f"{source}: plant.flux.optimise_aim")


def _check_aim_maps(aim: dict | None, where: str) -> None:
    """A limit map's and a target's rows are of equal length, a target not all zero (the schema checks
    the values)."""
    for key in ("limit_kw_m2", "target"):
        cells = (aim or {}).get(key)
        if not isinstance(cells, list):
            continue
        if len({len(row) for row in cells}) > 1:
            lengths = ", ".join(str(len(row)) for row in cells)
            raise ConfigError(f"{where}.{key}: rows of {lengths} values; a map needs rows of equal length (the top "
                              "row first, columns left to right as seen from the field)")
        if not any(v > 0 for row in cells for v in row):
            raise ConfigError(f"{where}.{key}: every value is 0; a target needs flux somewhere")


def _check_traced(ds: dict, where: str) -> None:
    """The checks of a traced dataset (or the field's calibration template) the schema cannot express."""
    sun = ds["sun"]
    for key in _SUN_KEYS[sun["kind"]]:
        if key not in sun:
            raise ConfigError(f"{where}.sun: kind {sun['kind']!r} needs key {key!r}")
    scalar_az = isinstance(sun.get("azimuth_deg"), (int, float))
    if sun["kind"] == "scan" and not scalar_az:
        raise ConfigError(f"{where}.sun.azimuth_deg = {sun['azimuth_deg']!r}: a scan needs one azimuth (a number)")
    if sun["kind"] == "hemisphere" and scalar_az:
        raise ConfigError(f"{where}.sun.azimuth_deg = {sun['azimuth_deg']!r}: expected a range [min, max]")
    check_effects(ds.get("world_effects"), f"{where}.world_effects", allow_fit=False)
    if ds["trace"]["splat"] == "bilinear" and ds["trace"].get("rays", 0) <= 0:
        raise ConfigError(f"{where}.trace.rays = {ds['trace'].get('rays')!r}: bilinear splatting needs rays > 0")


def _check_sees_target(position: list, target: dict, heliostat: str, where: str) -> None:
    """A heliostat at `position` (m) is in front of the calibration target (on the side its normal
    points to); `heliostat` names it in the error."""
    distance = facing(position, target["center_m"], target["normal"])
    if distance <= 0:
        place = "in the target plane" if distance == 0 else f"{-distance:g} m behind the target"
        raise ConfigError(f"{where}: {heliostat} at position_m {position} is {place} (target.center_m "
                          f"{target['center_m']}, target.normal {target['normal']} points towards the heliostats): "
                          "it cannot see the target")


_LAYOUT_KEYS = {"fermat": {"n", "min_radius_m", "spacing_m", "clearance_m", "sector_deg", "pivot_height_m"},
                "list": {"positions"}, "csv": {"csv"}}
_LAYOUT_KEYS["radial"] = _LAYOUT_KEYS["fermat"]
_LAYOUT_REQUIRED = {"fermat": ("n", "min_radius_m"), "radial": ("n", "min_radius_m"), "list": ("positions",),
                    "csv": ("csv",)}


def _check_field(config: dict, where: str) -> None:
    """The field section: its template heliostat and network exist, the layout has the keys of its
    kind, exactly one way of choosing the measured heliostats, effects and calibration template
    valid. What needs the layout itself (indices in range, generated names free) is checked by
    helioflow.workflow.expand_field."""
    field = config["field"]
    if field["heliostat"] not in config["heliostats"]:
        known = ", ".join(config["heliostats"])
        raise ConfigError(f"{where}.heliostat = {field['heliostat']!r} is not a heliostat in config; "
                          f"known: {known}")
    layout, kind = field["layout"], field["layout"]["kind"]
    for key in _LAYOUT_REQUIRED[kind]:
        if key not in layout:
            raise ConfigError(f"{where}.layout: kind {kind!r} needs key {key!r}")
    extra = sorted(set(layout) - _LAYOUT_KEYS[kind] - {"kind"})
    if extra:
        raise ConfigError(f"{where}.layout: key {extra[0]!r} is not used by kind {kind!r}; "
                          f"kind {kind!r} takes {', '.join(sorted(_LAYOUT_KEYS[kind]))} (a --configfile variant that "
                          f"changes the kind removes config.yaml's keys with {extra[0]}: null)")
    if not any(abs(x) > 0 for x in field["receiver"]["normal"]):
        raise ConfigError(f"{where}.receiver.normal = {field['receiver']['normal']}: "
                          "expected a non-zero vector")
    measured = field["measured"]
    if ("indices" in measured) == ("fraction" in measured):
        raise ConfigError(f"{where}.measured: give exactly one of 'indices' (a list) "
                          "or 'fraction' (with 'seed')")
    networks = config.get("networks") or {}
    if field["network"] not in networks:
        raise ConfigError(f"{where}.network = {field['network']!r} is not in networks; "
                          f"networks has {', '.join(networks) or 'none'}")
    from helioflow.models.registry import network_classes

    if not network_classes(field["network"])[1].controllable:
        raise ConfigError(f"{where}.network = {field['network']!r} cannot be steered by the sun position; "
                          "choose a controllable model")
    check_effects(field["world_effects"], f"{where}.world_effects", allow_fit=False)
    check_effects(field["model_effects"], f"{where}.model_effects", allow_fit=True)
    _check_traced(field["calibration"], f"{where}.calibration")
    check_effects(field["calibration"].get("model_effects"), f"{where}.calibration.model_effects",
                  allow_fit=True)


_PAINT_KEYS = {"paint_dir", "heliostats", "resolution", "holdout", "targets", "centered"}
_TRACE_KEYS = {"sun", "splits", "trace", "world_effects"}


def _check_paint_dataset(config: dict, name: str, where: str) -> None:
    """A PAINT dataset takes no trace keys; its heliostat (a PAINT folder, whose geometry goes to
    surfaces/<heliostat>.h5), or each heliostat its plant entry selects (`heliostats`), is no
    configured heliostat and comes from one PAINT directory."""
    ds = config["datasets"][name]
    extra = sorted((_TRACE_KEYS | _IMAGES_KEYS) & set(ds))
    if extra:
        kind = "traced datasets" if extra[0] in _TRACE_KEYS else "own images (source: images)"
        raise ConfigError(f"{where}: key {extra[0]!r} is for {kind}; a PAINT dataset (source: paint) "
                          f"takes {', '.join(['heliostat or heliostats', *sorted(_PAINT_KEYS - {'heliostats'})])}")
    if ("heliostat" in ds) == ("heliostats" in ds):
        raise ConfigError(f"{where}: a PAINT dataset takes heliostat (one folder of paint_dir) or heliostats (a "
                          f"plant: all, a glob over the folders or a list of them), "
                          f"{'not both' if 'heliostat' in ds else 'one of them'}")
    paint_dir = Path(ds["paint_dir"])
    if not (paint_dir / "tower-measurements.json").is_file():
        raise ConfigError(f"{where}.paint_dir = {ds['paint_dir']!r}: no PAINT directory there (expected a folder with "
                          "tower-measurements.json and one folder per heliostat)")
    key = "heliostat" if "heliostat" in ds else "heliostats"
    try:
        selected = plant_heliostats(paint_dir, ds["heliostats"]) if key == "heliostats" else [ds["heliostat"]]
    except DataError as exc:
        raise ConfigError(f"{where}.{exc}") from None
    found = sorted(d.name for d in paint_dir.iterdir() if d.is_dir())
    for heliostat in selected:
        label = f"{where}.heliostat = {heliostat!r}" if key == "heliostat" else f"{where}.heliostats: {heliostat!r}"
        if heliostat in config["heliostats"]:
            raise ConfigError(f"{label} is also a configured heliostat; both would write surfaces/{heliostat}.h5: "
                              "rename the configured one")
        if heliostat not in found:
            raise ConfigError(f"{label}: no such heliostat folder in {ds['paint_dir']}; "
                              f"folders there: {', '.join(found) or 'none'}")
        for other, o in config["datasets"].items():
            if o["source"] == "paint" and o["paint_dir"] != ds["paint_dir"] and heliostat in _paint_selection(o):
                raise ConfigError(f"{where}.paint_dir = {ds['paint_dir']!r}, but datasets.{other} takes heliostat "
                                  f"{heliostat!r} from {o['paint_dir']!r}; one heliostat, one PAINT directory")
        if key == "heliostats" and not _NAME.fullmatch(f"{name}_{heliostat}"):
            raise ConfigError(f"{where}.heliostats: the dataset of heliostat {heliostat!r} would be named "
                              f"{name}_{heliostat!r}, not a valid name (letters, digits, '_', '.', '-', at most 64 "
                              "characters): shorten the entry's name")


def _check_images_plant(name: str, ds: dict, where: str) -> None:
    """An images dataset with `heliostats` (a plant in one CSV, its `heliostat` column) takes each
    heliostat's geometry from heliostat_properties with {heliostat} in its path (with origin_wgs84),
    every such file exists and every generated dataset name is valid."""
    from helioflow.data.images import HELIOSTAT_PLACEHOLDER, csv_heliostats

    if "heliostat" in ds or HELIOSTAT_PLACEHOLDER not in ds.get("heliostat_properties", ""):
        raise ConfigError(f"{where}: a plant's heliostats stand at their own positions: give heliostat_properties "
                          f"with {HELIOSTAT_PLACEHOLDER} in its path (e.g. paint/{HELIOSTAT_PLACEHOLDER}/heliostat-"
                          "properties.json, each heliostat's own) and origin_wgs84, not one inline heliostat")
    if "origin_wgs84" not in ds:
        raise ConfigError(f"{where}: heliostat_properties {ds['heliostat_properties']!r} gives WGS84 positions; "
                          "add origin_wgs84: [latitude, longitude, altitude], the origin of the target's ENU frame")
    try:
        heliostats = csv_heliostats(ds["csv"], ds["heliostats"])
    except DataError as exc:
        raise ConfigError(f"{where}.heliostats: {exc}") from None
    for heliostat in heliostats:
        path = Path(ds["heliostat_properties"].replace(HELIOSTAT_PLACEHOLDER, heliostat))
        if not path.is_file():
            raise ConfigError(f"{where}.heliostat_properties: {path} (heliostat {heliostat!r}) does not exist")
        if not _NAME.fullmatch(f"{name}_{heliostat}"):
            raise ConfigError(f"{where}.heliostats: the dataset of heliostat {heliostat!r} would be named "
                              f"{name}_{heliostat!r}, not a valid name (letters, digits, '_', '.', '-', at most 64 "
                              "characters): rename it in the CSV or shorten the entry's name")


def _paint_selection(ds: dict) -> list[str]:
    """The heliostat folders a PAINT dataset takes (none if its selection is itself in error)."""
    if "heliostat" in ds:
        return [ds["heliostat"]]
    try:
        return plant_heliostats(ds["paint_dir"], ds["heliostats"])
    except (DataError, OSError):
        return []


_NAME = re.compile(r"(?!.*[.][.])[A-Za-z0-9][A-Za-z0-9_.-]{0,63}")
_IMAGES_KEYS = {"images_dir", "csv", "target", "site", "heliostat_properties", "origin_wgs84"}
_IMAGES_TAKES = ("images_dir", "csv", "target", "heliostat or heliostat_properties with origin_wgs84", "site",
                 "resolution", "splits or holdout", "model_effects")


def _check_images_dataset(config: dict, name: str, where: str) -> None:
    """An images dataset (source: images) takes no trace or PAINT keys, one heliostat (inline and ideal,
    or heliostat_properties with origin_wgs84) that sees the target, splits or holdout (not both);
    its folder and CSV exist, the CSV's timestamps have a site, and its heliostat file
    (surfaces/<dataset>.h5) is no other heliostat's."""
    from helioflow.data.images import ERROR_KEYS, TIMESTAMP, check_files, check_ideal, csv_heliostats, read_table

    ds = config["datasets"][name]
    extra = sorted(((_TRACE_KEYS - {"splits"}) | {"paint_dir", "targets", "centered"}) & set(ds))
    if extra:
        raise ConfigError(f"{where}: key {extra[0]!r} is not for own images; a dataset with source: images takes "
                          f"{', '.join(_IMAGES_TAKES)}")
    if not any(abs(x) > 0 for x in ds["target"]["normal"]):
        raise ConfigError(f"{where}.target.normal = {ds['target']['normal']}: expected a non-zero vector")
    if "heliostats" in ds:
        _check_images_plant(name, ds, where)
    elif ("heliostat" in ds) == ("heliostat_properties" in ds):
        which = "both heliostat and" if "heliostat" in ds else "neither heliostat nor"
        raise ConfigError(f"{where}: {which} heliostat_properties; give exactly one: the geometry inline (heliostat: "
                          "the keys of a heliostats entry) or a PAINT-style heliostat-properties.json")
    elif "heliostat_properties" in ds:
        if "origin_wgs84" not in ds:
            raise ConfigError(f"{where}: heliostat_properties {ds['heliostat_properties']!r} gives WGS84 positions; "
                              "add origin_wgs84: [latitude, longitude, altitude], the origin of the target's ENU frame")
        if not Path(ds["heliostat_properties"]).is_file():
            raise ConfigError(f"{where}.heliostat_properties = {ds['heliostat_properties']!r}: no such file")
    else:
        if "origin_wgs84" in ds:
            raise ConfigError(f"{where}: origin_wgs84 is for heliostat_properties; an inline heliostat's position_m "
                              "is already ENU: remove it")
        try:
            check_ideal(ds["heliostat"], f"{where}.heliostat")
        except HelioflowError as exc:
            raise ConfigError(str(exc)) from None
        for key in ERROR_KEYS + ("seed",):
            ds["heliostat"].pop(key, None)
        _check_sees_target(ds["heliostat"]["position_m"], ds["target"], "the heliostat", where)
    if ds.get("splits") and ds.get("holdout"):
        raise ConfigError(f"{where}: give splits (rules on the sun positions) or holdout (image ids), not both")
    if name in config["heliostats"]:
        raise ConfigError(f"{where}: an images dataset's heliostat is named like the dataset and written to "
                          f"surfaces/{name}.h5, as is the configured heliostat {name!r}; rename the dataset")
    for other, o in config["datasets"].items():
        listed = o.get("heliostats") if isinstance(o.get("heliostats"), list) else []  # a PAINT plant's, when listed
        if o["source"] == "paint" and name in [o.get("heliostat"), *listed]:
            raise ConfigError(f"{where}: an images dataset's heliostat is named like the dataset and written to "
                              f"surfaces/{name}.h5, as is datasets.{other}'s PAINT heliostat; rename the dataset")
    if not Path(ds["images_dir"]).is_dir():
        raise ConfigError(f"{where}.images_dir = {ds['images_dir']!r}: no such folder")
    try:
        columns = read_table(ds["csv"])[0]
        selected: list[str | None] = list(csv_heliostats(ds["csv"], ds["heliostats"])) if "heliostats" in ds else [None]
        for heliostat in selected:
            check_files(ds["csv"], ds["images_dir"], heliostat)
    except DataError as exc:
        raise ConfigError(f"{where}.csv: {exc}") from None
    if TIMESTAMP in columns and not {"azimuth_deg", "elevation_deg"} <= set(columns) and "site" not in ds:
        raise ConfigError(f"{where}: {ds['csv']} gives the sun by {TIMESTAMP}; add site: {{latitude_deg, "
                          "longitude_deg, altitude_m}, where the images were taken")
