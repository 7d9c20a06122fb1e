"""The config's schema (workflow/schemas/config.schema.yaml): where every config default lives.

`validate_config` fills a config with them; the code that reads a part a config may leave out, or
that tests build by hand (`plant`, `plan`), fills it from here too, so that no
default is written twice.
"""

from __future__ import annotations

import copy
import functools
from pathlib import Path

import yaml

SCHEMA_PATH = Path(__file__).resolve().parents[2] / "workflow" / "schemas" / "config.schema.yaml"


@functools.lru_cache(maxsize=4)
def load_schema(path: str = str(SCHEMA_PATH)) -> dict:
    """The schema at `path` as a dict (read once per process)."""
    return yaml.safe_load(Path(path).read_text())


def fill_defaults(node, schema: dict, root: dict) -> None:
    """Fill, in place, the keys of `node` that `schema` (a part of the schema `root`) gives a
    default and `node` lacks, at every depth (objects only)."""
    if "$ref" in schema:
        schema = root["definitions"][schema["$ref"].rsplit("/", 1)[-1]]
    if not isinstance(node, dict):
        return
    for key, sub in schema.get("properties", {}).items():
        if key not in node and "default" in sub:
            node[key] = copy.deepcopy(sub["default"])
        if key in node:
            fill_defaults(node[key], sub, root)
    extra = schema.get("additionalProperties")
    if isinstance(extra, dict):
        for key in set(node) - set(schema.get("properties", {})):
            fill_defaults(node[key], extra, root)


def with_defaults(node: dict | None, *path: str) -> dict:
    """`node`, the config's part at the key path `path` (("plant",), ("field", "layout"); a named entry
    by its name, ("heliostats", name); None: absent, so its schema default or {}), with the schema's
    defaults filled in: a copy."""
    schema = load_schema()
    sub = schema
    for key in path:
        if "$ref" in sub:
            sub = schema["definitions"][sub["$ref"].rsplit("/", 1)[-1]]
        properties = sub.get("properties", {})
        sub = properties[key] if key in properties else sub["additionalProperties"]
    filled = copy.deepcopy(node if node is not None else sub.get("default", {}))
    fill_defaults(filled, sub, schema)
    return filled
