"""Split labelling of sun positions."""

import numpy as np
import pytest

from helioflow.data.splits import assign_splits
from helioflow.errors import ConfigError


def sun_grid(n=200, seed=0):
    rng = np.random.default_rng(seed)
    return rng.uniform(-90, 90, n), rng.uniform(5, 85, n)


def spec(above=None, below=None, azimuth=None, fraction=0.1):
    return {
        "extrapolation": {
            "elevation_above_deg": above,
            "elevation_below_deg": below,
            "azimuth_outside_deg": azimuth,
        },
        "interpolation": {"fraction": fraction},
    }


def test_deterministic_with_seed():
    az, el = sun_grid()
    a = assign_splits(az, el, spec(above=70.0), seed=3)
    b = assign_splits(az, el, spec(above=70.0), seed=3)
    c = assign_splits(az, el, spec(above=70.0), seed=4)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)


def test_extrapolation_criteria():
    az, el = sun_grid()
    labels = assign_splits(az, el, spec(above=70.0, below=15.0, azimuth=[-45, 45], fraction=0.0), seed=0)
    expected = (el > 70) | (el < 15) | (az < -45) | (az > 45)
    np.testing.assert_array_equal(labels == "extrapolation", expected)
    assert set(labels[~expected]) == {"train"}

    # The azimuth interval is closed: its end points are not extrapolation.
    az, el = np.array([-45.0, 0.0, 45.0]), np.full(3, 30.0)
    labels = assign_splits(az, el, spec(azimuth=[-45, 45], fraction=0), seed=0)
    assert labels.tolist() == ["train"] * 3


def test_interpolation_inside_train_range_and_fraction():
    az, el = sun_grid()
    labels = assign_splits(az, el, spec(above=70.0, fraction=0.2), seed=1)
    train, interp = labels == "train", labels == "interpolation"
    assert interp.sum() == round(0.2 * (el <= 70).sum())
    assert (az[interp] > az[train].min()).all() and (az[interp] < az[train].max()).all()
    assert (el[interp] > el[train].min()).all() and (el[interp] < el[train].max()).all()


def test_small_fraction_gives_at_least_one():
    az, el = sun_grid(n=5)
    labels = assign_splits(az, el, spec(fraction=0.01), seed=0)
    assert (labels == "interpolation").sum() == 1
    assert (labels == "train").sum() == 4


def test_no_train_left_is_config_error():
    az, el = sun_grid()
    with pytest.raises(ConfigError, match="no training position"):
        assign_splits(az, el, spec(above=1.0), seed=0)


def test_too_few_interior_positions_is_config_error():
    with pytest.raises(ConfigError, match="strictly inside"):
        assign_splits(np.array([0.0, 10.0]), np.array([20.0, 30.0]), spec(fraction=0.5), seed=0)


@pytest.mark.parametrize(
    "bad",
    [
        {"holdout": {}},
        {"extrapolation": {"elevation_over_deg": 70.0}},
        {"interpolation": {"fraction": 1.5}},
        {"extrapolation": {"azimuth_outside_deg": [10, -10]}},
    ],
)
def test_invalid_spec_is_config_error(bad):
    az, el = sun_grid(n=10)
    with pytest.raises(ConfigError, match="split spec"):
        assign_splits(az, el, bad, seed=0)


def test_elevation_bands_hold_out_contiguous_gaps_inside_the_range():
    el = np.linspace(5.0, 85.0, 81)
    az = np.full_like(el, 10.0)
    spec = {"extrapolation": {"elevation_above_deg": 75.0}, "interpolation": {"elevation_bands_deg": [[30, 35]]}}
    labels = assign_splits(az, el, spec, seed=0)
    assert set(el[labels == "interpolation"]) == {30.0, 31.0, 32.0, 33.0, 34.0, 35.0}
    assert (labels[el > 75] == "extrapolation").all()
    with pytest.raises(ConfigError, match="lowest or highest"):
        assign_splits(az, el, {"interpolation": {"elevation_bands_deg": [[0, 10]]}}, seed=0)


def test_the_docs_dataset_table_gives_the_splits_the_default_config_makes():
    """docs/data.md's table of the default datasets: its train / interp. / extrap. column is what
    config.yaml's sun positions and split rules give (no tracing needed)."""
    from pathlib import Path

    from helioflow.config import load_config
    from helioflow.data.synthetic import sun_positions

    repo = Path(__file__).resolve().parents[2]
    config = load_config(repo / "config.yaml")
    rows = {line.split("|")[1].strip(): line.split("|")[-2].strip()
            for line in (repo / "docs" / "data.md").read_text().splitlines() if line.startswith("| ")}
    for name in ("sanity_check", "semi_sphere"):
        ds = config["datasets"][name]
        az, el = sun_positions(ds["sun"], config["seed"])
        split = assign_splits(az, el, ds["splits"], config["seed"])
        counts = " / ".join(str(int((split == s).sum())) for s in ("train", "interpolation", "extrapolation"))
        assert rows[name] == counts, f"docs/data.md gives {name}'s splits as {rows[name]}; config.yaml makes {counts}"
