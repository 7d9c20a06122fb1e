"""The config's schema (workflow/schemas/config.schema.yaml): where every config default lives.

`validate_config` fills a config with them; the code that reads a section a config may leave out
(`plant`) fills it from here too, so that no default is written twice.
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


def section_with_defaults(config: dict, section: str) -> dict:
    """Config `section` (a top-level key; absent or null: its schema default) with the schema's
    defaults filled in, a copy."""
    schema = load_schema()
    sub = schema["properties"][section]
    node = copy.deepcopy(config.get(section))
    if node is None:
        node = copy.deepcopy(sub.get("default", {}))
    fill_defaults(node, sub, schema)
    return node
