"""The benchmarks as they run: scripts that import their siblings by bare name (``from config_args import ...``).

``benchmarks/`` is not installed (the wheel leaves it out): a script finds its siblings beside it, and these
tests, which import a script (``benchmarks.bench_walk_placement``), put that folder on ``sys.path`` the same way.
"""

from __future__ import annotations

import sys
from pathlib import Path

BENCHMARKS = str(Path(__file__).resolve().parents[3] / "benchmarks")
if BENCHMARKS not in sys.path:
    sys.path.append(BENCHMARKS)
