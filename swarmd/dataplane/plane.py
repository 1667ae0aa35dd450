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

Authentication (issue 10, ``pairs.py``, docs/security.md). Every datagram to a peer is
sealed under the pair key with this node's freshness; a datagram from a peer is verified
before it can move anything (reader positions, acknowledged sets, readiness rows, dedup
sets): its GUID prefix must be a bundle participant discovery reported up, then the
channel's checks, cheapest first, then the tag (``PairChannels``); only then is it decoded
and each submessage must address a matched endpoint pair.

This module is the one class an owner drives and the wire in and out; each concern's state
lives in its own module: ``sessions.py`` (who is up, in which epoch, at which locator, what
is queued for each), ``pairs.py`` (keys, send counters, replay windows), ``received.py``
(the samples verified peers delivered), ``commands.py`` (command ids, dating, copies),
``ledger.py`` (executed ids, outcomes seen, command SNs), ``endpoints.py`` (writers and
readers), ``early.py`` (datagrams ahead of discovery).

Commands go out as one sample (one SN, one command id) with one copy per target, each
naming only that member and carrying only its time echo, so a command's size does not grow
with the swarm (``send_command``; ``commands.py``: ids, dating, copies, withdrawal).

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

from collections import Counter, deque
from collections.abc import Iterable
from typing import Any, Final

from swarmd.auth.freshness import U32_MAX
from swarmd.bundle.model import Bundle, Participant
from swarmd.dataplane.channel import Channel
from swarmd.dataplane.commands import CommandIdsExhausted, Commands, ForeignCommandId
from swarmd.dataplane.early import EarlyDatagrams
from swarmd.dataplane.endpoints import (
    TOPIC_OUTCOME,
    TOPIC_READY,
    Endpoints,
    Refused,
)
from swarmd.dataplane.events import (
    DataPlaneEvent,
    PacketDropped,
)
from swarmd.dataplane.ledger import CommandLedger, KeptOutcome
from swarmd.dataplane.outgoing import Outgoing
from swarmd.dataplane.pairs import PairChannels, PairKeys
from swarmd.dataplane.received import ReadinessStats, Received
from swarmd.dataplane.seal import TRAILER_BYTES, protected_part
from swarmd.dataplane.sessions import Sessions
from swarmd.dataplane.types import (
    MAX_REASON_CHARS,
    Command,
    CommandKind,
    CommandOutcome,
    CommandResult,
    Readiness,
    Sample,
    TimeEcho,
    encode_sample,
)
from swarmd.dataplane.writer import MAX_INCARNATION, ReliableWriter
from swarmd.rtps.errors import DecodeError
from swarmd.rtps.message import (
    AckNack,
    Data,
    Gap,
    Header,
    Heartbeat,
    InfoDst,
    decode_header,
    decode_message,
    encode_header,
)
from swarmd.rtps.types import (
    PROTOCOLVERSION_SWARMD,
    UNKNOWN_GUID_PREFIX,
    VENDORID_SWARMD,
    EntityId,
    Guid,
    GuidPrefix,
)

# the plane's public names, some defined by the modules split out of it
__all__ = [
    "MAX_DATAGRAM_BYTES",
    "MAX_PENDING_EVENTS",
    "CommandIdsExhausted",
    "DataPlane",
    "ForeignCommandId",
    "PairKeys",
    "ReadinessStats",
]

