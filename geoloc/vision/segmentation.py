"""Semantic segmentation of street photos into our classes (``geoloc.core.labels``), onnxruntime only.

The network is ESPNetv2 (s=2.0) trained on Cityscapes (``geoloc.export.nets.espnetv2``), exported to
ONNX by ``geoloc models build`` (``geoloc.export.models``) into the models folder
(:mod:`geoloc.vision.model_files`). This module never imports torch; :func:`load_session` opens the export
with a :class:`~geoloc.core.context.MethodContext`.

Pipeline: RGB image -> resize to the network size (default 768x384, W x H, whatever the image's aspect; the
context's ``segmentation_size``, ``GEOLOC_SEGMENTATION_SIZE``, picks another: docs/speed.md says what smaller
sizes and int8 cost) -> logits at half that size -> softmax over the kept Cityscapes channels -> probabilities
summed per class group below -> bilinear resize to the image size -> argmax.

Cityscapes trainId -> our class (``CITYSCAPES_TO_OURS``):

- building: building, wall
- tree: vegetation
- road: road, sidewalk, terrain (ground)
- sky: sky
- car: car, truck, bus
- other: fence, pole, traffic light, traffic sign, person, rider, motorcycle, bicycle, void (19)
- train: dropped from the softmax (never predicted)

Why (CamVid test, every 4th image; mean IoU over building/tree/road/sky/car): terrain -> road,
tree or other are within 0.2 points (1024x512: 0.8127 / 0.8112 / 0.8126; 768x384: road = tree =
0.821); road keeps ground out of the occluder class. fence -> building raises building accuracy
by 0.8-1.6 points but lowers building IoU by 0.4-0.9 points (768x576, 1024x512; CamVid labels
fences apart), so fence stays other. On the Lund phone photos deep-blue sky and yellow facades
came out as "train" (9.6 % of one photo, shown as car); dropping train
fixed that and is neutral on CamVid (car IoU 0.817 -> 0.819). Summing group probabilities is
within 0.1 point of mapping the 19-way argmax.

Network input size against accuracy and time (CamVid test, every 4th image = 59 images, all
480x360, resized to the size without keeping the aspect; ms = median per image of segment() incl.
pre/post, onnxruntime with 2 intra-op threads on a shared 2-core CPU, sizes interleaved):

    size (WxH)  bld acc  bld IoU  tree IoU  road IoU  sky IoU  car IoU  pix acc    ms
    512x256      0.887    0.793    0.675     0.949    0.813    0.765    0.893    146
    640x320      0.906    0.816    0.682     0.958    0.823    0.812    0.905    189
    768x384      0.919    0.824    0.679     0.960    0.825    0.819    0.908    224  <- default
    896x448      0.919    0.821    0.678     0.958    0.826    0.823    0.908    265
    1024x512     0.916    0.812    0.675     0.956    0.818    0.805    0.904    345
    640x480      0.918    0.796    0.672     0.957    0.755    0.802    0.893    231
    768x576      0.918    0.762    0.662     0.950    0.708    0.795    0.879    313
    1280x640     0.912    0.768    0.654     0.944    0.771    0.777    0.886    487
    1024x768     0.918    0.686    0.629     0.923    0.642    0.746    0.845    460  (train->car)

The 2:1 sizes of the training data (Cityscapes, 1024x512) beat the 4:3 sizes that keep CamVid's
aspect: with 4:3 input, bright sky is taken for building/tree. 768x384 is the best and cheap.
All 233 CamVid test images at 768x384 (``geoloc eval camvid --split test``): building accuracy
0.910 / IoU 0.816, tree 0.891 / 0.691, road 0.987 / 0.962, sky 0.838 / 0.829, car 0.909 / 0.820,
pixel accuracy 0.908. Most remaining sky errors are leafless trees, whose whole crown the network
calls vegetation while CamVid labels the sky between the branches.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import cv2
import numpy as np

from geoloc.core import labels
from geoloc.core.context import MethodContext
from geoloc.vision.model_files import SEG_DEFAULT_SIZE, segmentation_files
from geoloc.vision.onnx_session import onnx_session

if TYPE_CHECKING:
    import onnxruntime as ort

N_CITYSCAPES = 20  # 19 trainIds + void
DROP = 255  # mapping value: leave this Cityscapes class out of the softmax (never predicted)

# Cityscapes trainId (0..18, 19 = void) -> our class code.
CITYSCAPES_TO_OURS = np.array(
    [
        labels.ROAD,  # 0 road
        labels.ROAD,  # 1 sidewalk
        labels.BUILDING,  # 2 building
        labels.BUILDING,  # 3 wall
        labels.OTHER,  # 4 fence
        labels.OTHER,  # 5 pole
        labels.OTHER,  # 6 traffic light
        labels.OTHER,  # 7 traffic sign
        labels.TREE,  # 8 vegetation
        labels.ROAD,  # 9 terrain
        labels.SKY,  # 10 sky
        labels.OTHER,  # 11 person
        labels.OTHER,  # 12 rider
        labels.CAR,  # 13 car
        labels.CAR,  # 14 truck
        labels.CAR,  # 15 bus
        DROP,  # 16 train: never predicted (see above)
        labels.OTHER,  # 17 motorcycle
        labels.OTHER,  # 18 bicycle
        labels.OTHER,  # 19 void
    ],
    dtype=np.uint8,
)


class ModelNotBuiltError(FileNotFoundError):
    """The ONNX export is missing; the message says how to build it."""


def load_session(context: MethodContext, size: tuple[int, int] | None = None) -> ort.InferenceSession:
    """The onnxruntime session for network input ``size`` (W, H) on the context's device, cached per process.

    Parameters
    ----------
    context
        Where the built models are (``models_dir``), the intra-op threads (``onnx_threads``) and the device.
    size
        Network input (W, H); default the context's ``segmentation_size``, else
        ``geoloc.vision.model_files.SEG_DEFAULT_SIZE``.

    Raises
    ------
    ModelNotBuiltError
        The ONNX file is not in the models folder.
    geoloc.vision.onnx_session.DeviceUnavailableError
        The context's device is ``cuda`` and onnxruntime cannot run on a GPU here.
    """
    size = size or context.segmentation_size or SEG_DEFAULT_SIZE
    path = segmentation_files(context.models_dir, size).onnx
    if not path.exists():
        flag = "" if size == SEG_DEFAULT_SIZE else f" --size {size[0]}x{size[1]}"
        raise ModelNotBuiltError(
            f"segmentation model not found at {path}; build it once with `geoloc models build{flag}` "
            "(needs the export extra: pip install -e '.[export]')"
        )
    return onnx_session(str(path), context.onnx_threads, context.device)


def network_name(context: MethodContext) -> str:
    """The segmentation network the context runs: its ONNX file's stem (e.g. ``espnetv2_s2_city_768x384``)."""
    return segmentation_files(context.models_dir, context.segmentation_size).onnx.stem


