"""Who may speak as the autopilot on a UDP link: the pinned address, and nobody else.

Issue 10, attack 6: a ``udpin:`` link that learns its reply address from any datagram lets
anyone who reaches the port pose as PX4 (forged ``HEARTBEAT`` armed -> readiness says
``armed``) and receive swarmd's commands (the bridge's ARM went to the attacker). The guard:

- **pinned**: the autopilot's address is either configured (``px4.autopilot``, or the
  ``udpout:`` target), or pinned to the source of the first ``HEARTBEAT`` from the
  configured system and component 1 on the configured endpoint (with signing on, that
  heartbeat must also carry a good signature: the codec drops it otherwise);
- **dropped before decoding**: a datagram from any other address, counted
  (``dropped_address``); before the pin, every frame but the pinning heartbeat is dropped
  (``dropped_unpinned``), so nothing reaches readiness from an address not yet trusted;
- **replies** go only to the pinned address (the transport has no other destination);
- **re-pin** (learned pins only): when the pinned address has been silent for
  ``repin_after_s`` (PX4 rebooted, mavlink-router restarted on a new source port), the next
  good heartbeat pins again, counted in ``repins``. A configured address never moves.

Pure: addresses are ``"host:port"`` strings, time is the caller's ``now``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Final

REPIN_AFTER_S: Final = 5.0  # 2 x PX4's 2.5 s heartbeat timeout: the old peer is gone


@dataclass(slots=True)
class AutopilotPin:
    """The autopilot's address on one UDP link, and what was refused for not being it."""

    configured: str | None = None  # a fixed address; None: learn from the first heartbeat
    repin_after_s: float = REPIN_AFTER_S
    address: str | None = None
    last_heard: float | None = None
    counts: dict[str, int] = field(
        default_factory=lambda: {"dropped_address": 0, "dropped_unpinned": 0, "repins": 0}
    )

    def __post_init__(self) -> None:
        if self.configured is not None:
            self.address = self.configured

    @property
    def learned(self) -> bool:
        return self.configured is None

    def admit_datagram(self, source: str, now: float) -> bool:
        """Cheap check before any decoding: does ``source`` speak for the autopilot?

        True for the pinned address, and, while no address is pinned (or a learned one has
        gone silent), for anyone: their frames then face ``admit_frame``.
        """
        if self.address is None or source == self.address:
            return True
        if self._may_repin(now):
            return True
        self.counts["dropped_address"] += 1
        return False

    def admit_frame(self, source: str, is_autopilot_heartbeat: bool, now: float) -> bool:
        """A decoded (and, with signing, verified) frame from ``source``: deliver it?"""
        if source == self.address:
            self.last_heard = now
            return True
        if is_autopilot_heartbeat and (self.address is None or self._may_repin(now)):
            if self.address is not None:
                self.counts["repins"] += 1
            self.address = source
            self.last_heard = now
            return True
        self.counts["dropped_unpinned"] += 1
        return False

    def _may_repin(self, now: float) -> bool:
        return (
            self.learned
            and self.address is not None
            and self.last_heard is not None
            and now - self.last_heard > self.repin_after_s
        )

    def stats(self) -> dict[str, object]:
        return {"pinned": self.address, "pin": "configured" if not self.learned else "learned"}
