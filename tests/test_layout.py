"""The package's architecture: each part of src/helioflow imports only the parts below it.

Every import counts, at the top of a module or inside a function: a function-level import is a
loop all the same, only hidden until the function runs.
"""

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "src" / "helioflow"

# Bottom to top. A part may import itself and the parts before it, never one after it.
LAYERS = (
    "__init__",  # the version
    "errors",
    "schema",  # the config schema's defaults
    "io",  # atomic writes, torch files, fingerprints
    "checks",
    "device",
    "plotting",
    "physics",  # tracer, scene, effects, field geometry
    "data",  # HDF5 schema, surfaces, synthetic datasets, PAINT and own images
    "models",  # the networks, the physics models and their fit
    "scoring",  # metrics, evaluation, Table 1, recovery, leave-one-out
    "diagnosis",
    "field",  # field flux maps
    "report",
    "workflow",  # the Snakefile's rule helpers
    "batch",  # a plant's steps in groups, one process per group
    "config",  # validation of a whole config
    "cli",
    "bench",
    "__main__",
)


def part_of(module: Path) -> str:
    """src/helioflow/physics/raytrace.py -> 'physics'; src/helioflow/cli.py -> 'cli'."""
    rel = module.relative_to(PACKAGE)
    return rel.parts[0] if len(rel.parts) > 1 else rel.stem


def imported_modules(module: Path) -> set[str]:
    """Every helioflow module `module` imports, anywhere in it, as dotted names without 'helioflow.'."""
    package = ["helioflow", *module.relative_to(PACKAGE).parent.parts]
    names = set()
    for node in ast.walk(ast.parse(module.read_text(), str(module))):
        if isinstance(node, ast.Import):
            names.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = package[: len(package) - node.level + 1] if node.level else []
            target = ".".join([*base, node.module] if node.module else base)
            names.add(target)
            names.update(f"{target}.{a.name}" for a in node.names)  # `from helioflow import workflow`
    return {n.removeprefix("helioflow.") for n in names if n == "helioflow" or n.startswith("helioflow.")}


def part_imports() -> dict[str, set[str]]:
    """{part: the other parts it imports}."""
    graph: dict[str, set[str]] = {}
    for module in sorted(PACKAGE.rglob("*.py")):
        imports = graph.setdefault(part_of(module), set())
        for name in imported_modules(module):
            first = name.split(".")[0] if name != "helioflow" else "__init__"
            if (PACKAGE / first).is_dir() or (PACKAGE / f"{first}.py").exists():
                imports.add(first)
    return {p: i - {p} for p, i in graph.items()}


def test_every_part_has_a_place_in_the_layers():
    assert set(part_imports()) == set(LAYERS)


@pytest.mark.parametrize("part", LAYERS)
def test_a_part_imports_only_the_parts_below_it(part):
    above = set(LAYERS[LAYERS.index(part) + 1:])
    assert not part_imports()[part] & above, f"{part} imports {sorted(part_imports()[part] & above)}"


def test_no_module_imports_itself_back():
    """No loop between modules either, inside a part included (e.g. physics.effects <-> raytrace)."""
    modules = {".".join(m.relative_to(PACKAGE).with_suffix("").parts): m for m in PACKAGE.rglob("*.py")}
    graph = {name: {n for n in imported_modules(path) if n in modules and n != name} for name, path in modules.items()}
    state: dict[str, int] = {}  # 1 = on the current path, 2 = done

    def visit(name: str, path: list[str]) -> None:
        state[name] = 1
        for nxt in sorted(graph[name]):
            assert state.get(nxt) != 1, "import loop: " + " -> ".join([*path, name, nxt])
            if nxt not in state:
                visit(nxt, [*path, name])
        state[name] = 2

    for name in sorted(graph):
        if name not in state:
            visit(name, [])


def test_the_checker_sees_function_level_imports():
    module = PACKAGE / "config.py"
    assert "data.images" in imported_modules(module)  # imported inside _check_images_dataset
