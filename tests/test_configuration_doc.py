"""docs/configuration.md documents every key of the config schema and every network setting, and
nothing that the schema or the networks' config classes do not have."""

import dataclasses
import re
from pathlib import Path

import yaml

from helioflow.models.registry import GEOMETRY_ATTRIBUTES, LOOP_KEYS, network_classes

REPO = Path(__file__).resolve().parents[1]
SCHEMA = yaml.safe_load((REPO / "workflow" / "schemas" / "config.schema.yaml").read_text())
DOC = (REPO / "docs" / "configuration.md").read_text()
SHARED = {"sun_positions": "sun", "splits": "splits", "trace": "trace", "aim": "aim",
          "design_points": "design_points", "diagnosis": "diagnosis",
          "optimise_aim": "optimise_aim"}  # blocks documented once, by these names
NETWORKS = ("nearest", "gan", "cgan", "nerf", "raytrace", "drt")
SET_BY_THE_PIPELINE = {"effects", "heliostat_path"}  # physics-model fields the workflow fills in


def schema_keys() -> set[str]:
    """Every key path of the schema: `a.b.c`, `<name>` for a user-named entry; a shared block's keys
    under its own name (`sun.kind`)."""
    keys: set[str] = set()

    def walk(node: dict, path: str) -> None:
        ref = node.get("$ref", "").split("/")[-1]
        if ref in SHARED:
            walk(SCHEMA["definitions"][ref], SHARED[ref])
            return
        for key, child in (node.get("properties") or {}).items():
            keys.add(f"{path}.{key}" if path else key)
            walk(child, f"{path}.{key}" if path else key)
        if isinstance(node.get("additionalProperties"), dict) and path not in ("networks",):
            walk(node["additionalProperties"], f"{path}.<name>")

    walk(SCHEMA, "")
    return keys


def network_keys() -> set[str]:
    """networks.<network>.<setting> for every setting a network takes."""
    keys = set()
    for network in NETWORKS:
        config_cls, model_cls = network_classes(network)
        fields = {f.name for f in dataclasses.fields(config_cls)} - set(GEOMETRY_ATTRIBUTES) - SET_BY_THE_PIPELINE
        loop = set(LOOP_KEYS) if model_cls.uses_loop else set()
        keys |= {f"networks.{network}.{k}" for k in fields | loop}
    return keys


def documented() -> set[str]:
    """The keys in the first column of the document's tables."""
    return set(re.findall(r"^\| `([^`]+)` \|", DOC, flags=re.MULTILINE))


def test_every_schema_key_and_network_setting_is_documented():
    missing = sorted((schema_keys() | network_keys()) - documented())
    assert not missing, f"docs/configuration.md lacks {missing}"


def test_every_documented_key_exists():
    unknown = sorted(documented() - schema_keys() - network_keys())
    assert not unknown, f"docs/configuration.md documents keys the schema does not have: {unknown}"
