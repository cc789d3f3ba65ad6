"""Named arrays in one file, opened memory-mapped: what is read back, and what is refused."""

from __future__ import annotations

import zipfile
from pathlib import Path

import numpy as np
import pytest

from geoloc.core.array_file import is_mapped, map_arrays, write_arrays


def test_arrays_read_back_equal_read_only_and_mapped(tmp_path: Path) -> None:
    path = tmp_path / "a.npz"
    arrays = {
        "floats": np.random.default_rng(0).normal(size=(1000, 2)),
        "ints": np.arange(7, dtype=np.int32),
        "fortran": np.asfortranarray(np.arange(12, dtype=np.uint16).reshape(3, 4)),
        "empty": np.zeros((0, 2)),
        "bools": np.array([True, False, True]),
        "scalar": np.array(3.5),
    }
    write_arrays(path, arrays)
    back = map_arrays(path)
    assert set(back) == set(arrays)
    for name, array in arrays.items():
        assert back[name].dtype == array.dtype and back[name].shape == array.shape, name
        assert np.array_equal(back[name], array), name
        assert not back[name].flags.writeable, name
        with pytest.raises(ValueError):
            back[name][...] = 0
    assert is_mapped(back["floats"]) and not is_mapped(arrays["floats"])  # a view of the file's pages, not a copy
    with np.load(path) as npz:  # still a plain .npz
        assert np.array_equal(npz["floats"], arrays["floats"])


def test_a_compressed_or_foreign_file_is_refused(tmp_path: Path) -> None:
    compressed = tmp_path / "c.npz"
    np.savez_compressed(compressed, a=np.arange(10))
    with pytest.raises(ValueError, match="compressed"):
        map_arrays(compressed)
    foreign = tmp_path / "f.npz"
    foreign.write_bytes(b"not a zip at all")
    with pytest.raises(ValueError, match="not an array file"):
        map_arrays(foreign)
    objects = tmp_path / "o.npz"
    with zipfile.ZipFile(objects, "w") as archive, archive.open("a.npy", "w") as member:
        np.lib.format.write_array(member, np.array([{"x": 1}], dtype=object), allow_pickle=True)
    with pytest.raises(ValueError, match="objects"):
        map_arrays(objects)


def test_a_replaced_file_leaves_earlier_mappings_intact(tmp_path: Path) -> None:
    path = tmp_path / "a.npz"
    write_arrays(path, {"x": np.arange(100_000, dtype=np.int64)})
    first = map_arrays(path)["x"]
    write_arrays(path, {"x": np.zeros(100_000, dtype=np.int64)})
    assert int(first.sum()) == 99_999 * 100_000 // 2 and int(map_arrays(path)["x"].sum()) == 0
