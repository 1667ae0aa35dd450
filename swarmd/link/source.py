"""The one interface every link-quality source implements."""

from __future__ import annotations

from typing import Protocol

from swarmd.discovery.inputs import LinkSample


class LinkUnavailable(Exception):
    """The source cannot give a reading now (``permanent=False``) or ever (``permanent=True``).

    ``reason`` is one line an operator can act on; the monitor logs it and moves on to the
    next source. Permanent failures (no nl80211 in the kernel, not a wireless interface)
    retire the source for the daemon's life so it is not retried every poll.
    """

    def __init__(self, reason: str, *, permanent: bool = False) -> None:
        super().__init__(reason)
        self.reason = reason
        self.permanent = permanent


class LinkSource(Protocol):
    """A place a link-quality reading comes from."""

    @property
    def name(self) -> str:
        """Which source this is (``swarmd.link.SourceName``)."""
        ...

    async def read(self) -> LinkSample:
        """One reading; raises ``LinkUnavailable`` (and nothing else, by contract)."""
        ...

    def close(self) -> None:
        """Release what the source holds (sockets); idempotent."""
        ...
