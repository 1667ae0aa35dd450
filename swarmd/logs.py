"""structlog set-up: JSON lines for journald and pipes, a readable console on a terminal.

Under systemd (``JOURNAL_STREAM`` set) each JSON line gets an sd-daemon(3) ``<N>`` priority
prefix, which journald strips and turns into the entry's PRIORITY, so ``journalctl -p
warning`` works and ``journalctl -u swarmd -o cat | jq`` still sees clean JSON.
"""

from __future__ import annotations

import logging
import os
import sys
from typing import Any, Final, TextIO

import structlog
from structlog.typing import EventDict, Processor, WrappedLogger

from swarmd.terminal import safe_text

# sd-daemon(3) syslog levels
_PRIORITY: Final = {"debug": 7, "info": 6, "warning": 4, "error": 3, "critical": 2, "exception": 3}


class _JournalPrefixed:
    """JSONRenderer plus the ``<N>`` prefix journald understands."""

    def __init__(self) -> None:
        self._json = structlog.processors.JSONRenderer(sort_keys=False)

    def __call__(self, logger: WrappedLogger, name: str, event_dict: EventDict) -> str:
        level = str(event_dict.get("level", "info"))
        line = self._json(logger, name, event_dict)
        if isinstance(line, bytes):
            line = line.decode()
        return f"<{_PRIORITY.get(level, 6)}>{line}"


def _safe_for_terminal(logger: WrappedLogger, name: str, event_dict: EventDict) -> EventDict:
    """Every string of the line shown as visible escapes (issue 10, attack 8).

    Log lines carry peer-supplied strings (a foreign participant's ENTITY_NAME and vendor, a
    member's readiness reason, a decode error quoting the datagram): on a terminal an ESC or
    OSC in one of them would clear or retitle the operator's screen. Tracebacks (already
    text, from ``format_exc_info``) keep their newlines, each line escaped.
    """
    out: EventDict = {}
    for key, value in event_dict.items():
        if key in ("exception", "stack") and isinstance(value, str):
            out[key] = "\n".join(safe_text(line) for line in value.split("\n"))
        else:
            out[safe_text(key)] = _safe_value(value)
    return out


def _safe_value(value: Any) -> Any:
    # the console renderer prints other objects with repr(), and a class's repr may embed
    # a remote string raw: escape it here (numbers and None print as they are)
    if value is None or isinstance(value, bool | int | float):
        return value
    if isinstance(value, str):
        return safe_text(value)
    if isinstance(value, list | tuple):
        return [_safe_value(v) for v in value]
    if isinstance(value, dict):
        return {_safe_value(k): _safe_value(v) for k, v in value.items()}
    return safe_text(repr(value))


def configure(level: str = "info", fmt: str = "auto", stream: TextIO | None = None) -> None:
    """Configure structlog for the process. ``fmt``: auto | json | console."""
    out = sys.stderr if stream is None else stream
    console = fmt == "console" or (fmt == "auto" and out.isatty())
    processors: list[Processor] = [
        structlog.contextvars.merge_contextvars,
        structlog.processors.add_log_level,
        structlog.processors.TimeStamper(fmt="iso", utc=True),
    ]
    renderer: Processor
    if console:
        # exceptions rendered as plain text first, so the escaping below reaches their
        # messages too (a pretty renderer would print them, and frame locals, raw)
        processors += [structlog.processors.format_exc_info, _safe_for_terminal]
        renderer = structlog.dev.ConsoleRenderer(colors=out.isatty())
    else:
        processors += [structlog.processors.dict_tracebacks]
        renderer = (
            _JournalPrefixed()
            if os.environ.get("JOURNAL_STREAM")
            else structlog.processors.JSONRenderer()
        )
    structlog.configure(
        processors=[*processors, renderer],
        wrapper_class=structlog.make_filtering_bound_logger(getattr(logging, level.upper())),
        logger_factory=structlog.PrintLoggerFactory(file=out),
        cache_logger_on_first_use=False,
    )


def get_logger(**context: Any) -> Any:
    """A bound logger with ``context`` attached to every line."""
    return structlog.get_logger().bind(**context)
