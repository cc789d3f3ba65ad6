"""The local-feature types by name (:mod:`geoloc.vision.features` extracts them) and their descriptor lengths.

A module of its own so that the built models' files (:mod:`geoloc.vision.model_files`, which names a
vocabulary by feature type) need not import the extraction (which imports the ALIKED runtime).
"""

from __future__ import annotations

FEATURE_METHODS = ("rootsift", "aliked-n16", "aliked-t16")
DESCRIPTOR_DIMS = {"rootsift": 128, "aliked-n16": 128, "aliked-t16": 64}
METHOD_ALIASES = {"aliked": "aliked-n16"}
DEFAULT_METHOD = "rootsift"
"""The feature type used wherever none is given (pipeline, vocabulary). See :mod:`geoloc.vision.features`."""


def canonical_method(method: str | None) -> str:
    """The canonical feature type name ("rootsift", "aliked-n16", "aliked-t16"); None is :data:`DEFAULT_METHOD`.

    Raises ValueError for an unknown name.
    """
    name = DEFAULT_METHOD if method is None else METHOD_ALIASES.get(method, method)
    if name not in FEATURE_METHODS:
        raise ValueError(f"unknown feature method {method!r}; known: {', '.join(FEATURE_METHODS)} (or 'aliked')")
    return name
