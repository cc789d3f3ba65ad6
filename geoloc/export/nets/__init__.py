"""Network definitions used only by the export path (``geoloc.export.models``); they import torch.

Import the submodules explicitly (``from geoloc.export.nets import espnetv2``): this package itself
imports nothing, so the runtime never pulls in torch by accident.
"""
