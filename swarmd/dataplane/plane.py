"""The user-data plane of one node: RTPS DATA between the endpoints the bundle preloaded.

Sans-IO, like the discovery engine (docs/dataplane.md). Three sources drive it:

* received datagrams: ``receive_datagram(data, source, now)`` on the node's user unicast port;
* timer expiry: ``handle_timer(now)`` at ``get_timer()`` (reliable writers' heartbeats);
* calls from its owner: discovery's ``peer_up``/``peer_down`` and the application's
  ``publish_readiness``, ``send_command``, ``report_outcome``.

It answers with ``datagrams_to_send()`` (payload, (host, port)) and ``next_event()``.

Theory of operation. There is no SEDP: the bundle says which endpoint of which participant
talks to which (``Bundle.matches``). A match becomes live when discovery reports the peer
(``peer_up``, with the default unicast locator and the boot epoch from its authenticated
SPDP) and dies with ``peer_down``. Each local endpoint is an RTPS writer or reader chosen by
the topic's QoS in the bundle (``writer.py``, ``reader.py``); ``endpoints.py`` holds them and
routes each authenticated submessage to the one it addresses.

Authentication (issue 10, ``seal.py``, ``channel.py``, docs/security.md). Every datagram to
a peer is ``Header + submessages + AUTH``: a swarmd vendor submessage carrying this node's
freshness (epoch, per-peer sequence) and an HMAC-SHA256 tag under the pair key the bundle
gives the two nodes, bound to the peer's current epoch. A datagram from a peer is verified
before it can move anything (reader positions, acknowledged sets, readiness rows, dedup
sets): its GUID prefix must be a bundle participant discovery reported up, then the cheap
checks (a trailer, the sender's known epoch, our epoch's hint, a fresh sequence in the
sender's replay window), then the tag; only then is it decoded and each submessage must
address a matched endpoint pair. Replay windows, send counters and keys live per bundle
participant and outlive ``peer_down``, so a peer lost and found again in the same epoch
cannot be fed its own old datagrams.

Commands go out as one sample (one SN, one command id) with one copy per target, each
naming only that member and carrying only its time echo, so a command's size does not grow
with the swarm (``send_command``; docs/dataplane.md, "One copy per member").

Exactly-once commands: the reliable reader delivers each SN of a writer life at most once;
above it, a bounded set of executed ``(commander, command_id)`` pairs (``ledger.py``) turns
re-deliveries (a commander resending the same id, a proxy reset after ``peer_down``/
``peer_up``) into no-ops. Command ids carry the commander's boot epoch in their high 32
bits, so a restarted commander never reuses one, even when its state file (the boot
counter) was lost (docs/dataplane.md, "Exactly once"). An id is dated once: a resend
carries its first send's validity and echoes (``ledger.CommandLedger.dated``).

Invariant: ``receive_datagram`` never raises, whatever the bytes; bad input becomes a
``PacketDropped`` event and a counter. Any other exception escaping it is a bug.
"""

from __future__ import annotations

import hmac
from collections import Counter, deque
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any, Final, Protocol

from swarmd.auth.freshness import (
    U32_MAX,
    CounterExhausted,
    Freshness,
    ReplayWindow,
    SendCounter,
)
from swarmd.bundle.model import Bundle, EndpointKind, Participant, Topic
from swarmd.dataplane.channel import Channel
from swarmd.dataplane.early import EarlyDatagrams
from swarmd.dataplane.endpoints import (
    TOPIC_COMMAND,
    TOPIC_OUTCOME,
    TOPIC_READY,
    Endpoints,
    Refused,
    Writer,
)
from swarmd.dataplane.events import (
    CommandCopyVoided,
    CommandReceived,
    DataPlaneEvent,
    OutcomeReceived,
    PacketDropped,
    ReadinessReceived,
)
from swarmd.dataplane.ledger import CommandLedger, KeptOutcome, command_copies
from swarmd.dataplane.outgoing import Outgoing
from swarmd.dataplane.reader import Delivered
from swarmd.dataplane.seal import (
    EPOCH_HINT_MASK,
    TRAILER_BYTES,
    Trailer,
    peek_trailer,
    protected_part,
    seal,
    user_data_key,
    verify,
)
from swarmd.dataplane.types import (
    MAX_REASON_CHARS,
    TYPES_BY_NAME,
    Command,
    CommandKind,
    CommandOutcome,
    CommandResult,
    PayloadError,
    Readiness,
    Sample,
    TimeEcho,
    decode_sample,
    encode_sample,
)
from swarmd.dataplane.validity import echo_of
from swarmd.dataplane.writer import MAX_INCARNATION, ReliableWriter
from swarmd.rtps.errors import DecodeError
from swarmd.rtps.message import (
    AckNack,
    Data,
    Gap,
    Header,
    Heartbeat,
    InfoDst,
    Submessage,
    decode_header,
    decode_message,
    encode_header,
    encode_submessage,
)
from swarmd.rtps.types import (
    PROTOCOLVERSION_SWARMD,
    UNKNOWN_GUID_PREFIX,
    VENDORID_SWARMD,
    EntityId,
    Guid,
    GuidPrefix,
)

