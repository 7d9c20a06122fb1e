"""A field in the config (`field`): its layout, its heliostats and their datasets, the geometry check,
and `expand_field`, which adds them to the config.
"""

from __future__ import annotations

import copy
import functools
import json
from pathlib import Path

from helioflow.errors import ConfigError, DataError

# --- the field (config `field`, rule compose_field) --------------------------------------------

FIELD_PREFIX = "field_"


LAYOUT_DEFAULTS = {"spacing_m": "auto", "clearance_m": 1.0, "sector_deg": 120.0, "pivot_height_m": 0.0}  # fermat,
# radial: not the schema's, which would give a list or csv layout keys its kind refuses (config._check_field)


FIELD_ONLY_EFFECTS = ("blocking_shading",)  # acts in field traces only: left out of calibration datasets


def field_size(field: dict) -> int:
    """Number of heliostats of the field's layout (layout.n, or the rows of the list / CSV file)."""
    layout = field["layout"]
    if layout["kind"] in ("fermat", "radial"):
        return layout["n"]
    if layout["kind"] == "list":
        return len(layout["positions"])
    return len(field_positions(field, {}))


def field_positions(field: dict, template: dict) -> list[list[float]]:
    """Pivot positions of the field's layout (`layout_positions`), computed once per layout and
    template mirror: snakemake asks for them for every job while it builds the DAG."""
    layout = field["layout"]
    csv = Path(layout["csv"]) if layout["kind"] == "csv" else None
    stamp = (csv.stat().st_mtime_ns, csv.stat().st_size) if csv is not None and csv.is_file() else None
    mirror = mirror_size(template) if layout["kind"] in ("fermat", "radial") else None  # list, csv: not used
    key = json.dumps([layout, mirror, stamp], sort_keys=True)
    return [list(row) for row in _positions_of(key)]


@functools.lru_cache(maxsize=8)
def _positions_of(key: str) -> list[list[float]]:
    layout, mirror, _ = json.loads(key)
    return layout_positions(layout, mirror)


def layout_positions(layout: dict, mirror: list[float] | None) -> list[list[float]]:
    """Pivot positions, (n, 3) ENU in m rounded to the mm, of a field layout (config field.layout)
    for a template mirror of `mirror` = (width, height) m.

    fermat / radial: helioflow.physics.layout.fermat_spiral / radial_staggered of layout.n
    heliostats outside min_radius_m in a sector of sector_deg around north, pivots pivot_height_m
    up, no two closer than spacing_m (auto: the template mirror's diagonal plus clearance_m,
    layout.min_spacing); list: the rows [east, north(, up)] of layout.positions; csv: the rows of
    the file layout.csv (a header row is allowed). Defaults: LAYOUT_DEFAULTS.
    """
    from helioflow.physics import layout as geometry

    spec = {**LAYOUT_DEFAULTS, **layout}
    if spec["kind"] == "list":
        positions = geometry.positions_from_list(spec["positions"], "field.layout.positions")
    elif spec["kind"] == "csv":
        try:
            positions = geometry.load_positions(spec["csv"])
        except DataError as exc:
            raise ConfigError(f"field.layout.csv: {exc}") from None
    else:
        spacing = spec["spacing_m"]
        if spacing == "auto":
            assert mirror is not None, "an auto spacing needs the template mirror"
            width, height = mirror
            spacing = geometry.min_spacing(width, height, spec["clearance_m"])
        generate = geometry.fermat_spiral if spec["kind"] == "fermat" else geometry.radial_staggered
        positions = generate(spec["n"], spacing, spec["min_radius_m"], spec["sector_deg"],
                             spec["pivot_height_m"])
    return [[round(x, 3) for x in row] for row in positions.tolist()]


def mirror_size(heliostat: dict) -> tuple[float, float]:
    """(width, height) in m of a heliostat section's mirror (validated: gap_m the schema's default where
    not set): its facets and the gaps between them."""
    f = heliostat["facets"]
    gap = f["gap_m"]
    return f["cols"] * f["width_m"] + (f["cols"] - 1) * gap, f["rows"] * f["height_m"] + (f["rows"] - 1) * gap


def field_names(n: int) -> list[str]:
    """field_000, field_001, ... (at least three digits; more for fields of 1000 and more)."""
    width = max(3, len(str(n - 1)))
    return [f"{FIELD_PREFIX}{i:0{width}d}" for i in range(n)]


def measured_indices(field: dict, n: int) -> list[int]:
    """Sorted layout indices of the measured heliostats of a validated `field`: measured.indices, or a
    seeded random choice (numpy default_rng(measured.seed), the schema's default where not set) of
    max(1, round(fraction * n)) heliostats."""
    measured = field["measured"]
    if "indices" in measured:
        bad = [i for i in measured["indices"] if i >= n]
        if bad:
            raise ConfigError(f"field.measured.indices has {bad[0]}, but the field has {n} heliostats "
                              f"(indices 0 to {n - 1})")
        return sorted(measured["indices"])
    import numpy as np

    count = max(1, round(measured["fraction"] * n))
    return sorted(np.random.default_rng(measured["seed"]).choice(n, count, replace=False).tolist())


def field_measured(config: dict) -> list[str]:
    """Names of the measured field heliostats, which are also their calibration datasets' names
    (none without a field section)."""
    field = config.get("field")
    if not field:
        return []
    names = field_names(field_size(field))
    return [names[i] for i in measured_indices(field, len(names))]


