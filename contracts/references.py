"""The stored format of a labelled reference: its keypoint arrays and its label arrays, defined once.

A labelled reference is stored as two ``.npz`` blobs (:mod:`db.references`): its keypoints
(:class:`ReferenceKeypoints`, what the query stage reads back) and its labels (:class:`ReferenceLabelArrays`,
what the identity overlay draws). Each is a frozen dataclass whose field names are the stored array names:
:meth:`to_arrays` writes every field under its own name (optional fields only when set) and ``from_arrays``
reads them back, with the defaults of references stored before a field existed. The dtypes are the format's
and are written in each field's metadata: ``stored`` is what is written (descriptors as float16: unit vectors
with components in [-1, 1]; anchors as float32/int32), ``read`` what comes back (float32 descriptors,
float64/int64 anchors); a field without a dtype is written and read as it is.

The method's side converts: ``geoloc.localize.reference.LabelledReference.keypoints`` builds one,
``geoloc.localize.store.StoredReference.from_keypoints`` reads one. Frames and units: ``xy`` pixels of the
working-size photo, ``image_shape`` its (H, W[, C]), ``scale`` working size over original; anchors in local
metres of the map's frame; ``position_xy`` (2,) local metres, ``position_covariance`` (2, 2) m^2.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from typing import Any, Final

import numpy as np

UNKNOWN_POSITION_SIGMA_M: Final = 10.0
"""Position uncertainty (m, 1 sigma) credited to a reference stored before labelling recorded one."""
DEFAULT_METHOD: Final = "rootsift"
"""The feature type of references stored before ``method`` was recorded (the only one then)."""


def _dtypes(stored: type[Any] | None = None, read: type[Any] | None = None) -> dict[str, type[Any] | None]:
    """Field metadata: the dtype an array is written with and the one it is read back with (None: as it is)."""
    return {"stored": stored, "read": read}


def _cast(value: Any, dtype: type[Any] | None) -> np.ndarray:
    """``value`` as an array of ``dtype`` (a copy only when the dtype differs; None keeps it as it is)."""
    return np.asarray(value) if dtype is None else np.asarray(value).astype(dtype, copy=False)


@dataclass(frozen=True)
class ReferenceKeypoints:
    """A labelled reference's keypoints as stored: N features, their identities and their map anchors.

    xy (N, 2), descriptors (N, D), sizes, angles, responses (N,): the local features (``method`` names their
    type); identity (N, M): each keypoint's identity probabilities over ``building_ids`` (M,); anchor_* (N, 3),
    (N,): each keypoint's 3D point on the map's facades, its facade and building (-1: none) and its distance
    (m); alt_anchor_*: the same from the runner-up pose of an ambiguous label (None when there is none).
    """

    xy: np.ndarray
    descriptors: np.ndarray = field(metadata=_dtypes(np.float16, np.float32))
    sizes: np.ndarray
    angles: np.ndarray
    responses: np.ndarray
    image_shape: tuple[int, int]
    scale: float
    method: str
    identity: np.ndarray
    building_ids: np.ndarray
    anchor_xyz: np.ndarray = field(metadata=_dtypes(np.float32, np.float64))
    anchor_facade_id: np.ndarray = field(metadata=_dtypes(np.int32, np.int64))
    anchor_building_id: np.ndarray = field(metadata=_dtypes(np.int32, np.int64))
    anchor_distance_m: np.ndarray = field(metadata=_dtypes(np.float32, np.float64))
    position_covariance: np.ndarray = field(metadata=_dtypes(None, np.float64))
    position_xy: np.ndarray = field(metadata=_dtypes(None, np.float64))
    alt_anchor_xyz: np.ndarray | None = field(default=None, metadata=_dtypes(np.float32, np.float64))
    alt_anchor_facade_id: np.ndarray | None = field(default=None, metadata=_dtypes(np.int32, np.int64))
    alt_anchor_building_id: np.ndarray | None = field(default=None, metadata=_dtypes(np.int32, np.int64))
    alt_anchor_distance_m: np.ndarray | None = field(default=None, metadata=_dtypes(np.float32, np.float64))

    def to_arrays(self) -> dict[str, np.ndarray]:
        """The arrays to store, named by the fields, in the stored dtypes (unset optional fields left out)."""
        arrays: dict[str, np.ndarray] = {}
        for spec in fields(self):
            value = getattr(self, spec.name)
            if value is None:
                continue
            if spec.name == "image_shape":
                arrays[spec.name] = np.asarray(value, np.int64)
            elif spec.name == "scale":
                arrays[spec.name] = np.asarray(value, np.float64)
            else:
                arrays[spec.name] = _cast(value, spec.metadata.get("stored"))
        return arrays

    @classmethod
    def from_arrays(cls, arrays: Mapping[str, np.ndarray]) -> ReferenceKeypoints:
        """The keypoints from their stored arrays (a dict or an ``np.load`` result), in the read dtypes.

        References stored before a field existed get its default: no ``method``: :data:`DEFAULT_METHOD`; no
        anchors: NaN points, facade and building -1; no covariance: ``UNKNOWN_POSITION_SIGMA_M``^2 on the
        diagonal; no position: NaN. The alternative anchors are read when ``alt_anchor_xyz`` is stored.
        """
        n = len(arrays["xy"])
        defaults: dict[str, Any] = {
            "method": DEFAULT_METHOD,
            "anchor_xyz": np.full((n, 3), np.nan),
            "anchor_facade_id": np.full(n, -1),
            "anchor_building_id": np.full(n, -1),
            "anchor_distance_m": np.full(n, np.nan),
            "position_covariance": np.eye(2) * UNKNOWN_POSITION_SIGMA_M**2,
            "position_xy": np.full(2, np.nan),
        }
        has_anchors = "anchor_xyz" in arrays
        values: dict[str, Any] = {}
        for spec in fields(cls):
            name = spec.name
            stored = name in arrays and (has_anchors or not name.startswith("anchor_"))
            if name.startswith("alt_anchor_"):
                stored = "alt_anchor_xyz" in arrays
            if not stored:
                values[name] = defaults.get(name)
            elif name == "image_shape":
                values[name] = tuple(np.asarray(arrays[name]).tolist())
            elif name == "scale":
                values[name] = float(arrays[name])
            elif name == "method":
                values[name] = str(arrays[name])
            else:
                values[name] = _cast(arrays[name], spec.metadata.get("read"))
        return cls(**values)

    @staticmethod
    def position_from_arrays(arrays: Mapping[str, np.ndarray]) -> np.ndarray:
        """Only the (2,) stored position (float64; NaN when stored before positions were), reading no other array."""
        if "position_xy" not in arrays:
            return np.full(2, np.nan)
        return _cast(arrays["position_xy"], np.float64)

    def __len__(self) -> int:
        """The number of keypoints."""
        return len(self.xy)


@dataclass(frozen=True)
class ReferenceLabelArrays:
    """A labelled reference's identity map as stored (the identity overlay ``labels.png`` draws it).

    building_ids (M,); column_prob (W, M) float32: each working-size column's identity probabilities;
    building_mask (H, ceil(W / 8)) uint8: the building pixels, bit-packed along rows; mask_width (1,): W;
    likelihood: the label's pose likelihood grid, float32.
    """

    building_ids: np.ndarray
    column_prob: np.ndarray = field(metadata=_dtypes(np.float32, None))
    building_mask: np.ndarray
    mask_width: np.ndarray
    likelihood: np.ndarray = field(metadata=_dtypes(np.float32, None))

    @classmethod
    def from_mask(
        cls, building_ids: np.ndarray, column_prob: np.ndarray, building_mask: np.ndarray, likelihood: np.ndarray
    ) -> ReferenceLabelArrays:
        """The arrays of an identity map with its (H, W) boolean ``building_mask`` (packed here)."""
        return cls(
            building_ids,
            column_prob,
            np.packbits(building_mask, axis=1),
            np.array([building_mask.shape[1]]),
            likelihood,
        )

    def to_arrays(self) -> dict[str, np.ndarray]:
        """The arrays to store, named by the fields, in the stored dtypes."""
        return {spec.name: _cast(getattr(self, spec.name), spec.metadata.get("stored")) for spec in fields(self)}

    @classmethod
    def from_arrays(cls, arrays: Mapping[str, np.ndarray]) -> ReferenceLabelArrays:
        """The label arrays from their stored form (a dict or an ``np.load`` result)."""
        return cls(**{spec.name: _cast(arrays[spec.name], spec.metadata.get("read")) for spec in fields(cls)})

    @property
    def width(self) -> int:
        """W, the working-size photo's width (px)."""
        return int(self.mask_width[0])

    def mask(self) -> np.ndarray:
        """The (H, W) boolean building mask, unpacked."""
        return np.unpackbits(self.building_mask, axis=1, count=self.width).astype(bool)


