"""One-off research scripts: diagnostics run to answer one question, whose findings are in docs/measurements.md.

Unlike ``benchmarks/`` they are not rerun against a baseline; each script's docstring gives its command and the
docs the section its figures went to. Not shipped in the wheel.
"""
