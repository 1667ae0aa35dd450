"""What verified peers sent the data plane: each delivered sample decoded and taken once.

A sample reaches here only after its datagram passed authentication (``pairs.py``) and
its reader delivered it (``reader.py``). Readiness is kept per member (how many, the
latest, when, in which of the member's lives): the commander dates a command with it
(``time_echoes``; docs/dataplane.md, "Validity"). A command is handed on once per
``(commander, id)`` and an outcome once per ``(node, epoch, id, result, flags, save_gen)``,
of its flags only those this build reads (``OUTCOME_KNOWN_FLAGS``; ``ledger.py``), its
``save_gen`` only with one of them (a mark told again after a clear is news).
A sample naming another node than its sender is refused (``node_mismatch``).

Split out of ``plane.py`` by concern: the plane keeps the peers' sessions and the wire.
Sans-IO; no clock.
"""

from __future__ import annotations

from collections import Counter, deque
from collections.abc import Iterable, Mapping
from dataclasses import dataclass

from swarmd.bundle.model import Participant, Topic
from swarmd.dataplane.events import (
    CommandReceived,
    DataPlaneEvent,
    OutcomeReceived,
    ReadinessReceived,
)
from swarmd.dataplane.ledger import CommandLedger
from swarmd.dataplane.pairs import PairChannels
from swarmd.dataplane.reader import Delivered
from swarmd.dataplane.types import (
    OUTCOME_KNOWN_FLAGS,
    TYPES_BY_NAME,
    Command,
    CommandOutcome,
    PayloadError,
    Readiness,
    TimeEcho,
    decode_sample,
)
from swarmd.dataplane.validity import echo_of

__all__ = ["ReadinessStats", "Received"]


@dataclass(slots=True)
class ReadinessStats:
    """Readiness samples received from one member: how many, the latest, when (``now``)."""

    count: int = 0
    last: Readiness | None = None
    last_rx: float = 0.0
    epoch: int = 0  # the member's boot epoch when ``last`` arrived: its clock's life


class Received:
    """The samples verified peers delivered; events go to the plane's queue (``events``)."""

    __slots__ = (
        "_counters",
        "_events",
        "_ledger",
        "_local_name",
        "_pairs",
        "_participants",
        "readiness",
    )

    def __init__(
        self,
        local_name: str,
        participants: Mapping[str, Participant],
        pairs: PairChannels,
        ledger: CommandLedger,
        counters: Counter[str],
        events: deque[DataPlaneEvent],
    ) -> None:
        self._local_name = local_name
        self._participants = participants
        self._pairs = pairs
        self._ledger = ledger
        self._counters = counters
        self._events = events
        self.readiness: dict[str, ReadinessStats] = {}  # bounded: bundle names only

    def deliver(
        self, peer_name: str, topic: Topic, delivered: Delivered, now: float
    ) -> tuple[str, str] | None:
        """Take one delivered sample of ``peer_name`` (up and verified): None when taken
        or quietly ignored (counted), else the (reason, detail) to drop it for."""
        if delivered.payload is None:
            return "no_payload", f"{topic.name} sn {delivered.sn}"
        cls = TYPES_BY_NAME[topic.type_name]
        try:
            sample = decode_sample(delivered.payload, cls)
        except PayloadError as exc:
            return "bad_payload", f"{topic.name}: {exc}"
        if isinstance(sample, Readiness):
            return self._readiness(peer_name, sample, now)
        if isinstance(sample, Command):
            self._command(peer_name, sample)
            return None
        return self._outcome(peer_name, sample)

    def stats(self, node: str) -> ReadinessStats | None:
        """What ``node`` has sent us on ``swarm/ready`` (a copy), None if nothing yet."""
        s = self.readiness.get(node)
        return None if s is None else ReadinessStats(s.count, s.last, s.last_rx, s.epoch)

    def time_echoes(self, members: Iterable[str], now: float) -> list[TimeEcho]:
        """Per member, the echo of its last readiness report (``DataPlane.time_echoes``)."""
        out: list[TimeEcho] = []
        for name in members:
            stats = self.readiness.get(name)
            if stats is None or stats.last is None:
                continue
            target = self._participants.get(name)
            epoch = None if target is None else self._pairs.peer_epoch(target.guid_prefix)
            if epoch != stats.epoch:
                # A report of the member's earlier life: its stamp is on a clock that may
                # have started again (a reboot), so it cannot date anything (fail closed).
                continue
            echo = echo_of(name, stats.last.stamp_ms, stats.last_rx, now, epoch=stats.epoch)
            if echo is not None:
                out.append(echo)
        return out

    def _readiness(self, peer_name: str, sample: Readiness, now: float) -> tuple[str, str] | None:
        if sample.node != peer_name:
            return "node_mismatch", f"{peer_name} sent readiness of {sample.node}"
        stats = self.readiness.setdefault(peer_name, ReadinessStats())
        stats.count += 1
        stats.last = sample
        stats.last_rx = now
        stats.epoch = self._pairs.channels[self._participants[peer_name].guid_prefix].peer_epoch
        self._events.append(ReadinessReceived(peer_name, sample, stats.count))
        return None

    def _command(self, commander: str, command: Command) -> None:
        if command.targets and self._local_name not in command.targets:
            self._counters["command_not_targeted"] += 1
            return
        if not self._ledger.first_run(commander, command.command_id):
            self._counters["command_duplicate"] += 1
            return
        self._counters["commands_received"] += 1
        self._events.append(CommandReceived(commander, command))

    def _outcome(self, peer_name: str, outcome: CommandOutcome) -> tuple[str, str] | None:
        if outcome.node != peer_name:
            return "node_mismatch", f"{peer_name} sent outcome of {outcome.node}"
        epoch = self._pairs.channels[self._participants[peer_name].guid_prefix].peer_epoch
        # only the flags this build reads: reserved bits are ignored on receipt, here too
        flags = outcome.flags & OUTCOME_KNOWN_FLAGS
        gen = outcome.save_gen if flags else 0
        if not self._ledger.new_outcome(
            peer_name, epoch, outcome.command_id, int(outcome.result.value), flags, gen
        ):
            self._counters["outcome_duplicate"] += 1
            return None
        self._events.append(OutcomeReceived(peer_name, outcome, epoch))
        return None
