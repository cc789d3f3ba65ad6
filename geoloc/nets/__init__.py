"""Network definitions used only by the export path (``geoloc.models``); they import torch.

Import the submodules explicitly (``from geoloc.nets import espnetv2``): this package itself
imports nothing, so the runtime never pulls in torch by accident.
"""
