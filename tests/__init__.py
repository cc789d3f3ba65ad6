"""The tests, mirroring the packages.

``unit/<package or stage>/``: one folder per layer or method stage; ``e2e/``: the service end to end (a real
server on loopback, real workers). The shared fixtures and helpers stay here at the top (``conftest.py``,
``service_fixtures.py``, ``model_fixtures.py``, ``map_files.py``, ``scenes.py``, the worker plugins), with
``test_structure.py`` (the house's rules) and ``test_docs.py`` (the README and ``docs/`` against the code).
"""

from pathlib import Path

TESTS_DIR = Path(__file__).resolve().parent
"""This folder (the helpers and worker plugins live here)."""
REPO_ROOT = TESTS_DIR.parent
"""The repository's root."""
