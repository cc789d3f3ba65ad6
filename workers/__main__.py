"""``python -m workers``: run one worker process (``GEOLOC_WORKER_START=spawn``, tests).

It refuses to start (exit code 2, the reason on stderr) on an invalid setting, when the models the method
needs are missing or stale, or when ``GEOLOC_DEVICE=cuda`` and no GPU can run them here; it runs at the CPU
niceness ``GEOLOC_WORKER_NICE`` so that the API on the same machine keeps answering while the workers are busy.
With ``GEOLOC_WORKER_START=fork`` the supervisor runs :mod:`workers.pool` instead, which prepares the same way
and forks.
"""

from __future__ import annotations

import argparse

from workers.pool import device_refused, prepare, supervisor_pid
from workers.worker import Worker, install_signal_handlers


def main(argv: list[str] | None = None) -> int:
    """Parse options, load handlers and run the worker loop until SIGTERM/SIGINT."""
    parser = argparse.ArgumentParser(prog="python -m workers", description="Run one geoloc worker process.")
    parser.add_argument("--max-jobs", type=int, default=None, help="exit after this many jobs")
    parser.add_argument("--log-level", default=None, help="default: GEOLOC_LOG_LEVEL")
    args = parser.parse_args(argv)
    settings = prepare(args.log_level)
    if settings is None or device_refused(settings):
        return 2
    worker = Worker(settings)
    worker.parent_pid = supervisor_pid()
    install_signal_handlers(worker)
    worker.run(max_jobs=args.max_jobs)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
