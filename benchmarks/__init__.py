"""Speed and load benchmarks (see docs/measurements.md), and the real PostgreSQL and Redis servers the tests use too.

Which benchmarks take ``--baseline REF`` (their figures beside a commit's, ``baseline.py``) and why the others
do not: docs/speed.md, "Against a baseline commit".
"""
