"""The data plane's authentication state with one bundle participant (issue 10, ``seal.py``).

One ``Channel`` per bundle participant the key ring has a pair key for, made on first use
and kept across ``peer_down`` (so a peer lost and found again in the same epoch cannot be
fed its own old datagrams): the prepared HMAC of the pair's user-data key, this node's
freshness counter towards the peer, the peer's boot epoch (from its authenticated SPDP,
via ``peer_up``) and the replay window of what it sent in that epoch.

``check`` does the receive side's checks in cost order, so a forgery costs at most one
HMAC, and only if it guessed a fresh sequence in the sender's current epoch and ours
(docs/security.md). Sans-IO; no clock.
"""

from __future__ import annotations

import hmac
from dataclasses import dataclass, field

from swarmd.auth.freshness import ReplayWindow, SendCounter
from swarmd.dataplane.seal import EPOCH_HINT_MASK, peek_trailer, verify
from swarmd.rtps.types import GuidPrefix


@dataclass(slots=True)
class Channel:
    """Authentication state with one bundle participant; kept across ``peer_down``."""

    key: hmac.HMAC
    tx: SendCounter  # our freshness towards this peer (per pair: a dense window there)
    peer_epoch: int  # from its authenticated SPDP, via peer_up
    window: ReplayWindow = field(default_factory=ReplayWindow)

    def check(self, data: bytes, me: GuidPrefix, my_epoch: int) -> tuple[str, str] | None:
        """None when ``data`` is authentic and fresh for receiver ``me`` in ``my_epoch``
        (its freshness is then recorded), else (reason, detail)."""
        trailer = peek_trailer(data)
        if trailer is None:
            return "auth_missing", "no swarmd authenticator at the end"
        fresh = trailer.freshness
        if fresh.epoch != self.peer_epoch:
            # Lower: a datagram of an earlier life (replay). Higher: the sender restarted
            # and its new SPDP has not reached us yet; refused until it does.
            older = fresh.epoch < self.peer_epoch
            reason = "auth_stale_epoch" if older else "auth_epoch_ahead"
            return reason, f"epoch {fresh.epoch}, known {self.peer_epoch}"
        if trailer.epoch_hint != my_epoch & EPOCH_HINT_MASK:
            # Made for another life of ours: a capture replayed after we restarted, or a
            # sender that has not yet heard our new SPDP.
            return "auth_receiver_epoch", f"hint {trailer.epoch_hint}, ours {my_epoch}"
        if not self.window.is_fresh(fresh):
            return "auth_replayed", f"{fresh.epoch}/{fresh.seq}"
        if not verify(self.key, data, me, my_epoch):
            return "auth_failed", f"{fresh.epoch}/{fresh.seq}"
        self.window.accept(fresh)
        return None
