"""The default SBoW vocabularies, built from CamVid by ``geoloc models build`` into the models folder.

One per feature type (``method``, :mod:`geoloc.vision.features`): the descriptors on the ground-truth
Building pixels of the CamVid *train* images (shared folder ``data/camvid``) clustered deterministically
(seed :data:`geoloc.localize.retrieval.VOCABULARY_SEED`) by :func:`geoloc.localize.retrieval.build_vocabulary`
and saved at :func:`geoloc.vision.model_files.vocabulary_path`, where the runtime's
:func:`geoloc.localize.retrieval.default_vocabulary` reads it.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np
from PIL import Image

from contracts.settings import shared_path
from geoloc.core.context import MethodContext
from geoloc.core.labels import BUILDING
from geoloc.localize.retrieval import VOCABULARY_SEED, Vocabulary, build_vocabulary
from geoloc.vision.feature_types import DESCRIPTOR_DIMS, canonical_method
from geoloc.vision.features import extract_features
from geoloc.vision.model_files import DEFAULT_WORDS, vocabulary_path

VOCABULARY_FEATURES_PER_IMAGE = 600
"""Descriptors per CamVid image used for the default vocabulary (its 367 train images give ~70k)."""


def camvid_building_descriptors(
    context: MethodContext,
    split: str = "train",
    *,
    per_image: int = VOCABULARY_FEATURES_PER_IMAGE,
    progress: Callable[[str], None] | None = None,
    method: str | None = None,
) -> np.ndarray:
    """Descriptors on the ground-truth Building pixels of the CamVid ``split`` images, in file order.

    Of feature type ``method`` (None: the default type); ``context`` holds the models ALIKED needs.
    """
    images = sorted(shared_path("data", "camvid", split, "images").glob("*.*"))
    label_dir = shared_path("data", "camvid", split, "labels")
    chunks = []
    for i, image_path in enumerate(images):
        label_path = label_dir / f"{image_path.stem}.png"
        if not label_path.exists():
            continue
        rgb = np.asarray(Image.open(image_path).convert("RGB"))
        mask = np.asarray(Image.open(label_path)) == BUILDING
        chunks.append(extract_features(rgb, mask, per_image, method=method, context=context).descriptors)
        if progress and (i + 1) % 50 == 0:
            progress(f"  features: {i + 1}/{len(images)} images, {sum(map(len, chunks))} descriptors")
    return np.concatenate(chunks) if chunks else np.zeros((0, DESCRIPTOR_DIMS[canonical_method(method)]), np.float32)


def build_default_vocabulary(
    context: MethodContext, n_words: int = DEFAULT_WORDS, progress: bool = True, method: str | None = None
) -> Vocabulary:
    """The default SBoW vocabulary in ``context.models_dir``: loaded when there, else built and saved.

    Of feature type ``method`` (None: the default type), with ``n_words`` words. Built deterministically
    (seed :data:`~geoloc.localize.retrieval.VOCABULARY_SEED`) from the building pixels of the CamVid train
    images (measured on the loaded 2-core box: RootSIFT 2 minutes, ALIKED-n16 4.5, ALIKED-t16 6.5);
    ``progress`` prints what it does.
    """
    method = canonical_method(method)
    path = vocabulary_path(context.models_dir, n_words, method)
    if path.exists():
        return Vocabulary.load(path)
    say: Callable[[str], None] = (lambda s: print(s, flush=True)) if progress else (lambda s: None)
    say(f"Building SBoW vocabulary ({method}, {n_words} words) from CamVid train building pixels -> {path}")
    t0 = time.perf_counter()
    desc = camvid_building_descriptors(context, "train", progress=say, method=method)
    t1 = time.perf_counter()
    say(f"  {len(desc)} descriptors in {t1 - t0:.1f} s; clustering")
    vocab = build_vocabulary(desc, n_words, VOCABULARY_SEED)
    vocab.meta["source"] = "camvid/train building pixels"
    vocab.meta["method"] = method
    say(f"  clustered in {time.perf_counter() - t1:.1f} s (total {time.perf_counter() - t0:.1f} s)")
    vocab.save(path)
    return vocab
