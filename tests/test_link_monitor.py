"""The link monitor: source order, fallback with a clear log line, recovery."""

from __future__ import annotations

import asyncio
from collections.abc import MutableMapping
from typing import Any

import structlog
from structlog.testing import capture_logs

from swarmd.discovery.inputs import LinkSample
from swarmd.link.monitor import LinkMonitor
from swarmd.link.nl80211 import Nl80211Source
from swarmd.link.source import LinkUnavailable
from swarmd.link.static import StaticSource


class _Scripted:
    """A source whose next answers the test sets."""

    def __init__(self, name: str) -> None:
        self.name = name
        self.answer: LinkSample | BaseException = LinkUnavailable("not yet")
        self.reads = 0
        self.closed = False

    async def read(self) -> LinkSample:
        self.reads += 1
        if isinstance(self.answer, BaseException):
            raise self.answer
        return self.answer

    def close(self) -> None:
        self.closed = True


def _poll(monitor: LinkMonitor) -> LinkSample | None:
    return asyncio.run(monitor.poll())


def _events(logs: list[MutableMapping[str, Any]]) -> list[str]:
    return [str(e["event"]) for e in logs]


def test_fallback_when_nl80211_is_absent_logs_once_then_uses_next_source() -> None:
    # The real nl80211 source on loopback: no nl80211 family here (or lo is not wireless).
    nl = Nl80211Source("lo")
    monitor = LinkMonitor([nl, StaticSource(0.6)], structlog.get_logger())
    with capture_logs() as logs:
        first = _poll(monitor)
        second = _poll(monitor)
    assert first == second == LinkSample(q=0.6, source="static")
    retired = [e for e in logs if e["event"] == "link_source_retired"]
    assert len(retired) == 1
    assert retired[0]["source"] == "nl80211"
    assert retired[0]["next_source"] == "static"
    assert "nl80211" in retired[0]["reason"]
    assert _events(logs).count("link_source_active") == 1
    assert "nl80211" in monitor.retired
    assert monitor.active_source == "static"


def test_transient_failure_falls_back_and_better_source_takes_over_again() -> None:
    top, bottom = _Scripted("file"), _Scripted("static")
    bottom.answer = LinkSample(q=0.5)
    monitor = LinkMonitor([top, bottom], structlog.get_logger())
    with capture_logs() as logs:
        assert _poll(monitor) == LinkSample(q=0.5)
        top.answer = LinkSample(q=0.9, source="file")
        assert _poll(monitor) == LinkSample(q=0.9, source="file")
        assert _poll(monitor) == LinkSample(q=0.9, source="file")
    active = [e for e in logs if e["event"] == "link_source_active"]
    assert [e["source"] for e in active] == ["static", "file"]
    assert active[0]["skipped"] == {"file": "not yet"}
    assert top.reads == 3  # a transient failure is retried every poll
    assert not top.closed


def test_permanent_failure_retires_and_closes() -> None:
    gone, other = _Scripted("nl80211"), _Scripted("static")
    gone.answer = LinkUnavailable("no family", permanent=True)
    other.answer = LinkSample(q=0.3)
    monitor = LinkMonitor([gone, other], structlog.get_logger())
    with capture_logs():
        _poll(monitor)
        _poll(monitor)
    assert gone.reads == 1
    assert gone.closed


def test_nothing_available_returns_none_keeps_latest_and_logs_once() -> None:
    only = _Scripted("file")
    only.answer = LinkSample(q=0.7)
    monitor = LinkMonitor([only], structlog.get_logger())
    with capture_logs() as logs:
        _poll(monitor)
        only.answer = LinkUnavailable("file vanished")
        assert _poll(monitor) is None
        assert _poll(monitor) is None
    assert _events(logs).count("link_unavailable") == 1
    assert monitor.latest == LinkSample(q=0.7)


def test_a_buggy_source_does_not_escape() -> None:
    buggy, backup = _Scripted("file"), _Scripted("static")
    buggy.answer = ZeroDivisionError("bug")
    backup.answer = LinkSample(q=0.2)
    monitor = LinkMonitor([buggy, backup], structlog.get_logger())
    with capture_logs() as logs:
        assert _poll(monitor) == LinkSample(q=0.2)
    assert "link_source_failed" in _events(logs)
