"""``python -m service --host H --port P``: run the API with uvicorn (the supervisor starts this)."""

from __future__ import annotations

import argparse
import os
import resource
import signal
import sys
import threading
import time

from contracts.logs import configure_logging
from contracts.settings import SettingsError, get_settings
from service.auth import is_loopback_host


def _watch_parent(parent_pid: int) -> None:
    """Stop this process (SIGTERM to self) if the supervisor that started it disappears."""
    while os.getppid() == parent_pid:
        time.sleep(1.0)
    os.kill(os.getpid(), signal.SIGTERM)


def _raise_open_files(connections: int) -> None:
    """Raise this process's soft limit of open files toward the hard one, to fit ``connections`` and the rest."""
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    wanted = connections + 256  # the database, stored files, logs
    if soft != resource.RLIM_INFINITY and soft < wanted:
        target = wanted if hard == resource.RLIM_INFINITY else min(wanted, hard)
        resource.setrlimit(resource.RLIMIT_NOFILE, (target, hard))


def main(argv: list[str] | None = None) -> int:
    """Check the host against the auth policy, then serve."""
    parser = argparse.ArgumentParser(prog="python -m service", description="Run the geoloc API.")
    parser.add_argument("--host", default="127.0.0.1")
    parser.add_argument("--port", type=int, default=8000)
    parser.add_argument("--log-level", default="info")
    args = parser.parse_args(argv)
    try:
        settings = get_settings()
    except SettingsError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if not settings.auth_enabled and not is_loopback_host(args.host):
        print(
            f"refusing to bind to {args.host}: no API keys are configured (GEOLOC_API_KEYS), "
            "so the service may only listen on a loopback address such as 127.0.0.1",
            file=sys.stderr,
        )
        return 2
    parent = os.environ.get("GEOLOC_SUPERVISOR_PID")
    if parent:
        threading.Thread(target=_watch_parent, args=(int(parent),), daemon=True).start()
    # lazy: the host and settings checks answer before uvicorn and the app are loaded
    import uvicorn

    from service.app import create_app  # lazy: see above
    from service.connections import uvicorn_options  # lazy: see above

    # Our own log lines in GEOLOC_LOG_FORMAT: uvicorn's loggers go to the root handler, and its access log is
    # replaced by the request observer's line (service/observe.py), which carries the request id.
    configure_logging(args.log_level, settings.log_format, "api")
    _raise_open_files(settings.http_max_connections)
    options = uvicorn_options(settings)
    app = create_app(settings)
    uvicorn.run(
        app, host=args.host, port=args.port, log_level=args.log_level, log_config=None, access_log=False, **options
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
