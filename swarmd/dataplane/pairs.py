"""The data plane's sealing and opening: one ``Channel`` per bundle participant, and the
freshness windows in them (issue 10, ``seal.py``, ``channel.py``, docs/security.md).

Every datagram to a peer is ``Header + submessages + AUTH``: a swarmd vendor submessage
carrying this node's freshness (epoch, per-peer sequence) and an HMAC-SHA256 tag under the
pair key the bundle gives the two nodes, bound to the peer's current epoch (``seal``).
A datagram from a peer is verified before it can move anything: the cheap checks first
(a trailer, the sender's known epoch, our epoch's hint, a fresh sequence in the sender's
replay window), then the tag (``Channel.check``). Replay windows, send counters and keys
live per bundle participant and outlive ``peer_down``, so a peer lost and found again in
the same epoch cannot be fed its own old datagrams.

Split out of ``plane.py`` by concern: the plane keeps the peers' sessions (who is up, in
which epoch, where) and routing; this keeps the keys and the freshness. Sans-IO; no clock.
"""

from __future__ import annotations

import hmac
from typing import Protocol

from swarmd.auth.freshness import CounterExhausted, Freshness, SendCounter
from swarmd.dataplane.channel import Channel
from swarmd.dataplane.seal import EPOCH_HINT_MASK, Trailer, peek_trailer, seal, user_data_key
from swarmd.dataplane.seal import verify as verify_tag
from swarmd.rtps.types import GuidPrefix

__all__ = ["PairChannels", "PairKeys"]


class PairKeys(Protocol):
    """Where the plane gets pairwise keys: ``swarmd.auth.keys.KeyRing`` in the daemon."""

    def pair_key(self, peer: GuidPrefix) -> bytes | None:
        """The 32-byte key this node shares with ``peer`` (equal on both ends), or None."""
        ...


class PairChannels:
    """This node's ``Channel`` with each bundle participant it has a pair key for.

    ``prefix`` and ``epoch`` are this node's: what a datagram to us is bound to. Only
    bundle prefixes reach here (the plane checks membership first), so the tables hold at
    most one entry per bundle participant."""

    __slots__ = ("_keys", "_prepared", "channels", "epoch", "prefix")

    def __init__(self, keys: PairKeys, prefix: GuidPrefix, epoch: int) -> None:
        self._keys = keys
        self.prefix = prefix
        self.epoch = epoch
        self.channels: dict[GuidPrefix, Channel] = {}
        # prepared MAC states of participants without a channel yet (the early hold's check)
        self._prepared: dict[GuidPrefix, hmac.HMAC] = {}

    def channel(self, prefix: GuidPrefix, epoch: int) -> Channel | None:
        """The authentication state with a bundle participant, made on first use (its peer
        epoch ``epoch``); None without a pair key."""
        channel = self.channels.get(prefix)
        if channel is None:
            key = self.key(prefix)
            if key is None:
                return None
            channel = Channel(key, SendCounter(self.epoch), epoch)
            self.channels[prefix] = channel
        return channel

    def peer_epoch(self, prefix: GuidPrefix) -> int | None:
        """The boot epoch of the participant's life last authenticated, None if never."""
        channel = self.channels.get(prefix)
        return None if channel is None else channel.peer_epoch

    def key(self, prefix: GuidPrefix) -> hmac.HMAC | None:
        """The prepared user-data MAC state with a bundle participant (its channel's once
        it has one), None without a pair key."""
        channel = self.channels.get(prefix)
        if channel is not None:
            return channel.key
        key = self._prepared.get(prefix)
        if key is None:
            pair_key = self._keys.pair_key(prefix)
            if pair_key is None:
                return None
            key = self._prepared[prefix] = user_data_key(pair_key)
        return key

    def early_trailer(self, data: bytes) -> Trailer | None:
        """Cheap, stateless: the trailer of a datagram from a participant not up, if it is
        sealed for this life of ours (a capture made for an earlier one can never pass,
        docs/security.md); the caller checked its size."""
        trailer = peek_trailer(data)
        if trailer is None or trailer.epoch_hint != self.epoch & EPOCH_HINT_MASK:
            return None
        return trailer

    def may_hold(self, prefix: GuidPrefix, data: bytes, fresh: Freshness) -> tuple[str, str] | None:
        """Whether a datagram of a participant not up may take a slot in the early hold:
        None if so, else (reason, detail). Cheapest first, as ``Channel.check``: an earlier
        life of the sender, or a freshness its replay window already took (a capture), then
        the tag for this life of ours (one HMAC). The sender's epoch cannot be checked yet
        (its SPDP has not been taken), and nothing moves here: the window moves at release,
        where every check runs again. Without this a forger cycled the hold's slots and
        pushed a genuine report out (docs/security-history.md, "Network paths end to end")."""
        channel = self.channels.get(prefix)
        if channel is not None and fresh.epoch <= channel.peer_epoch:
            if fresh.epoch < channel.peer_epoch:
                return "auth_stale_epoch", f"epoch {fresh.epoch}, known {channel.peer_epoch}"
            if not channel.window.is_fresh(fresh):
                return "auth_replayed", f"{fresh.epoch}/{fresh.seq}"
        key = self.key(prefix)
        if key is None or not verify_tag(key, data, self.prefix, self.epoch):
            return "auth_failed", f"{fresh.epoch}/{fresh.seq}"
        return None

    def seal(self, prefix: GuidPrefix, messages: list[bytes]) -> tuple[list[bytes], bool]:
        """``messages`` to a participant with a channel, each sealed under the next
        freshness of our counter towards it; True when the counter ran out (2^32 - 1
        datagrams to one peer in one epoch) and the rest were not sent."""
        channel = self.channels[prefix]
        out: list[bytes] = []
        for message in messages:
            try:
                freshness = channel.tx.next()
            except CounterExhausted:
                return out, True
            out.append(seal(channel.key, message, freshness, prefix, channel.peer_epoch))
        return out, False
