"""The driving protocol every sans-IO core of swarmd speaks, declared once.

After aioquic's ``QuicConnection`` (style.md rules 2 and 11): inputs
``receive_datagram(data, source, now)`` and ``handle_timer(now)``; outputs
``datagrams_to_send()``, ``get_timer()`` (one earliest absolute deadline) and
``next_event()``. ``swarmd.driver.Driver`` runs a core on the event loop, the lab's
``MemNet`` on virtual time, and the simulator on its channel model: all three through this
protocol (docs/architecture.md, "The driving protocol"). No imports of swarmd, no I/O.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Protocol, TypeVar

InT_contra = TypeVar("InT_contra", contravariant=True)
OutT_co = TypeVar("OutT_co", covariant=True)
EvT_co = TypeVar("EvT_co", covariant=True)


class SansIOCore(Protocol[InT_contra, OutT_co, EvT_co]):
    """The driving protocol every swarmd core implements (docs/architecture.md)."""

    def receive_datagram(self, data: InT_contra, source: Any, now: float) -> None: ...

    def handle_timer(self, now: float) -> None: ...

    def datagrams_to_send(self) -> Sequence[OutT_co]: ...

    def get_timer(self) -> float | None: ...

    def next_event(self) -> EvT_co | None: ...
