"""A tool, not the runtime: the PyTorch networks, their ONNX export and the CamVid vocabulary build.

``geoloc models build`` runs it; it imports the runtime (:mod:`geoloc.vision.model_files` for the files' names),
and nothing in the runtime imports it.
"""
