"""Logs of a LOD server: one line per event, plain text or JSON (``--log-format``).

Events are named ``session.opened``, ``session.resumed``, ``session.detached``,
``session.ended``, ``session.refused``, ``keyframe.requested``, ``server.*``;
their fields are key=value pairs (text) or JSON members. Logs go to stderr;
stdout carries only the ``listening on HOST:PORT`` line.
"""

from __future__ import annotations

import json
import logging
import sys
import time

LOGGER = "caveclod.server"


class JsonFormatter(logging.Formatter):
    """One JSON object per line: time, level, event and the event's fields."""

    def format(self, record: logging.LogRecord) -> str:
        out = {"time": time.strftime("%Y-%m-%dT%H:%M:%S", time.gmtime(record.created))
               + f".{int(record.msecs):03d}Z", "level": record.levelname.lower(), "event": record.getMessage()}
        out.update(getattr(record, "fields", {}))
        return json.dumps(out, default=str)


class TextFormatter(logging.Formatter):
    """``2026-01-02T03:04:05.678Z info session.opened session=ab12cd34 mesh=terrain``."""

    def format(self, record: logging.LogRecord) -> str:
        stamp = time.strftime("%Y-%m-%dT%H:%M:%S", time.gmtime(record.created)) + f".{int(record.msecs):03d}Z"
        fields = " ".join(f"{k}={_text(v)}" for k, v in getattr(record, "fields", {}).items())
        return f"{stamp} {record.levelname.lower()} {record.getMessage()} {fields}".rstrip()


def _text(value) -> str:
    s = str(value)
    return json.dumps(s) if (not s or any(c in s for c in ' ="')) else s


def configure(fmt: str = "text", stream=None) -> None:
    """Send the server's events to ``stream`` (stderr) in ``fmt`` ("text" or "json")."""
    handler = logging.StreamHandler(stream or sys.stderr)
    handler.setFormatter(JsonFormatter() if fmt == "json" else TextFormatter())
    logger = logging.getLogger(LOGGER)
    logger.handlers[:] = [handler]
    logger.setLevel(logging.INFO)
    logger.propagate = False


def event(name: str, level: int = logging.INFO, **fields) -> None:
    """Log one event with its fields."""
    logging.getLogger(LOGGER).log(level, name, extra={"fields": fields})
