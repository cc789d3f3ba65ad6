"""Deprecated alias of the top-level :mod:`client` package, kept for one release (0.2); import ``client``.

``import geoloc.client`` warns ``DeprecationWarning`` and gives the :mod:`client` package itself, and
``geoloc.client.<module>`` the same module objects as ``client.<module>`` (``sys.modules`` aliases), so
classes and exceptions are the same objects under both names.
"""

import sys
import warnings

import client
from client import *  # noqa: F403 (the alias exports what the package does, for type checkers)

warnings.warn(
    "geoloc.client is deprecated and will be removed in the next release: import client instead",
    DeprecationWarning,
    stacklevel=2,
)
for _name, _module in list(sys.modules.items()):
    if _name.startswith("client."):
        sys.modules[f"geoloc.{_name}"] = _module
sys.modules[__name__] = client
