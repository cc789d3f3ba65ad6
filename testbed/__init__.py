"""What the tests and the benchmarks both use: real PostgreSQL, Redis and Prometheus servers on loopback, small maps.

Not shipped in the wheel (nor are ``benchmarks``, ``research`` and ``tests``); it sits below ``benchmarks`` and
``tests`` in the layers (docs/layout.md), so both may import it.
"""
