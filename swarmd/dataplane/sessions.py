"""The data plane's per-peer sessions: who is up, in which boot epoch, at which locator,
which endpoint pairs are matched with it, and what is queued for it.

A session opens when discovery reports the peer (``up``, with the locator and the boot
epoch from its authenticated SPDP) and closes with ``down``. Back in the same epoch (a
link that came back), our writers resume its readers where they were; in a new epoch the
peer restarted: its reliable state and replay window start over, and each still-held
command it never acknowledged is voided for it (``CommandCopyVoided``; docs/dataplane.md,
"Rejoining while a command is valid"). An epoch lower than one seen is ignored (counted).

Split out of ``plane.py`` by concern: the plane keeps the wire in and out; the keys and
windows are ``pairs.py``'s. Sans-IO; no clock.
"""

from __future__ import annotations

from collections import Counter, deque
from dataclasses import dataclass, field

from swarmd.auth.freshness import U32_MAX, ReplayWindow
from swarmd.bundle.model import Bundle, EndpointKind, Participant
from swarmd.dataplane.endpoints import TOPIC_COMMAND, Endpoints, Writer
from swarmd.dataplane.events import CommandCopyVoided, DataPlaneEvent
from swarmd.dataplane.ledger import CommandLedger
from swarmd.dataplane.outgoing import Outgoing
from swarmd.dataplane.pairs import PairChannels
from swarmd.rtps.message import Submessage, encode_submessage
from swarmd.rtps.types import EntityId, Guid, GuidPrefix

__all__ = ["PeerSession", "Sessions"]


@dataclass(slots=True)
class PeerSession:
    participant: Participant
    locator: tuple[str, int]
    matched: list[tuple[EntityId, Guid]] = field(default_factory=list)  # (local entity, remote)


class Sessions:
    """One ``PeerSession`` per peer up, by name and by GUID prefix (bounded: bundle
    participants only), and the submessages queued per peer until ``frames``."""

    __slots__ = (
        "_bundle",
        "_counters",
        "_endpoints",
        "_events",
        "_ledger",
        "_local",
        "_pairs",
        "by_name",
        "by_prefix",
        "pending",
    )

    def __init__(
        self,
        bundle: Bundle,
        local: Participant,
        endpoints: Endpoints,
        pairs: PairChannels,
        ledger: CommandLedger,
        counters: Counter[str],
        events: deque[DataPlaneEvent],
    ) -> None:
        self._bundle = bundle
        self._local = local
        self._endpoints = endpoints
        self._pairs = pairs
        self._ledger = ledger
        self._counters = counters
        self._events = events
        self.by_name: dict[str, PeerSession] = {}
        self.by_prefix: dict[GuidPrefix, str] = {}
        self.pending: dict[GuidPrefix, list[Submessage]] = {}

    def up(self, name: str, locator: tuple[str, int], now: float, epoch: int) -> GuidPrefix | None:
        """Open (or move) ``name``'s session (``DataPlane.peer_up``); its prefix when it
        came up, so what it sent early may be taken now, else None."""
        peer = self._bundle.participant(name)
        if peer.name == self._local.name:
            raise ValueError(f"peer_up({name!r}) names this node itself")
        if not 0 <= epoch <= U32_MAX:
            raise ValueError(f"epoch {epoch} outside 0..{U32_MAX}")
        channel = self._pairs.channel(peer.guid_prefix, epoch)
        if channel is None:
            self._counters["peer_without_key"] += 1
            return None
        if epoch < channel.peer_epoch:
            # Epochs only grow (swarmd.auth.epoch); an older one would re-open the replay
            # window to that life's captures. Discovery refuses such SPDP too: fail closed.
            self._counters["peer_epoch_went_back"] += 1
            return None
        known = self.by_name.get(name)
        if known is not None:
            if channel.peer_epoch == epoch:
                known.locator = locator
                return None
            self.down(name)
            self._counters["peer_restarts"] += 1
        same_life = channel.peer_epoch == epoch
        if not same_life:
            channel.peer_epoch = epoch
            channel.window = ReplayWindow()
        state = PeerSession(peer, locator)
        self.by_name[name] = state
        self.by_prefix[peer.guid_prefix] = name
        for match in self._bundle.matches(self._local, peer):
            entity = match.local.entity_id
            if match.local_kind == EndpointKind.WRITER and entity in self._endpoints.writers:
                writer = self._endpoints.writers[entity][1]
                if not same_life:
                    self._void_copies(name, writer, writer.forget_reader(match.remote))
                self.queue(writer.add_reader(match.remote, now, resume=same_life))
            elif match.local_kind == EndpointKind.READER and entity in self._endpoints.readers:
                self._endpoints.readers[entity][1].add_writer(match.remote)
            else:
                continue
            state.matched.append((entity, match.remote))
        return peer.guid_prefix

    def down(self, name: str) -> None:
        """Close ``name``'s session (``DataPlane.peer_down``); its channel stays."""
        state = self.by_name.pop(name, None)
        if state is None:
            return
        self.by_prefix.pop(state.participant.guid_prefix, None)
        self.pending.pop(state.participant.guid_prefix, None)
        for entity, remote in state.matched:
            if entity in self._endpoints.writers:
                self._endpoints.writers[entity][1].remove_reader(remote)
            else:
                self._endpoints.readers[entity][1].remove_writer(remote)

    def queue(self, out: list[Outgoing]) -> None:
        for item in out:
            self.pending.setdefault(item.peer, []).append(item.submessage)

    def frames(
        self, head: bytes, room: int
    ) -> list[tuple[GuidPrefix, tuple[str, int], list[bytes]]]:
        """Everything queued, as (peer, locator, messages): ``head`` and as many encoded
        submessages as fit in ``room`` octets each (one alone may exceed it); the queue
        is emptied, and what is queued for a peer not up is dropped."""
        out: list[tuple[GuidPrefix, tuple[str, int], list[bytes]]] = []
        for prefix, submessages in self.pending.items():
            name = self.by_prefix.get(prefix)
            if name is None:
                continue
            chunks: list[bytes] = []
            chunk = head
            for sm in submessages:
                encoded = encode_submessage(sm)
                if len(chunk) + len(encoded) > room and chunk != head:
                    chunks.append(chunk)
                    chunk = head
                chunk += encoded
            if chunk != head:
                chunks.append(chunk)
            out.append((prefix, self.by_name[name].locator, chunks))
        self.pending.clear()
        return out

    def _void_copies(self, name: str, writer: Writer, sns: list[int]) -> None:
        if writer is not self._endpoints.by_topic.get(TOPIC_COMMAND):
            return  # an outcome or another topic: the new life simply starts afresh
        for sn in sns:
            command_id = self._ledger.command_at(sn)
            if command_id is not None:
                self._counters["command_copies_voided"] += 1
                self._events.append(CommandCopyVoided(name, command_id))