# Stay under a Wi-Fi MTU (1500 - IPv4 20 - UDP 8) with margin: never IP-fragment user data.
MAX_DATAGRAM_BYTES: Final = 1400
# Undrained events kept; past it drop reports are counted, not queued (samples always are).
MAX_PENDING_EVENTS: Final = 4096


class PairKeys(Protocol):
    """Where the plane gets pairwise keys: ``swarmd.auth.keys.KeyRing`` in the daemon."""

    def pair_key(self, peer: GuidPrefix) -> bytes | None:
        """The 32-byte key this node shares with ``peer`` (equal on both ends), or None."""
        ...


@dataclass(slots=True)
class _Peer:
    participant: Participant
    locator: tuple[str, int]
    matched: list[tuple[EntityId, Guid]] = field(default_factory=list)  # (local entity, remote)


@dataclass(slots=True)
class ReadinessStats:
    """Readiness samples received from one member: how many, the latest, when (``now``)."""

    count: int = 0
    last: Readiness | None = None
    last_rx: float = 0.0
    epoch: int = 0  # the member's boot epoch when ``last`` arrived: its clock's life


class ForeignCommandId(ValueError):
    """``send_command`` was given an id this life neither made nor sent (nothing sent)."""


class CommandIdsExhausted(ValueError):
    """``make_command`` gave out every counter of this life (2^32 - 1): restart for more."""