# Stay under a Wi-Fi MTU (1500 - IPv4 20 - UDP 8) with margin: never IP-fragment user data.
MAX_DATAGRAM_BYTES: Final = 1400
# Undrained events kept; past it drop reports are counted, not queued (samples always are).
MAX_PENDING_EVENTS: Final = 4096


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
        # keys, send counters and replay windows per bundle participant (pairs.py)
        self._pairs = PairChannels(keys, self.prefix, epoch)
        # our writers and readers, and what reaches them (endpoints.py)
        self._endpoints = Endpoints(bundle, self.local, incarnation)
        self._participants: dict[str, Participant] = {p.name: p for p in bundle.participants}
        # datagrams that beat their sender's discovery, taken at its peer_up (early.py)
        self._early = EarlyDatagrams()
        self._events: deque[DataPlaneEvent] = deque()
        self.counters: Counter[str] = Counter()
        # executed ids (member), outcomes seen and command SNs (commander): ledger.py
        self._ledger = CommandLedger(self.counters, executed_command_ids, executed_outcomes)
        # who is up, in which epoch, at which locator, and what is queued (sessions.py)
        self._sessions = Sessions(
            bundle,
            self.local,
            self._endpoints,
            self._pairs,
            self._ledger,
            self.counters,
            self._events,
        )
        # what we queue for a peer (a bound method: one call less on the receive path)
        self._queue = self._sessions.queue
        # what verified peers delivered: readiness per member, new commands and outcomes
        self._received = Received(
            self.local.name,
            self._participants,
            self._pairs,
            self._ledger,
            self.counters,
            self._events,
        )
        # this life's command ids, their dating and copies (commands.py)
        self._commands = Commands(
            bundle,
            self.local,
            self._endpoints,
            self._ledger,
            self.counters,
            life=epoch if epoch else incarnation,
        )

    @property
    def _channels(self) -> dict[GuidPrefix, Channel]:
        """The pair channels by participant prefix (``PairChannels.channels``)."""
        return self._pairs.channels

    @property
    def _readiness(self) -> dict[str, ReadinessStats]:
        """Readiness received per member (``Received.readiness``)."""
        return self._received.readiness

    @property
    def _next_command(self) -> int:
        """The counter of this life's last command id (``Commands.issued``)."""
        return self._commands.issued

    @_next_command.setter
    def _next_command(self, issued: int) -> None:  # tests start it near its end
        self._commands.issued = issued

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
        prefix = self._sessions.up(name, locator, now, epoch)
        if prefix is not None:
            self._release_early(prefix, name, now)

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

    def peer_down(self, name: str, now: float) -> None:
        """Discovery lost ``name`` (lease expiry or dispose): its traffic stops and its
        proxies are unmatched (the writers keep their place for a return in the same life,
        ``peer_up``)."""
        self._sessions.down(name)

    @property
    def peers_up(self) -> list[str]:
        return sorted(self._sessions.by_name)

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
        return self._commands.make(kind, altitude_m, targets, valid_ms, echoes)

    def time_echoes(self, members: Iterable[str], now: float) -> list[TimeEcho]:
        """For a command issued ``now``: per member, the stamp of its last readiness report
        here and that report's age (docs/dataplane.md, "Validity"). Members never heard
        from, or not for ``validity.MAX_ECHO_AGE_MS``, get none (they will refuse)."""
        return self._received.time_echoes(members, now)

    def withdraw_command(self, sn: int) -> bool:
        """Stop (re)sending the command written as ``sn``: its validity ended, so repair
        must not carry it to a member late. Readers are told it is gone (GAP). True when
        it was still held."""
        return self._commands.withdraw(sn)

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
        sn, out = self._commands.write(command, now)
        self._queue(out)
        return sn

    def dated(self, command: Command) -> Command:
        """``command`` with the dating it is sent with: its own the first time its id is
        sent, the first send's after (docs/dataplane.md, "A life runs only its own
        commands")."""
        return self._commands.dated(command)

    def report_outcome(
        self,
        command_id: int,
        result: CommandResult,
        now: float,
        reason: str = "",
        *,
        commander: str | None = None,
        flags: int = 0,
        save_gen: int = 0,
    ) -> int:
        """Tell the commander what this member did with ``command_id`` (reliable). With
        ``commander`` (whose command it is), the outcome goes to that commander only (its
        own copy; other readers are sent a GAP) and is kept next to the executed id, for
        ``executed_outcomes``: ids are unique per commander only, and an outcome names
        none, so another commander with the same id would take it as its own answer
        (docs/dataplane.md, "Exactly once" 4). Without, it goes to every reader.
        ``flags``: ``OUTCOME_NOT_SAVED`` when this node could not write its record of the
        decision, ``OUTCOME_NOW_SAVED`` when a later write held it; ``save_gen``: this
        node's state-file writes answered so far, which orders the two at the commander
        (docs/dataplane.md, "A failed save")."""
        reason = reason.encode("utf-8")[:MAX_REASON_CHARS].decode("utf-8", "ignore")
        outcome = CommandOutcome(command_id, self.local.name, result, reason, flags, save_gen)
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
        return None if participant is None else self._pairs.peer_epoch(participant.guid_prefix)

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
        peer_name = self._sessions.by_prefix.get(prefix)
        if peer_name is None:
            known = self.bundle.by_prefix(prefix) is not None
            # no larger than we ever send, and sealed for this life of ours (pairs.py)
            small = known and len(data) <= MAX_DATAGRAM_BYTES
            trailer = self._pairs.early_trailer(data) if small else None
            if trailer is not None:
                # Discovery may report it up in a moment: held if its tag holds, and still
                # checked in full at release (early.py)
                refused = self._pairs.may_hold(prefix, data, trailer.freshness)
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

    def _take(
        self, data: bytes, prefix: GuidPrefix, peer_name: str, source: tuple[str, int], now: float
    ) -> None:
        """A datagram from ``peer_name``, up: verify it, then let it move state."""
        refused = self._pairs.channels[prefix].check(data, self.prefix, self.epoch)
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
        # our readers' ACKNACKs to this datagram, the last per (reader, writer): a later one
        # says all an earlier one would (its base and bitmap are the newer state), so one
        # datagram of many HEARTBEATs draws one answer each, not one per HEARTBEAT (review
        # 16: a captured member's 1,000 drew 41 datagrams to its signed locator)
        acks: dict[tuple[EntityId, EntityId], tuple[AckNack, Outgoing]] = {}
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
                for reply in self._on_reader_input(peer_name, prefix, sm, source, now):
                    out = reply.submessage
                    if isinstance(out, AckNack):
                        acks[(out.reader_id, out.writer_id)] = (out, reply)
                    else:
                        self._queue([reply])
        for ack, reply in acks.values():
            # past the writer's answer rate (counted by the reader), the next HEARTBEAT's
            # answer will say it
            if self._endpoints.may_answer(ack.reader_id, Guid(prefix, ack.writer_id), now):
                self._queue([reply])

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
        for prefix, locator, chunks in self._sessions.frames(head, room):
            sealed, exhausted = self._pairs.seal(prefix, chunks)
            out += [(datagram, locator) for datagram in sealed]
            if exhausted:  # 2^32 - 1 datagrams to one peer in one epoch
                self.counters["tx_counter_exhausted"] += 1
        self.counters["tx_datagrams"] += len(out)
        return out

    def get_timer(self) -> float | None:
        """The earliest heartbeat deadline, on the caller's clock; None when all is acked."""
        return self._endpoints.deadline()

    def next_event(self) -> DataPlaneEvent | None:
        return self._events.popleft() if self._events else None

    def readiness_received(self, node: str) -> ReadinessStats | None:
        """What ``node`` has sent us on ``swarm/ready`` (a copy), None if nothing yet."""
        return self._received.stats(node)

    def status(self, now: float) -> dict[str, Any]:
        """A JSON-ready snapshot for ``swarmctl status``."""
        writers, readers = self._endpoints.status()
        return {
            "incarnation": self.incarnation,
            "epoch": self.epoch,
            "peers_up": self.peers_up,
            "peer_epochs": {
                name: self._pairs.channels[p.participant.guid_prefix].peer_epoch
                for name, p in sorted(self._sessions.by_name.items())
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
    ) -> list[Outgoing]:
        """Hand ``sm`` to the reader it addresses; its replies, for the caller to queue."""
        taken = self._endpoints.reader_input(prefix, sm)
        if isinstance(taken, Refused):
            self._drop(taken.reason, source, taken.detail)
            return []
        topic, result = taken
        if result.dropped is not None:
            self.counters[result.dropped] += 1  # normal protocol noise, not an event
        for delivered in result.delivered:
            refused = self._received.deliver(peer_name, topic, delivered, now)
            if refused is not None:
                self._drop(refused[0], source, refused[1])
        return result.replies
