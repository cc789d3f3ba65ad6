"""Speed and load benchmarks (see docs/measurements.md), and the real PostgreSQL and Redis servers the tests use too."""
