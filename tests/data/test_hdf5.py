"""Round trip, atomicity and error discipline of the HDF5 schema module."""

import h5py
import numpy as np
import pytest

from helioflow.data.hdf5 import (
    DATASET_SCHEMA,
    CalibrationDataset,
    read_arrays,
    read_dataset,
    write_arrays,
    write_dataset,
)
from helioflow.errors import DataError, OutputError


def make_dataset(n=4, h=8, w=6) -> CalibrationDataset:
    rng = np.random.default_rng(0)
    return CalibrationDataset(
        images=rng.uniform(0, 1000, size=(n, h, w)).astype(np.float32),
        azimuth_deg=np.linspace(-60, 60, n),
        elevation_deg=np.linspace(10, 80, n),
        split=np.array(["train", "interpolation", "train", "extrapolation"][:n]),
        attrs={
            "heliostat": "AA39",
            "json_looking": "json:not really",
            "seed": 7,
            "pixel_m": 0.25,
            "flag": True,
            "target": {"center_m": [0.0, -1.5, 40.0], "nested": {"n": None, "names": ["a", "b"]}},
            "shape": [h, w],
        },
        extras={
            "fill_fraction": rng.uniform(size=n),
            "centroid_m": rng.normal(size=(n, 2)),
        },
    )


def test_round_trip_is_exact(tmp_path):
    ds = make_dataset()
    path = tmp_path / "sub" / "ds.h5"
    write_dataset(path, ds)
    back = read_dataset(path)

    np.testing.assert_array_equal(back.images, ds.images)
    assert back.images.dtype == np.float32
    np.testing.assert_array_equal(back.azimuth_deg, ds.azimuth_deg)
    np.testing.assert_array_equal(back.elevation_deg, ds.elevation_deg)
    assert back.split.tolist() == ds.split.tolist()
    assert back.attrs == ds.attrs
    assert back.extras.keys() == ds.extras.keys()
    for name, arr in ds.extras.items():
        np.testing.assert_array_equal(back.extras[name], arr)
    assert back.indices("train").tolist() == [0, 2]
    assert back.indices("extrapolation").tolist() == [3]

    with h5py.File(path, "r") as f:
        assert f.attrs["schema"] == DATASET_SCHEMA
        assert f["images"].attrs["units"] == "W/m^2"
        assert f["sun/elevation_deg"].attrs["units"] == "deg"
        assert f["images"].compression == "gzip"
        assert f["images"].chunks == (1, 8, 6)
    assert [p.name for p in path.parent.iterdir()] == ["ds.h5"]


def test_generic_arrays_round_trip_and_required_key(tmp_path):
    path = tmp_path / "model.h5"
    arrays = {"weights/w": np.arange(6.0).reshape(2, 3), "names": np.array(["x", "ÿ"])}
    write_arrays(path, arrays, {"config": {"lr": 1e-3}}, "helioflow.test/1")
    got, attrs = read_arrays(path, "helioflow.test/1", required=["weights/w"])
    np.testing.assert_array_equal(got["weights/w"], arrays["weights/w"])
    assert got["names"].tolist() == ["x", "ÿ"]
    assert attrs == {"config": {"lr": 1e-3}}

    with pytest.raises(DataError, match=r"model\.h5.*'weights/b'"):
        read_arrays(path, "helioflow.test/1", required=["weights/b"])


def test_failed_write_leaves_nothing_and_names_the_file(tmp_path, monkeypatch):
    """A full disk while writing: no output, no temporary file holding the space, one clear error."""
    def full_disk(*args, **kwargs):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(h5py.Dataset, "__setitem__", full_disk)
    monkeypatch.setattr(h5py.Group, "create_dataset", full_disk)
    path = tmp_path / "out.h5"
    with pytest.raises(OutputError, match=r"cannot write .*out\.h5: No space left on device"):
        write_dataset(path, make_dataset())
    assert list(tmp_path.iterdir()) == []


def test_missing_file(tmp_path):
    with pytest.raises(DataError, match="does not exist"):
        read_dataset(tmp_path / "nope.h5")


def test_truncated_file_names_path(tmp_path):
    path = tmp_path / "trunc.h5"
    write_dataset(path, make_dataset(n=4, h=64, w=64))
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(DataError, match=r"trunc\.h5 is not a readable HDF5 file"):
        read_dataset(path)


def test_random_bytes_file(tmp_path):
    path = tmp_path / "junk.h5"
    path.write_bytes(np.random.default_rng(1).bytes(4096))
    with pytest.raises(DataError, match=r"junk\.h5 is not a readable HDF5 file"):
        read_dataset(path)


def test_missing_key_is_named(tmp_path):
    path = tmp_path / "ds.h5"
    write_dataset(path, make_dataset())
    with h5py.File(path, "a") as f:
        del f["sun/elevation_deg"]
    with pytest.raises(DataError, match="'sun/elevation_deg'"):
        read_dataset(path)


def test_wrong_schema(tmp_path):
    path = tmp_path / "other.h5"
    write_arrays(path, {"images": np.zeros((1, 2, 2))}, {}, "helioflow.model/1")
    with pytest.raises(DataError, match="schema 'helioflow.model/1', expected 'helioflow.dataset/1'"):
        read_dataset(path)
    with h5py.File(path, "a") as f:
        del f.attrs["schema"]
    with pytest.raises(DataError, match="no 'schema' attribute"):
        read_dataset(path)


def test_nan_image_rejected_on_write_and_read(tmp_path):
    ds = make_dataset()
    ds.images[1, 2, 3] = np.nan
    path = tmp_path / "nan.h5"
    with pytest.raises(DataError, match="NaN"):
        write_dataset(path, ds)
    assert not path.exists()

    write_dataset(path, make_dataset())
    with h5py.File(path, "a") as f:
        f["images"][0, 0, 0] = np.nan
    with pytest.raises(DataError, match=r"nan\.h5.*NaN"):
        read_dataset(path)


@pytest.mark.parametrize(
    "field, value, message",
    [
        ("images", -np.ones((4, 8, 6), np.float32), "negative flux"),
        ("elevation_deg", np.array([10.0, 0.0, 30.0, 40.0]), r"outside \(0, 90\]"),
        ("split", np.array(["train", "test", "train", "train"]), "unknown split labels"),
        ("azimuth_deg", np.zeros(3), r"azimuth_deg has shape \(3,\)"),
    ],
)
def test_invalid_dataset_not_written(tmp_path, field, value, message):
    ds = make_dataset()
    setattr(ds, field, value)
    with pytest.raises(DataError, match=message):
        write_dataset(tmp_path / "bad.h5", ds)
    assert list(tmp_path.iterdir()) == []
