"""Speed and load benchmarks, recurring (see docs/measurements.md); one-off diagnostics are in ``research/``.

Run as scripts (``python benchmarks/bench_service.py``): they import their siblings by bare name
(``from baseline import ...``), and ``local_service`` puts this checkout on ``sys.path``. The servers of the
distributed profile are ``testbed/servers.py``; neither this package nor ``testbed`` ships in the wheel.

Which benchmarks take ``--baseline REF`` (their figures beside a commit's, ``baseline.py``) and why the others
do not: docs/speed.md, "Against a baseline commit".
"""
