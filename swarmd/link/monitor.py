"""The link monitor: an ordered list of sources, the first that answers wins.

Every poll walks the list from the top, so a better source that comes back (the interface
associates again, the testbed rewrites its file) takes over at once. A source that fails
permanently is retired with one log line; the monitor logs only when the active source
changes, never once per poll.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from swarmd.discovery.inputs import LinkSample
from swarmd.link.source import LinkSource, LinkUnavailable


class LinkMonitor:
    """Polls ``sources`` in order and remembers the latest sample."""

    def __init__(self, sources: Sequence[LinkSource], log: Any) -> None:
        if not sources:
            raise ValueError("a link monitor needs at least one source")
        self._sources = list(sources)
        self._retired: dict[str, str] = {}
        self._log = log
        self._active: str | None = None
        self._none_logged = False
        self.latest: LinkSample | None = None

    @property
    def active_source(self) -> str | None:
        return self._active

    @property
    def retired(self) -> dict[str, str]:
        """Sources retired for good, with the reason."""
        return dict(self._retired)

    async def poll(self) -> LinkSample | None:
        """One reading from the first source that has one, or None when none has."""
        skipped: dict[str, str] = {}
        for source in self._sources:
            if source.name in self._retired:
                continue
            try:
                sample = await source.read()
            except LinkUnavailable as exc:
                skipped[source.name] = exc.reason
                if exc.permanent:
                    self._retire(source, exc.reason)
                continue
            except Exception as exc:  # a source bug must not stop discovery
                skipped[source.name] = f"unexpected {type(exc).__name__}: {exc}"
                self._log.exception("link_source_failed", source=source.name)
                continue
            if source.name != self._active:
                self._log.info(
                    "link_source_active", source=source.name, q=sample.q, skipped=skipped
                )
                self._active = source.name
                self._none_logged = False
            self.latest = sample
            return sample
        if not self._none_logged:
            keep = self.latest.q if self.latest is not None else None
            self._log.warning("link_unavailable", tried=skipped, keeping_q=keep)
            self._none_logged = True
        self._active = None
        return None

    def _retire(self, source: LinkSource, reason: str) -> None:
        self._retired[source.name] = reason
        source.close()
        remaining = [s.name for s in self._sources if s.name not in self._retired]
        nxt = remaining[0] if remaining else None
        self._log.warning("link_source_retired", source=source.name, reason=reason, next_source=nxt)

    def close(self) -> None:
        for source in self._sources:
            source.close()
