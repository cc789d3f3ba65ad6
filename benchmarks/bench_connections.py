"""Connection limits at size (issue 51, item 2): 1,000 idle, 50 slow-head and 20 slow-body clients held open.

They are held against ``geoloc serve`` while a normal client times ``/healthz`` and ``GET /v1/maps``.

``python benchmarks/bench_connections.py [--idle 1000 --slow-headers 50 --slow-bodies 20 --json out.json]``;
the limits are set short so that the run is short (head 5 s, body stalled 5 s, whole body 10 s): the slow
clients must be cut at those times and the normal client's p99 stay under 200 ms. The CI-sized version is
``tests/e2e/test_connection_limits.py``; the figures are in docs/measurements/faults.md.
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

import httpx
from connection_load import hold_slow_clients
from local_service import LocalService, run_figures

from testbed.maps import ONE_BUILDING

LIMITS = {
    "GEOLOC_HTTP_HEADER_TIMEOUT_S": "5",
    "GEOLOC_HTTP_BODY_IDLE_S": "5",
    "GEOLOC_HTTP_BODY_TIMEOUT_S": "10",
}


def main() -> int:
    """Run the load once; print (and write) the figures and the verdict; exit 1 when a check fails."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--idle", type=int, default=1000)
    parser.add_argument("--slow-headers", type=int, default=50)
    parser.add_argument("--slow-bodies", type=int, default=20)
    parser.add_argument("--duration-s", type=float, default=15.0)
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="bench-connections-") as tmp:
        service = LocalService(Path(tmp) / "data", workers=1, env=LIMITS)
        try:
            files = {"file": ("hall.geojson", json.dumps(ONE_BUILDING).encode())}
            created = httpx.post(
                f"{service.url}/v1/maps", files=files, data={"wait_s": "60", "name": "hall"}, timeout=60
            )
            created.raise_for_status()
            result = hold_slow_clients(
                service.url,
                None,
                int(created.json()["id"]),
                idle=args.idle,
                slow_headers=args.slow_headers,
                slow_bodies=args.slow_bodies,
                duration_s=args.duration_s,
            )
        finally:
            service.stop()
    figures = {**run_figures(), "limits": LIMITS, **result.figures()}
    cut = {"idle": (4.5, 7.0), "slow_header": (4.5, 7.0), "stalled_body": (4.5, 7.0), "trickled_body": (9.5, 12.5)}
    checks = {
        "p99 /healthz < 200 ms": result.p99("/healthz") < 200,
        "p99 /v1/maps < 200 ms": result.p99("/v1/maps") < 200,
        "no errors": not result.errors,
        **{
            f"{kind} cut at {low}-{high} s": all(t is not None and low <= t <= high for t in result.closed_after(kind))
            for kind, (low, high) in cut.items()
        },
    }
    figures["checks"] = {name: "PASS" if ok else "FAIL" for name, ok in checks.items()}
    text = json.dumps(figures, indent=2)
    print(text)
    if args.json is not None:
        args.json.write_text(text + "\n")
    return 0 if all(checks.values()) else 1


if __name__ == "__main__":
    raise SystemExit(main())
