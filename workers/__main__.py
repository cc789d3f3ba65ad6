"""``python -m workers``: run one worker process (the supervisor starts these).

It refuses to start (exit code 2, the reason on stderr) on an invalid setting, when the models the method
needs are missing or stale, or when ``GEOLOC_DEVICE=cuda`` and no GPU can run them here; it runs at the CPU
niceness ``GEOLOC_WORKER_NICE`` so that the API on the same machine keeps answering while the workers are busy.
"""

from __future__ import annotations

import argparse
import logging
import os
import sys

from contracts.settings import SettingsError, get_settings
from workers.context import device_probe, model_problems, needs_models
from workers.handlers import load_builtin_handlers, load_plugins
from workers.worker import Worker, install_signal_handlers


def main(argv: list[str] | None = None) -> int:
    """Parse options, load handlers and run the worker loop until SIGTERM/SIGINT."""
    parser = argparse.ArgumentParser(prog="python -m workers", description="Run one geoloc worker process.")
    parser.add_argument("--max-jobs", type=int, default=None, help="exit after this many jobs")
    parser.add_argument("--log-level", default=None, help="default: GEOLOC_LOG_LEVEL")
    args = parser.parse_args(argv)
    try:
        settings = get_settings()
    except SettingsError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    logging.basicConfig(
        level=(args.log_level or settings.log_level).upper(),
        format="%(asctime)s %(levelname)s [worker %(process)d] %(message)s",
    )
    problems = model_problems() if needs_models(settings) else []
    problems = problems or (device_probe() if needs_models(settings) else [])
    if problems:
        print("error: the worker cannot run jobs:\n  " + "\n  ".join(problems), file=sys.stderr)
        return 2
    if settings.worker_nice:
        os.nice(settings.worker_nice)
    load_builtin_handlers()
    load_plugins(settings.worker_plugins)
    worker = Worker(settings)
    parent = os.environ.get("GEOLOC_SUPERVISOR_PID")
    worker.parent_pid = int(parent) if parent else None
    install_signal_handlers(worker)
    worker.run(max_jobs=args.max_jobs)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
