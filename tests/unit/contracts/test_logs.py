"""The log formats (``GEOLOC_LOG_FORMAT``) and request ids (:mod:`contracts.logs`)."""

from __future__ import annotations

import io
import json
import logging
import re

import pytest

from contracts.logs import REQUEST_ID, JsonFormatter, TextFormatter, configure_logging, request_id_from_header


@pytest.fixture
def captured() -> logging.Logger:
    logger = logging.getLogger("test.contracts.logs")
    logger.propagate = False
    logger.setLevel(logging.INFO)
    return logger


def _emit(logger: logging.Logger, formatter: logging.Formatter, *args: object, **kwargs: object) -> str:
    stream = io.StringIO()
    handler = logging.StreamHandler(stream)
    handler.setFormatter(formatter)
    logger.handlers = [handler]
    logger.info(*args, **kwargs)  # type: ignore[arg-type]
    return stream.getvalue()


def test_a_json_line_has_the_request_id_the_extra_fields_and_the_traceback(captured: logging.Logger) -> None:
    token = REQUEST_ID.set("req-1")
    try:
        line = json.loads(_emit(captured, JsonFormatter(), "job %d done", 7, extra={"job_id": 7, "kind": "k"}))
    finally:
        REQUEST_ID.reset(token)
    assert line["message"] == "job 7 done" and line["level"] == "INFO" and line["logger"] == captured.name
    assert line["request_id"] == "req-1" and line["job_id"] == 7 and line["kind"] == "k"
    assert re.fullmatch(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d\.\d{3}Z", line["ts"])
    try:
        raise ValueError("boom")
    except ValueError:
        stream = io.StringIO()
        handler = logging.StreamHandler(stream)
        handler.setFormatter(JsonFormatter())
        captured.handlers = [handler]
        captured.exception("failed")
    failed = json.loads(stream.getvalue())
    assert "request_id" not in failed and "ValueError: boom" in failed["exc_info"]


def test_a_text_line_shows_the_request_id_only_when_there_is_one(captured: logging.Logger) -> None:
    assert "[api " in _emit(captured, TextFormatter("api"), "hello") and "[]" not in _emit(
        captured, TextFormatter("api"), "hello"
    )
    token = REQUEST_ID.set("abc")
    try:
        assert "] [abc] hello" in _emit(captured, TextFormatter("api"), "hello")
    finally:
        REQUEST_ID.reset(token)


def test_request_ids_from_the_header() -> None:
    assert request_id_from_header("4bf92f3577b34da6a3ce929d0e0e4736") == "4bf92f3577b34da6a3ce929d0e0e4736"
    made = request_id_from_header(None)
    assert made is not None and re.fullmatch(r"[0-9a-f]{32}", made) and made != request_id_from_header("")
    assert request_id_from_header("a b") is None and request_id_from_header("x" * 129) is None
    assert request_id_from_header("x" * 128) == "x" * 128


def test_configure_logging_replaces_the_root_handlers() -> None:
    root = logging.getLogger()
    saved, level = list(root.handlers), root.level
    try:
        configure_logging("warning", "json", "api")
        assert len(root.handlers) == 1 and isinstance(root.handlers[0].formatter, JsonFormatter)
        assert root.level == logging.WARNING
    finally:
        root.handlers, root.level = saved, level
