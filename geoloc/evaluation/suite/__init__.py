"""The accuracy suite (``geoloc eval suite``): many simulated worlds over every map and urban form, two splits.

Entry points: :func:`run_suite` (a split rendered, evaluated and summarised with 95 % intervals, optionally
against a baseline commit) and :func:`load_suite` (the declared worlds, ``worlds.toml``).
"""

from geoloc.evaluation.suite.run import SuiteError, SuiteRun, run_suite
from geoloc.evaluation.suite.worlds import Suite, SuiteWorld, load_suite

__all__ = ["Suite", "SuiteError", "SuiteRun", "SuiteWorld", "load_suite", "run_suite"]
