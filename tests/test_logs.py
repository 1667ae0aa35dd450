"""The daemon's own log lines: peer-supplied strings never reach a terminal raw (issue 10,
attack 8), while JSON lines keep the exact value."""

from __future__ import annotations

import io
import json
import unicodedata
from collections.abc import Iterator

import pytest
import structlog

from swarmd import logs
from swarmd.terminal import UNSAFE_CATEGORIES

# clears the screen, homes the cursor, retitles the window, a C1 CSI, a bidi override
HOSTILE = "\x1b[2J\x1b[H\x1b]0;owned\x07uav9\x9b31m\u202eydaer\r\x00\u2028"


class _Hostile:
    """An object whose repr carries a remote string raw (the console renderer uses repr)."""

    def __repr__(self) -> str:
        return f"Name({HOSTILE})"


@pytest.fixture(autouse=True)
def _reset() -> Iterator[None]:
    yield
    structlog.reset_defaults()


def _controls(text: str) -> list[str]:
    # newline ends a log line; anything else of these categories is a terminal control
    return [c for c in text if unicodedata.category(c) in UNSAFE_CATEGORIES and c != "\n"]


def _console(**fields: object) -> str:
    out = io.StringIO()
    logs.configure(level="debug", fmt="console", stream=out)
    logs.get_logger(node="uav1").info("foreign_participant", **fields)
    return out.getvalue()


def test_console_line_escapes_every_remote_string() -> None:
    text = _console(
        name=HOSTILE,
        vendor=HOSTILE,
        reason=HOSTILE,
        user=[HOSTILE, ("x", HOSTILE)],
        detail={HOSTILE: HOSTILE},
        obj=_Hostile(),
    )
    assert _controls(text) == []
    assert text.count("\n") == 1  # one event, one line: no U+2028, no raw CR or LF
    assert "\\x1b[2J" in text and "\\u202e" in text and "uav9" in text


def test_console_keeps_plain_values_readable() -> None:
    text = _console(name="uav2", suppressed=3, ready=True, epoch=None)
    assert "uav2" in text and "suppressed=3" in text and "ready=True" in text


def test_console_exception_text_is_escaped_line_by_line() -> None:
    out = io.StringIO()
    logs.configure(level="debug", fmt="console", stream=out)
    try:
        raise ValueError(f"bad name {HOSTILE}")
    except ValueError:
        logs.get_logger().exception("core_failed", core="discovery")
    text = out.getvalue()
    assert _controls(text) == []
    assert "ValueError: bad name \\x1b[2J" in text
    assert "Traceback" in text and text.count("\n") > 2  # the traceback keeps its lines


def test_json_lines_keep_the_exact_value() -> None:
    out = io.StringIO()
    logs.configure(level="debug", fmt="json", stream=out)
    logs.get_logger(node="uav1").info("foreign_participant", name=HOSTILE)
    line = out.getvalue()
    assert _controls(line) == []  # JSON escapes the controls itself (\u001b)
    assert json.loads(line)["name"] == HOSTILE