def network_size(session: ort.InferenceSession) -> tuple[int, int]:
    """Fixed input (W, H) of a session's graph."""
    shape = session.get_inputs()[0].shape
    return int(shape[3]), int(shape[2])


def _prepare(image_rgb: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """(H, W, 3) uint8 RGB -> (1, 3, h, w) float32 0..255 at network ``size`` = (w, h)."""
    if image_rgb.ndim != 3 or image_rgb.shape[2] != 3:
        raise ValueError(f"expected an (H, W, 3) RGB image, got shape {image_rgb.shape}")
    h, w = image_rgb.shape[:2]
    shrink = size[0] < w and size[1] < h
    resized = cv2.resize(image_rgb, size, interpolation=cv2.INTER_AREA if shrink else cv2.INTER_LINEAR)
    return np.ascontiguousarray(resized.astype(np.float32).transpose(2, 0, 1)[None])


def cityscapes_logits(image_rgb: np.ndarray, *, session: Any) -> np.ndarray:
    """Raw network output: (20, h, w) float32 Cityscapes logits at half the network input size.

    session: from :func:`load_session`.
    """
    x = _prepare(image_rgb, network_size(session))
    logits: np.ndarray = session.run(None, {session.get_inputs()[0].name: x})[0][0]
    return logits


def _group_probabilities(logits: np.ndarray, mapping: np.ndarray) -> np.ndarray:
    """(20, h, w) logits -> (h, w, 6) probabilities summed per our class.

    The softmax runs over the channels whose mapping is not ``DROP`` (dropped classes are never
    predicted: their pixels go to the next most likely class).
    """
    keep = mapping != DROP
    z = logits[keep]
    z -= z.max(axis=0, keepdims=True)
    np.exp(z, out=z)
    z /= z.sum(axis=0, keepdims=True)
    onehot = (mapping[keep][None, :] == np.arange(len(labels.CLASS_NAMES))[:, None]).astype(np.float32)
    groups = onehot @ z.reshape(z.shape[0], -1)  # (6, h*w)
    probabilities: np.ndarray = groups.T.reshape(*z.shape[1:], len(labels.CLASS_NAMES))
    return probabilities


def class_probabilities(image_rgb: np.ndarray, *, session: Any, mapping: np.ndarray = CITYSCAPES_TO_OURS) -> np.ndarray:
    """Per-pixel probabilities of our classes at the image's resolution.

    Parameters
    ----------
    image_rgb
        (H, W, 3) uint8 RGB photo, any size.
    session
        An onnxruntime session from :func:`load_session`.
    mapping
        (20,) Cityscapes trainId -> our class code, or ``DROP`` to leave a class out.

    Returns
    -------
    numpy.ndarray
        (H, W, 6) float32, summing to 1 over the last axis (class order ``labels.CLASS_NAMES``).
    """
    probs = _group_probabilities(cityscapes_logits(image_rgb, session=session), mapping)
    h, w = image_rgb.shape[:2]
    return cv2.resize(probs, (w, h), interpolation=cv2.INTER_LINEAR)


def segment(image_rgb: np.ndarray, *, session: Any) -> np.ndarray:
    """Label every pixel of an RGB photo with our classes.

    Parameters
    ----------
    image_rgb
        (H, W, 3) uint8 RGB.
    session
        The onnxruntime session from :func:`load_session` (its network size is the graph's).

    Returns
    -------
    numpy.ndarray
        (H, W) uint8 class codes (``geoloc.core.labels``).
    """
    codes: np.ndarray = class_probabilities(image_rgb, session=session).argmax(axis=2).astype(np.uint8)
    return codes