class DataPlane:
    """RTPS user data for one node of a bundle. Sans-IO; see the module docstring."""

    def __init__(
        self,
        bundle: Bundle,
        local_name: str,
        *,
        keys: PairKeys,
        epoch: int,
        incarnation: int = 0,
        executed_command_ids: Iterable[tuple[str, int]] = (),
        executed_outcomes: Iterable[KeptOutcome] = (),
    ) -> None:
        """``keys`` gives the pairwise keys (``KeyRing``); ``epoch`` is this node's boot
        epoch, the one its SPDP announces (``swarmd.auth.epoch``): peers bind the datagrams
        they send here to it. ``incarnation`` must grow with every restart of this node (a
        persisted boot counter, or wall-clock seconds); it keeps sequence numbers and
        command ids unique across restarts. ``executed_command_ids`` restores the dedup set
        a previous life saved from ``executed_command_ids``, ``executed_outcomes`` what it
        decided for them (``executed_outcomes``; ``earlier_outcomes``)."""
        if not 0 <= incarnation <= MAX_INCARNATION:
            raise ValueError(f"incarnation {incarnation} outside 0..{MAX_INCARNATION}")
        if not 0 <= epoch <= U32_MAX:
            raise ValueError(f"epoch {epoch} outside 0..{U32_MAX}")
        self.bundle = bundle
        self.local = bundle.participant(local_name)
        self.prefix = self.local.guid_prefix
        self.incarnation = incarnation
        self.epoch = epoch
        self._keys = keys
        self._channels: dict[GuidPrefix, Channel] = {}
        # prepared MAC states of participants without a channel yet (the early hold's check)
        self._keys_prepared: dict[GuidPrefix, hmac.HMAC] = {}
        # our writers and readers, and what reaches them (endpoints.py)
        self._endpoints = Endpoints(bundle, self.local, incarnation)
        self._participants: dict[str, Participant] = {p.name: p for p in bundle.participants}
        self._peers: dict[str, _Peer] = {}
        self._peer_by_prefix: dict[GuidPrefix, str] = {}
        self._pending: dict[GuidPrefix, list[Submessage]] = {}
        # datagrams that beat their sender's discovery, taken at its peer_up (early.py)
        self._early = EarlyDatagrams()
        self._events: deque[DataPlaneEvent] = deque()
        self.counters: Counter[str] = Counter()
        # executed ids (member), outcomes seen and command SNs (commander): ledger.py
        self._ledger = CommandLedger(self.counters, executed_command_ids, executed_outcomes)
        self._readiness: dict[str, ReadinessStats] = {}
        self._next_command = 0
        # the high 32 bits of our command ids: this life's, never an earlier one's
        self._id_life = epoch if epoch else incarnation

    # --- discovery inputs -------------------------------------------------------------------

    def peer_up(self, name: str, locator: tuple[str, int], now: float, *, epoch: int) -> None:
        """Discovery found ``name`` (a bundle participant) in boot epoch ``epoch`` (from its
        authenticated SPDP): its matched endpoints become live, and user data for it goes to
        ``locator``, whatever the caller chose (the daemon: the host discovery heard it at,
        with the bundle's user port for it, ``Bundle.user_port``). Again for a known peer in
        the same epoch: only the locator moves. Back after ``peer_down`` in the same epoch
        (the same life: a link that came back): our writers resume its readers where they
        were, handing over what was written for them meanwhile and is still held, i.e. the
        commands still valid (docs/dataplane.md, "Rejoining while a command is valid"). In
        another epoch the peer restarted: its reliable state starts over (as for a new
        volatile reader), its replay window too, our datagrams are bound to the new epoch,
        and each still-held command it never acknowledged is voided for it
        (``CommandCopyVoided``: its echo dates it on the earlier life's clock). An epoch
        lower than one seen before is ignored (counted): it would let that earlier life's
        datagrams count again.

        A participant the key ring has no pair key for stays down (counted)."""
        peer = self.bundle.participant(name)
        if peer.name == self.local.name:
            raise ValueError(f"peer_up({name!r}) names this node itself")
        if not 0 <= epoch <= U32_MAX:
            raise ValueError(f"epoch {epoch} outside 0..{U32_MAX}")
        channel = self._channel(peer.guid_prefix, epoch)
        if channel is None:
            self.counters["peer_without_key"] += 1
            return
        if epoch < channel.peer_epoch:
            # Epochs only grow (swarmd.auth.epoch); an older one would re-open the replay
            # window to that life's captures. Discovery refuses such SPDP too: fail closed.
            self.counters["peer_epoch_went_back"] += 1
            return
        known = self._peers.get(name)
        if known is not None:
            if channel.peer_epoch == epoch:
                known.locator = locator
                return
            self.peer_down(name, now)
            self.counters["peer_restarts"] += 1
        same_life = channel.peer_epoch == epoch
        if not same_life:
            channel.peer_epoch = epoch
            channel.window = ReplayWindow()
        state = _Peer(peer, locator)
        self._peers[name] = state
        self._peer_by_prefix[peer.guid_prefix] = name
        for match in self.bundle.matches(self.local, peer):
            entity = match.local.entity_id
            if match.local_kind == EndpointKind.WRITER and entity in self._endpoints.writers:
                writer = self._endpoints.writers[entity][1]
                if not same_life:
                    self._void_copies(name, writer, writer.forget_reader(match.remote))
                self._queue(writer.add_reader(match.remote, now, resume=same_life))
            elif match.local_kind == EndpointKind.READER and entity in self._endpoints.readers:
                self._endpoints.readers[entity][1].add_writer(match.remote)
            else:
                continue
            state.matched.append((entity, match.remote))
        self._release_early(peer.guid_prefix, name, now)

    def _release_early(self, prefix: GuidPrefix, name: str, now: float) -> None:
        """Take what ``name`` sent before we had it up, within ``EARLY_HOLD_S`` (a member's
        report at its re-discovery of the commander, which reaches the commander before the
        member's own SPDP answer does: docs/dataplane.md, "Readiness after a blackout").
        Every check runs on it now, as on a datagram just received."""
        fresh, expired = self._early.release(prefix, now)
        for _, source in expired:
            self._drop("peer_not_up", source, f"{name}: held past {self._early.hold_s} s")
        for data, source in fresh:
            self.counters["early_taken"] += 1
            self._take(data, prefix, name, source, now)

    def _void_copies(self, name: str, writer: Writer, sns: list[int]) -> None:
        if writer is not self._endpoints.by_topic.get(TOPIC_COMMAND):
            return  # an outcome or another topic: the new life simply starts afresh
        for sn in sns:
            command_id = self._ledger.command_at(sn)
            if command_id is not None:
                self.counters["command_copies_voided"] += 1
                self._events.append(CommandCopyVoided(name, command_id))

    def peer_down(self, name: str, now: float) -> None:
        """Discovery lost ``name`` (lease expiry or dispose): its traffic stops and its
        proxies are unmatched (the writers keep their place for a return in the same life,
        ``peer_up``)."""
        state = self._peers.pop(name, None)
        if state is None:
            return
        self._peer_by_prefix.pop(state.participant.guid_prefix, None)
        self._pending.pop(state.participant.guid_prefix, None)
        for entity, remote in state.matched:
            if entity in self._endpoints.writers:
                self._endpoints.writers[entity][1].remove_reader(remote)
            else:
                self._endpoints.readers[entity][1].remove_writer(remote)

    @property
    def peers_up(self) -> list[str]:
        return sorted(self._peers)

    # --- application inputs -----------------------------------------------------------------

    def publish_readiness(self, sample: Readiness, now: float) -> int:
        """Publish this member's readiness (best effort, keep last 1). Returns the RTPS SN.

        ``sample.node`` must be this node; ``sample.seq`` is the caller's 1-based counter.
        """
        if sample.node != self.local.name:
            raise ValueError(f"readiness of {sample.node!r} published by {self.local.name!r}")
        return self._publish(TOPIC_READY, sample, now)

    def make_command(
        self,
        kind: CommandKind,
        *,
        altitude_m: float = 0.0,
        targets: Iterable[str] = (),
        valid_ms: int = 0,
        echoes: Iterable[TimeEcho] = (),
    ) -> Command:
        """A command with a fresh id: ``epoch << 32 | counter``, never reused: the boot
        epoch grows with every start even when the state file, and with it the boot counter
        (``incarnation``), is lost (``swarmd.auth.epoch``: the epoch file or the wall
        clock). Only with no epoch (0) the incarnation stands in.

        ``valid_ms`` and ``echoes`` date it for the members (``validity.py``); without them
        a member refuses it as expired. ``time_echoes`` gives the echoes."""
        if self._next_command >= U32_MAX:  # more would carry into the epoch's bits
            raise CommandIdsExhausted(f"all {U32_MAX} command ids of this life are used")
        self._next_command += 1
        command_id = (self._id_life << 32) | self._next_command
        return Command(command_id, kind, float(altitude_m), list(targets), valid_ms, list(echoes))

    def time_echoes(self, members: Iterable[str], now: float) -> list[TimeEcho]:
        """For a command issued ``now``: per member, the stamp of its last readiness report
        here and that report's age (docs/dataplane.md, "Validity"). Members never heard
        from, or not for ``validity.MAX_ECHO_AGE_MS``, get none (they will refuse)."""
        out: list[TimeEcho] = []
        for name in members:
            stats = self._readiness.get(name)
            if stats is None or stats.last is None:
                continue
            target = self._participants.get(name)
            channel = None if target is None else self._channels.get(target.guid_prefix)
            if channel is None or channel.peer_epoch != stats.epoch:
                # A report of the member's earlier life: its stamp is on a clock that may
                # have started again (a reboot), so it cannot date anything (fail closed).
                continue
            echo = echo_of(name, stats.last.stamp_ms, stats.last_rx, now, epoch=stats.epoch)
            if echo is not None:
                out.append(echo)
        return out

    def withdraw_command(self, sn: int) -> bool:
        """Stop (re)sending the command written as ``sn``: its validity ended, so repair
        must not carry it to a member late. Readers are told it is gone (GAP). True when
        it was still held."""
        writer = self._endpoints.by_topic.get(TOPIC_COMMAND)
        if not isinstance(writer, ReliableWriter):
            return False
        self._ledger.command_withdrawn(sn)
        return writer.withdraw(sn)

    def send_command(self, command: Command, now: float) -> int:
        """Send ``command`` reliably to its targets (commander only); empty targets: every
        member whose reader matches our command writer. Returns the one SN it is written as.

        Each target receives its own copy, naming only itself in ``targets`` and carrying
        only its own time echo (if any), so a command's size does not grow with the swarm:
        one sample, one SN, one command id, each copy under its own pair MAC
        (docs/dataplane.md, "One copy per member"). Matched members that are not targets
        are sent a GAP for the SN. Targets that are not bundle participants, or this node
        itself, are skipped (counted ``command_target_unknown``).

        Resending a command with the same id is safe: members execute an id once, and
        the resend carries the first send's dating (``dated``), so a member whose daemon
        restarted meanwhile refuses it (``memory_lost``) rather than run it again.

        Raises ``ForeignCommandId`` (nothing sent, no SN spent) for an id this life did
        not make (``make_command``) and has no dating of: an earlier life's id, which a
        fresh echo would re-date past both member rules (docs/security.md, "A re-dated
        id"), or one ahead of the counter.
        """
        writer = self._endpoints.by_topic.get(TOPIC_COMMAND)
        if writer is None:
            raise ValueError(f"{self.local.name!r} has no writer on {TOPIC_COMMAND!r}")
        if not self._made_here(command.command_id) and not self._ledger.has_dating(
            command.command_id
        ):
            self.counters["command_id_not_ours"] += 1
            raise ForeignCommandId(
                f"command id {command.command_id} is not of this life (epoch "
                f"{self._id_life}, ids up to {self._id_life << 32 | self._next_command}) "
                "and was never sent by it: issue a new command (make_command)"
            )
        command = self.dated(command)
        sn, out = writer.write(self._command_copies(command), now)
        self._queue(out)
        self._ledger.command_written(sn, command.command_id)
        return sn

    def dated(self, command: Command) -> Command:
        """``command`` with the dating it is sent with: its own the first time its id is
        sent, the first send's after (docs/dataplane.md, "A life runs only its own
        commands")."""
        return self._ledger.dated(command, self._made_here(command.command_id))

    def _made_here(self, command_id: int) -> bool:
        """Whether ``make_command`` of this life gave out ``command_id``."""
        return command_id >> 32 == self._id_life and 0 < command_id & 0xFFFF_FFFF <= (
            self._next_command
        )

    def _command_copies(self, command: Command) -> dict[GuidPrefix, bytes]:
        """One encoded copy of ``command`` per target (``ledger.command_copies``)."""
        names = list(command.targets) or self._command_readers()
        return command_copies(command, names, self._participants, self.local.name, self.counters)

    def _command_readers(self) -> list[str]:
        """Every bundle participant with a reader matching our command writer."""
        writer = self._endpoints.by_topic[TOPIC_COMMAND]
        entity = next(e for e, (_, w) in self._endpoints.writers.items() if w is writer)
        return [
            p.name
            for p in self.bundle.participants
            if p.name != self.local.name
            and any(m.local.entity_id == entity for m in self.bundle.matches(self.local, p))
        ]

    def report_outcome(
        self,
        command_id: int,
        result: CommandResult,
        now: float,
        reason: str = "",
        *,
        commander: str | None = None,
    ) -> int:
        """Tell the commander what this member did with ``command_id`` (reliable). With
        ``commander`` (whose command it is), the outcome goes to that commander only (its
        own copy; other readers are sent a GAP) and is kept next to the executed id, for
        ``executed_outcomes``: ids are unique per commander only, and an outcome names
        none, so another commander with the same id would take it as its own answer
        (docs/dataplane.md, "Exactly once" 4). Without, it goes to every reader."""
        reason = reason.encode("utf-8")[:MAX_REASON_CHARS].decode("utf-8", "ignore")
        outcome = CommandOutcome(command_id, self.local.name, result, reason)
        target = None if commander is None else self._participants.get(commander)
        if target is None:
            return self._publish(TOPIC_OUTCOME, outcome, now)
        self._ledger.decided(target.name, command_id, int(result.value), reason)
        return self._publish(TOPIC_OUTCOME, outcome, now, to=target.guid_prefix)

    @property
    def executed_command_ids(self) -> list[tuple[str, int]]:
        """The dedup set, oldest first; persist it to keep exactly-once across restarts."""
        return self._ledger.executed

    @property
    def executed_outcomes(self) -> list[KeptOutcome]:
        """What was decided for the executed ids (``report_outcome(commander=)``), oldest
        first; persist it with them so a restarted member can re-report it."""
        return self._ledger.outcomes

    def earlier_outcomes(self, commander: str, limit: int) -> list[KeptOutcome]:
        """The newest outcomes an earlier life of this node decided for ``commander``'s
        ids (restored at start-up), oldest first: at most ``limit``, and at most the
        outcome writer's history depth, so writing them all at once pushes none out of
        the history before it is acknowledged."""
        writer = self._endpoints.by_topic.get(TOPIC_OUTCOME)
        depth = writer.depth if isinstance(writer, ReliableWriter) else 1
        return self._ledger.earlier_outcomes(commander, min(limit, depth))

    def peer_epoch(self, name: str) -> int | None:
        """The boot epoch of ``name``'s life this node last authenticated (kept across
        ``peer_down``), None if never."""
        participant = self._participants.get(name)
        channel = None if participant is None else self._channels.get(participant.guid_prefix)
        return None if channel is None else channel.peer_epoch

    # --- network and timer inputs -----------------------------------------------------------

    def receive_datagram(self, data: bytes, source: tuple[str, int], now: float) -> None:
        """One UDP datagram from the user unicast socket. Never raises."""
        self.counters["rx_datagrams"] += 1
        try:
            header = decode_header(data)
        except DecodeError as exc:
            self._drop("decode_error", source, str(exc))
            return
        prefix = header.guid_prefix
        if prefix == self.prefix:
            self._drop("own", source)
            return
        peer_name = self._peer_by_prefix.get(prefix)
        if peer_name is None:
            known = self.bundle.by_prefix(prefix) is not None
            trailer = self._may_be_early(data) if known else None
            if trailer is not None:
                # Discovery may report it up in a moment: held if its tag holds, and still
                # checked in full at release (early.py)
                refused = self._may_hold(prefix, data, trailer.freshness)
                if refused is not None:
                    self._drop(refused[0], source, f"{prefix}: {refused[1]}, not held")
                    return
                self.counters["early_held"] += 1
                for _, src in self._early.hold(prefix, data, source, trailer.freshness, now):
                    self._drop("peer_not_up", src, f"{prefix}: held, not taken")
                return
            reason = "peer_not_up" if known else "unknown_participant"
            self._drop(reason, source, str(prefix))
            return
        self._take(data, prefix, peer_name, source, now)

    def _may_be_early(self, data: bytes) -> Trailer | None:
        """Cheap, stateless: the trailer of a datagram from a bundle participant that is
        not up if it is worth holding: no larger than we ever send, and sealed for this life
        of ours (a capture made for an earlier one can never pass, docs/security.md)."""
        if len(data) > MAX_DATAGRAM_BYTES:
            return None
        trailer = peek_trailer(data)
        if trailer is None or trailer.epoch_hint != self.epoch & EPOCH_HINT_MASK:
            return None
        return trailer

    def _may_hold(
        self, prefix: GuidPrefix, data: bytes, fresh: Freshness
    ) -> tuple[str, str] | None:
        """Whether a datagram of a participant not up may take a slot in the early hold:
        None if so, else (reason, detail). Cheapest first, as ``Channel.check``: an earlier
        life of the sender, or a freshness its replay window already took (a capture), then
        the tag for this life of ours (one HMAC). The sender's epoch cannot be checked yet
        (its SPDP has not been taken), and nothing moves here: the window moves at release,
        where every check runs again. Without this a forger cycled the hold's slots and
        pushed a genuine report out (docs/security-history.md, "Network paths end to end")."""
        channel = self._channels.get(prefix)
        if channel is not None and fresh.epoch <= channel.peer_epoch:
            if fresh.epoch < channel.peer_epoch:
                return "auth_stale_epoch", f"epoch {fresh.epoch}, known {channel.peer_epoch}"
            if not channel.window.is_fresh(fresh):
                return "auth_replayed", f"{fresh.epoch}/{fresh.seq}"
        key = self._user_data_key(prefix)
        if key is None or not verify(key, data, self.prefix, self.epoch):
            return "auth_failed", f"{fresh.epoch}/{fresh.seq}"
        return None

    def _take(
        self, data: bytes, prefix: GuidPrefix, peer_name: str, source: tuple[str, int], now: float
    ) -> None:
        """A datagram from ``peer_name``, up: verify it, then let it move state."""
        refused = self._channels[prefix].check(data, self.prefix, self.epoch)
        if refused is not None:
            self._drop(refused[0], source, f"{peer_name}: {refused[1]}")
            return
        self.counters["rx_authenticated"] += 1
        try:
            message = decode_message(protected_part(data))
        except DecodeError as exc:  # authentic but malformed: a bug on the sender's side
            self._drop("decode_error", source, str(exc))
            return
        for_us = True
        for sm in message.submessages:
            if isinstance(sm, InfoDst):
                for_us = sm.guid_prefix in (self.prefix, UNKNOWN_GUID_PREFIX)
            elif not isinstance(sm, Data | Heartbeat | AckNack | Gap):
                continue  # INFO_TS, and submessages the codec skips (DATA_FRAG, PAD, ...)
            elif not for_us:
                self._drop("not_for_us", source)
            elif isinstance(sm, AckNack):
                replies = self._endpoints.acknack(prefix, sm, now)
                if isinstance(replies, Refused):
                    self._drop(replies.reason, source, replies.detail)
                else:
                    self._queue(replies)
            else:
                self._on_reader_input(peer_name, prefix, sm, source, now)

    def handle_timer(self, now: float) -> None:
        """Send the heartbeats that are due."""
        self._queue(self._endpoints.on_timer(now))

    # --- outputs ----------------------------------------------------------------------------

    def datagrams_to_send(self) -> list[tuple[bytes, tuple[str, int]]]:
        """Everything queued, as ``(payload, (host, port))`` to the peers' unicast locators."""
        out: list[tuple[bytes, tuple[str, int]]] = []
        # No INFO_DST: the tag is bound to the receiver's prefix, which says more (wire.md).
        head = encode_header(Header(PROTOCOLVERSION_SWARMD, VENDORID_SWARMD, self.prefix))
        room = MAX_DATAGRAM_BYTES - TRAILER_BYTES
        for prefix, submessages in self._pending.items():
            name = self._peer_by_prefix.get(prefix)
            if name is None:
                continue
            locator = self._peers[name].locator
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
            channel = self._channels[prefix]
            for message in chunks:
                try:
                    freshness = channel.tx.next()
                except CounterExhausted:  # 2^32 - 1 datagrams to one peer in one epoch
                    self.counters["tx_counter_exhausted"] += 1
                    break
                sealed = seal(channel.key, message, freshness, prefix, channel.peer_epoch)
                out.append((sealed, locator))
        self._pending.clear()
        self.counters["tx_datagrams"] += len(out)
        return out

    def get_timer(self) -> float | None:
        """The earliest heartbeat deadline, on the caller's clock; None when all is acked."""
        return self._endpoints.deadline()

    def next_event(self) -> DataPlaneEvent | None:
        return self._events.popleft() if self._events else None

    def readiness_received(self, node: str) -> ReadinessStats | None:
        """What ``node`` has sent us on ``swarm/ready`` (a copy), None if nothing yet."""
        s = self._readiness.get(node)
        return None if s is None else ReadinessStats(s.count, s.last, s.last_rx, s.epoch)

    def status(self, now: float) -> dict[str, Any]:
        """A JSON-ready snapshot for ``swarmctl status``."""
        writers, readers = self._endpoints.status()
        return {
            "incarnation": self.incarnation,
            "epoch": self.epoch,
            "peers_up": self.peers_up,
            "peer_epochs": {
                name: self._channels[p.participant.guid_prefix].peer_epoch
                for name, p in sorted(self._peers.items())
            },
            "writers": writers,
            "readers": readers,
            # no per-member readiness here: the commander's table (status "readiness") is
            # the one place `swarmctl status --json` shows the count (ReadinessReceived.count)
            "executed_commands": len(self._ledger.executed),
            "early_holding": len(self._early),  # held now (counters: early_held, _taken)
            "counters": dict(sorted(self.counters.items())),
        }

    # --- internals --------------------------------------------------------------------------

    def _channel(self, prefix: GuidPrefix, epoch: int) -> Channel | None:
        """The authentication state with a bundle participant, made on first use."""
        channel = self._channels.get(prefix)
        if channel is None:
            key = self._user_data_key(prefix)
            if key is None:
                return None
            channel = Channel(key, SendCounter(self.epoch), epoch)
            self._channels[prefix] = channel
        return channel

    def _user_data_key(self, prefix: GuidPrefix) -> hmac.HMAC | None:
        """The prepared user-data MAC state with a bundle participant (its channel's once
        it has one), None without a pair key. At most one per bundle participant: only
        bundle prefixes reach here."""
        channel = self._channels.get(prefix)
        if channel is not None:
            return channel.key
        key = self._keys_prepared.get(prefix)
        if key is None:
            pair_key = self._keys.pair_key(prefix)
            if pair_key is None:
                return None
            key = self._keys_prepared[prefix] = user_data_key(pair_key)
        return key

    def _publish(self, topic: str, sample: Sample, now: float, to: GuidPrefix | None = None) -> int:
        """Write ``sample`` to every matched reader, or with ``to`` to that participant's
        only (the others are sent a GAP, as for a command's copies)."""
        writer = self._endpoints.by_topic.get(topic)
        if writer is None:
            raise ValueError(f"{self.local.name!r} has no writer on {topic!r} in the bundle")
        payload = encode_sample(sample)
        sn, out = writer.write(payload if to is None else {to: payload}, now)
        self._queue(out)
        return sn

    def _queue(self, out: list[Outgoing]) -> None:
        for item in out:
            self._pending.setdefault(item.peer, []).append(item.submessage)

    def _drop(self, reason: str, source: tuple[str, int] | None, detail: str = "") -> None:
        self.counters[f"dropped_{reason}"] += 1
        if len(self._events) < MAX_PENDING_EVENTS:
            self._events.append(PacketDropped(reason, source, detail))
        else:
            self.counters["events_overflow"] += 1

    def _on_reader_input(
        self,
        peer_name: str,
        prefix: GuidPrefix,
        sm: Data | Heartbeat | Gap,
        source: tuple[str, int],
        now: float,
    ) -> None:
        taken = self._endpoints.reader_input(prefix, sm)
        if isinstance(taken, Refused):
            self._drop(taken.reason, source, taken.detail)
            return
        topic, result = taken
        if result.dropped is not None:
            self.counters[result.dropped] += 1  # normal protocol noise, not an event
        self._queue(result.replies)
        for delivered in result.delivered:
            self._deliver(peer_name, topic, delivered, source, now)

    def _deliver(
        self,
        peer_name: str,
        topic: Topic,
        delivered: Delivered,
        source: tuple[str, int],
        now: float,
    ) -> None:
        if delivered.payload is None:
            self._drop("no_payload", source, f"{topic.name} sn {delivered.sn}")
            return
        cls = TYPES_BY_NAME[topic.type_name]
        try:
            sample = decode_sample(delivered.payload, cls)
        except PayloadError as exc:
            self._drop("bad_payload", source, f"{topic.name}: {exc}")
            return
        if isinstance(sample, Readiness):
            self._on_readiness(peer_name, sample, source, now)
        elif isinstance(sample, Command):
            self._on_command(peer_name, sample)
        else:
            self._on_outcome(peer_name, sample, source)

    def _on_readiness(
        self, peer_name: str, sample: Readiness, source: tuple[str, int], now: float
    ) -> None:
        if sample.node != peer_name:
            self._drop("node_mismatch", source, f"{peer_name} sent readiness of {sample.node}")
            return
        stats = self._readiness.setdefault(peer_name, ReadinessStats())
        stats.count += 1
        stats.last = sample
        stats.last_rx = now
        stats.epoch = self._channels[self._participants[peer_name].guid_prefix].peer_epoch
        self._events.append(ReadinessReceived(peer_name, sample, stats.count))

    def _on_command(self, commander: str, command: Command) -> None:
        if command.targets and self.local.name not in command.targets:
            self.counters["command_not_targeted"] += 1
            return
        if not self._ledger.first_run(commander, command.command_id):
            self.counters["command_duplicate"] += 1
            return
        self.counters["commands_received"] += 1
        self._events.append(CommandReceived(commander, command))

    def _on_outcome(self, peer_name: str, outcome: CommandOutcome, source: tuple[str, int]) -> None:
        if outcome.node != peer_name:
            self._drop("node_mismatch", source, f"{peer_name} sent outcome of {outcome.node}")
            return
        epoch = self._channels[self._participants[peer_name].guid_prefix].peer_epoch
        if not self._ledger.new_outcome(
            peer_name, epoch, outcome.command_id, int(outcome.result.value)
        ):
            self.counters["outcome_duplicate"] += 1
            return
        self._events.append(OutcomeReceived(peer_name, outcome, epoch))
