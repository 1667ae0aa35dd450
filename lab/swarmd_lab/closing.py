"""One shape for the lab's resources that must go on every exit path.

A LAN of namespaces (``netns.Lan``), the Wi-Fi testbed (``bench.wifi.topology.Testbed``) and
the start barrier's socket (``bench.wifi.barrier.StartBarrier``) are used as ``with X(...) as
x:``: entering builds the resource (``_open``), and it is closed on normal exit, on an
exception and on KeyboardInterrupt, and also when building fails half-way (``close`` undoes
whatever part of it exists, so it must be idempotent).
"""

from __future__ import annotations

from typing import Self


class Closing:
    """Base of a resource built on ``with`` entry and closed on every exit path."""

    def _open(self) -> None:
        """Build the resource (nothing by default: built by the constructor)."""

    def close(self) -> None:
        """Release the resource; idempotent, and safe on a half-built one."""
        raise NotImplementedError

    def __enter__(self) -> Self:
        try:
            self._open()
        except BaseException:  # KeyboardInterrupt too: nothing half-built may stay behind
            self.close()
            raise
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()