def field_heliostats(config: dict) -> dict[str, dict]:
    """The generated `heliostats` entries of the measured field heliostats (field_measured): field
    heliostat i is the template's section with its own position and seed (field.seed + i), so that
    the `surfaces` rule gives it its own errors. The others need no entry: compose_field builds them
    from their positions and seeds (compose_field_params)."""
    field = config["field"]
    template = config["heliostats"][field["heliostat"]]
    positions = field_positions(field, template)
    names = field_names(len(positions))
    return {names[i]: {**copy.deepcopy(template), "position_m": positions[i], "seed": field["seed"] + i}
            for i in measured_indices(field, len(positions))}


def _field_effects(effects: dict | None) -> dict:
    return {k: copy.deepcopy(v) for k, v in (effects or {}).items() if k not in FIELD_ONLY_EFFECTS}


def field_datasets(config: dict) -> dict[str, dict]:
    """The generated `datasets` entries: one calibration dataset per measured heliostat, named
    like it, from field.calibration. Its world (and model) effects are field.world_effects
    (model_effects) without the field-only ones, then the calibration's own entries: the
    calibration images see the same atmosphere as the field."""
    field = config["field"]
    calibration = copy.deepcopy(field["calibration"])
    world = {**_field_effects(field.get("world_effects")), **calibration.pop("world_effects", {})}
    model = {**_field_effects(field.get("model_effects")), **calibration.pop("model_effects", {})}
    return {name: {"source": "synthetic", "heliostat": name, **copy.deepcopy(calibration),
                   "world_effects": copy.deepcopy(world), "model_effects": copy.deepcopy(model)}
            for name in field_measured(config)}


def facing(position_m, center_m, normal):
    """Distance (m) of a point (3,), or of points (n, 3), in front of a plane (centre, normal towards
    the field): > 0 when a heliostat there can see the plane, <= 0 when it is in the plane or behind
    it. A float for one point, an (n,) array for several."""
    import numpy as np

    n = np.asarray(normal, dtype=float)
    distance = np.subtract(position_m, center_m) @ (n / np.linalg.norm(n))
    return float(distance) if np.ndim(distance) == 0 else distance


def check_field_geometry(config: dict) -> None:
    """ConfigError naming the heliostat when a field heliostat is behind the receiver (or, measured,
    behind the calibration target), or when two pivots are closer than the mirror diagonal (their
    mirrors would collide: list and csv layouts; fermat and radial keep their spacing)."""
    import numpy as np
    from scipy.spatial import cKDTree

    from helioflow.physics.layout import min_spacing

    field = config["field"]
    template = config["heliostats"][field["heliostat"]]
    positions = field_positions(field, template)
    names = field_names(len(positions))
    xyz = np.asarray(positions)
    receiver, target = field["receiver"], config["target"]
    measured = np.zeros(len(xyz), dtype=bool)
    measured[measured_indices(field, len(xyz))] = True
    behind = np.nonzero(facing(xyz, receiver["center_m"], receiver["normal"]) <= 0)[0]
    if len(behind):
        i = int(behind[0])
        raise ConfigError(f"field: heliostat {names[i]} at {positions[i]} is behind the receiver (field.receiver."
                          f"center_m {receiver['center_m']}, normal {receiver['normal']}): it cannot reach it")
    behind = np.nonzero(measured & (facing(xyz, target["center_m"], target["normal"]) <= 0))[0]
    if len(behind):
        i = int(behind[0])
        raise ConfigError(f"field: measured heliostat {names[i]} at {positions[i]} is behind the calibration target "
                          f"(target.center_m {target['center_m']}, normal {target['normal']}): it cannot see it")
    if field["layout"]["kind"] not in ("list", "csv") or len(xyz) < 2:
        return
    diagonal = min_spacing(*mirror_size(template))
    xy = xyz[:, :2]
    pairs = [(a, b) for a, b in cKDTree(xy).query_pairs(diagonal) if np.linalg.norm(xy[a] - xy[b]) < diagonal]
    if pairs:
        a, b = min(pairs)
        raise ConfigError(f"field.layout: heliostats {names[a]} {positions[a]} and {names[b]} {positions[b]} are "
                          f"{np.linalg.norm(xy[a] - xy[b]):.2f} m apart, less than the mirror diagonal "
                          f"{diagonal:.2f} m: "
                          "their mirrors would collide")


def expand_field(config: dict) -> dict:
    """The config with the field's generated `heliostats` and `datasets` entries added (a copy; the
    config itself without a field section). Applied right after validation (common.smk, the
    CLI), so that the existing surfaces, trace, train and evaluate rules build the field's
    heliostat geometries, calibration datasets and models. A generated name already in use
    raises ConfigError."""
    config = copy.deepcopy(config)
    if not config.get("field"):
        return config
    check_field_geometry(config)
    generated = set(field_names(field_size(config["field"])))
    for section, entries in (("heliostats", field_heliostats(config)), ("datasets", field_datasets(config))):
        taken = sorted(generated & set(config[section]))
        if taken:
            raise ConfigError(f"field: the generated name {taken[0]!r} is already in {section}; rename that "
                              f"entry (field heliostats and their datasets are named {FIELD_PREFIX}<index>)")
        config[section].update(entries)
    return config
