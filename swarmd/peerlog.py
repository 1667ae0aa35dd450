"""What the operator sees in flight: the last peer changes (lost, regained, restarted).

``swarmctl status`` shows where each peer stands now; in flight the operator also needs
what just happened: which drone dropped out, why (its lease ran out, or it said goodbye),
how good its link was and how long it had been silent when it was declared lost, and when
it came back (issue 20). The daemon records discovery's ``PeerDiscovered``/``PeerLost``/
``PeerRestarted`` here and serves the ring in ``status`` (``peer_changes``); ``swarmctl
watch`` prints the ones it has not shown yet.

Sans-IO: times are the daemon's monotonic ``now`` passed in. The ring is capped
(``MAX_PEER_CHANGES``): only bundle peers produce these events, but a peer flapping at the
edge of range must not grow the daemon's memory, so the oldest change is dropped and counted.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from enum import StrEnum
from typing import Any, Final

# a fading peer at the edge of range can flap every lease: 64 changes is minutes of a bad
# flight for a handful of peers, and bounds what a flapping (or hostile) member costs us
MAX_PEER_CHANGES: Final = 64


class PeerChangeKind(StrEnum):
    DISCOVERED = "discovered"  # first time this life of ours
    REGAINED = "regained"  # discovered again after being lost
    LOST = "lost"
    RESTARTED = "restarted"  # its signed boot epoch rose: it rebooted within its lease


@dataclass(frozen=True, slots=True)
class PeerChange:
    """One change of one peer, on the daemon's clock.

    ``link_q``: the link quality the peer itself advertised in its latest DATA(p), in
    [0, 1] (None if it never sent one); ``silent_s``: how long it had not been heard at the
    change (for a loss by lease: about the lease)."""

    seq: int
    at: float
    peer: str
    kind: PeerChangeKind
    reason: str | None
    link_q: float | None
    silent_s: float | None


class PeerHistory:
    """A capped ring of peer changes, numbered from 1 so a client can ask "what is new"."""

    def __init__(self, cap: int = MAX_PEER_CHANGES) -> None:
        self._ring: deque[PeerChange] = deque(maxlen=cap)
        self._seq = 0
        self._seen: set[str] = set()  # peers discovered at least once (bundle names only)
        self.dropped = 0  # changes pushed out of the ring by newer ones
        self.lost = 0
        self.regained = 0

    def record(
        self,
        now: float,
        peer: str,
        kind: PeerChangeKind,
        *,
        reason: str | None = None,
        link_quality_permille: int | None = None,
        last_heard: float | None = None,
    ) -> PeerChange:
        """Record a change; ``DISCOVERED`` of a peer seen before is stored as ``REGAINED``."""
        if kind is PeerChangeKind.DISCOVERED:
            if peer in self._seen:
                kind = PeerChangeKind.REGAINED
                self.regained += 1
            self._seen.add(peer)
        elif kind is PeerChangeKind.LOST:
            self.lost += 1
        if len(self._ring) == self._ring.maxlen:
            self.dropped += 1
        self._seq += 1
        change = PeerChange(
            seq=self._seq,
            at=now,
            peer=peer,
            kind=kind,
            reason=reason,
            link_q=None if link_quality_permille is None else link_quality_permille / 1000,
            silent_s=None if last_heard is None else max(0.0, now - last_heard),
        )
        self._ring.append(change)
        return change

    def changes(self) -> tuple[PeerChange, ...]:
        return tuple(self._ring)

    def status(self, now: float) -> dict[str, Any]:
        """JSON form (``status.peer_changes``): ``last_seq`` lets a client print only what is
        new; ``ago_s`` dates each change against the reply."""
        return {
            "last_seq": self._seq,
            "lost": self.lost,
            "regained": self.regained,
            "dropped": self.dropped,
            "changes": [
                {
                    "seq": c.seq,
                    "clock_s": round(c.at, 3),
                    "ago_s": round(max(0.0, now - c.at), 3),
                    "peer": c.peer,
                    "change": str(c.kind),
                    "reason": c.reason,
                    "link_q": None if c.link_q is None else round(c.link_q, 3),
                    "silent_s": None if c.silent_s is None else round(c.silent_s, 3),
                }
                for c in self._ring
            ],
        }