_WALK_FRAME_SCALARS: Final[dict[str, type[Any]]] = {
    "intrinsics_source": str,
    "building_mask_width": int,
    "features_scale": float,
    "features_method": str,
    "model_bin_deg": float,
}
_WALK_FRAME_SHAPES: Final = ("features_image_shape", "original_size")


@dataclass(frozen=True)
class WalkFrameArrays:
    """A walk reference's label alone as stored for the sequence job, which reads it instead of labelling again.

    The method's side converts (``geoloc.localize.sequence.frames.FrameLabel.stored`` and ``.from_stored``);
    :mod:`db.references` keeps it in the reference's labels blob. Every array is stored in its own dtype (no
    float16 descriptors, unlike :class:`ReferenceKeypoints`), so what is read back is bit-identical to what the
    label job computed. pose (3,) float64: x_m, y_m (local metres of the map's frame), yaw_deg (bearing);
    position_covariance (2, 2) m^2; anchor_*: the label's keypoints on the map's facades (as
    :class:`ReferenceKeypoints`'); intrinsics (5,) float64: width, height (px), focal_px, cx, cy of the
    working-size photo, intrinsics_source where the focal length came from; building_mask_bits (H, ceil(W / 8))
    uint8: the building pixels bit-packed along rows, building_mask_width W; rotation_upright_from_cam (3, 3);
    features_*: the local features (xy pixels of the working-size photo, ``features_scale`` working over original
    size); model_*: the photo's image model per column bin (``model_bin_deg`` wide), the optional ones when set;
    timings_ms: its label's timings (stored as ``timing_names`` and ``timing_values_ms``); original_size: the
    uploaded photo's (width, height) in pixels.
    """

    pose: np.ndarray
    position_covariance: np.ndarray
    anchor_xyz: np.ndarray
    anchor_facade_id: np.ndarray
    anchor_building_id: np.ndarray
    anchor_distance_m: np.ndarray
    intrinsics: np.ndarray
    intrinsics_source: str
    building_mask_bits: np.ndarray
    building_mask_width: int
    rotation_upright_from_cam: np.ndarray
    features_xy: np.ndarray
    features_descriptors: np.ndarray
    features_sizes: np.ndarray
    features_angles: np.ndarray
    features_responses: np.ndarray
    features_image_shape: tuple[int, int]
    features_scale: float
    features_method: str
    model_offsets_deg: np.ndarray
    model_facade_present: np.ndarray
    model_orientation_deg: np.ndarray
    model_bin_deg: float
    timings_ms: dict[str, float]
    original_size: tuple[int, int]
    model_identity_building_ids: np.ndarray | None = None
    model_identity_prob: np.ndarray | None = None
    model_distance_m: np.ndarray | None = None
    model_top_tan_elevation: np.ndarray | None = None

    def to_arrays(self) -> dict[str, np.ndarray]:
        """The arrays to store, named by the fields (scalars as 0-d arrays; unset optional fields left out)."""
        arrays: dict[str, np.ndarray] = {}
        for spec in fields(self):
            value = getattr(self, spec.name)
            if value is None:
                continue
            if spec.name == "timings_ms":
                arrays["timing_names"] = np.array(list(value), dtype=str)
                arrays["timing_values_ms"] = np.array(list(value.values()), np.float64)
            elif spec.name in _WALK_FRAME_SHAPES or _WALK_FRAME_SCALARS.get(spec.name) is int:
                arrays[spec.name] = np.array(value, np.int64)
            elif _WALK_FRAME_SCALARS.get(spec.name) is float:
                arrays[spec.name] = np.array(value, np.float64)
            else:
                arrays[spec.name] = np.asarray(value)
        return arrays

    @classmethod
    def from_arrays(cls, arrays: Mapping[str, np.ndarray]) -> WalkFrameArrays:
        """The walk frame from its stored arrays (a dict or an ``np.load`` result), arrays as stored.

        Raises KeyError naming the first required array that is missing.
        """
        values: dict[str, Any] = {}
        for spec in fields(cls):
            name = spec.name
            if name == "timings_ms":
                names, ms = arrays["timing_names"], arrays["timing_values_ms"]
                values[name] = {str(k): float(v) for k, v in zip(names, ms, strict=True)}
            elif name not in arrays:
                if spec.default is not None:
                    raise KeyError(f"walk frame: no {name!r} array stored")
                values[name] = None
            elif name in _WALK_FRAME_SCALARS:
                values[name] = _WALK_FRAME_SCALARS[name](arrays[name])
            elif name in _WALK_FRAME_SHAPES:
                values[name] = tuple(int(v) for v in arrays[name])
            else:
                values[name] = arrays[name]
        return cls(**values)
