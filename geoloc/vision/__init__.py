"""The image side of the method: segmentation, lines and vanishing points, facades, local features.

:func:`geoloc.vision.evidence.analyze_photo` is the stage's entry; the networks run on onnxruntime from the
built models (:mod:`geoloc.vision.model_files`), never on PyTorch.
"""
