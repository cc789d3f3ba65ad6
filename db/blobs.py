"""Numpy arrays <-> compressed ``.npz`` blobs (no pickle either way)."""

from __future__ import annotations

import io

import numpy as np


def pack_arrays(arrays: dict[str, np.ndarray], compress: bool = True) -> bytes:
    """A dict of arrays as one ``.npz`` blob.

    Compressed unless ``compress=False``: floats hardly compress, and zlib costs seconds on a city's
    facades.
    """
    buffer = io.BytesIO()
    save = np.savez_compressed if compress else np.savez
    # allow_pickle is numpy's default, named so that the arrays are not matched against it (mypy).
    save(buffer, allow_pickle=True, **{name: np.asarray(value) for name, value in arrays.items()})
    return buffer.getvalue()


def unpack_arrays(blob: bytes) -> dict[str, np.ndarray]:
    """The dict of arrays stored by :func:`pack_arrays`."""
    with np.load(io.BytesIO(blob), allow_pickle=False) as npz:
        return {name: npz[name] for name in npz.files}
