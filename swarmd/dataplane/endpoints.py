"""The local RTPS endpoints of one node: the writers and readers its bundle preloads, and
the routing of an authenticated submessage to the one it addresses.

Sans-IO and clock-free (``now`` comes in). Split out of ``plane.py`` by concern: the plane
keeps the peers, authentication, the datagrams and the application's calls; this module
keeps which endpoint exists (one per bundle endpoint whose topic's type the data plane
carries, chosen by the topic's QoS: ``writer.py``, ``reader.py``) and what reaches it. A
submessage arrives here only after its datagram passed every check of ``Channel.check``
(docs/security.md), from a peer that is up; what is refused here is counted and reported
by the plane (``Refused``), never raised.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Final

from swarmd.bundle.model import Bundle, Durability, EndpointKind, Participant, Reliability, Topic
from swarmd.dataplane.outgoing import Outgoing
from swarmd.dataplane.reader import BestEffortReader, ReaderResult, ReliableReader
from swarmd.dataplane.types import TYPES_BY_NAME
from swarmd.dataplane.writer import (
    MAX_HISTORY_DEPTH,
    BestEffortWriter,
    ReliableWriter,
    first_sequence_number,
)
from swarmd.rtps.message import AckNack, Data, Gap, Heartbeat
from swarmd.rtps.types import ENTITYID_UNKNOWN, EntityId, Guid, GuidPrefix

TOPIC_READY: Final = "swarm/ready"
TOPIC_COMMAND: Final = "swarm/command"
TOPIC_OUTCOME: Final = "swarm/outcome"
# The type each well-known topic must declare in the bundle.
TOPIC_TYPES: Final = {
    TOPIC_READY: "swarmd::Readiness",
    TOPIC_COMMAND: "swarmd::Command",
    TOPIC_OUTCOME: "swarmd::CommandOutcome",
}

# Highest SN accepted from the wire. A reader's ACKNACK base is one above the last SN it
# delivered and must still fit SequenceNumber_t (int32 high word, spec 9.3.2); a writer's
# incarnation scheme stays far below (writer.MAX_INCARNATION << 32).
MAX_SEQUENCE_NUMBER: Final = (1 << 63) - (1 << 32)

Writer = BestEffortWriter | ReliableWriter
Reader = BestEffortReader | ReliableReader


@dataclass(frozen=True, slots=True)
class Refused:
    """A submessage no local endpoint takes: the plane's drop ``reason`` and its detail."""

    reason: str
    detail: str


class Endpoints:
    """The writers and readers of ``local`` in ``bundle``, by entity id and by topic."""

    __slots__ = ("by_topic", "readers", "writers")

    def __init__(self, bundle: Bundle, local: Participant, incarnation: int) -> None:
        """A topic that names a well-known one with another type stops start-up (the
        mission's topics are wrong); a topic whose type the plane does not carry (e.g.
        ``swarm/position``) gets no endpoint."""
        self.writers: dict[EntityId, tuple[Topic, Writer]] = {}
        self.readers: dict[EntityId, tuple[Topic, Reader]] = {}
        self.by_topic: dict[str, Writer] = {}
        for endpoint in local.endpoints:
            topic = bundle.topic(endpoint.topic)
            expected = TOPIC_TYPES.get(topic.name)
            if expected is not None and topic.type_name != expected:
                raise ValueError(
                    f"bundle topic {topic.name!r} declares type {topic.type_name!r}; "
                    f"swarmd's data plane carries {expected!r} on it: fix the mission's topics"
                )
            if topic.type_name not in TYPES_BY_NAME:
                continue  # a topic the data plane does not carry (e.g. swarm/position)
            guid = local.guid(endpoint)
            if endpoint.kind == EndpointKind.WRITER:
                writer = _make_writer(guid, topic, incarnation)
                self.writers[guid.entity_id] = (topic, writer)
                self.by_topic[topic.name] = writer
            else:
                self.readers[guid.entity_id] = (topic, _make_reader(guid, topic))

    def acknack(self, prefix: GuidPrefix, ack: AckNack, now: float) -> list[Outgoing] | Refused:
        """An ACKNACK from participant ``prefix`` to one of our writers: its repairs."""
        entry = self.writers.get(ack.writer_id)
        remote = Guid(prefix, ack.reader_id)
        if entry is None or not entry[1].matched(remote):
            return Refused("unmatched_acknack", f"{remote} -> {ack.writer_id}")
        return entry[1].on_acknack(remote, ack, now)

    def reader_input(
        self, prefix: GuidPrefix, sm: Data | Heartbeat | Gap
    ) -> tuple[Topic, ReaderResult] | Refused:
        """A DATA, HEARTBEAT or GAP from participant ``prefix`` to one of our readers (or
        to every matched one, ``ENTITYID_UNKNOWN``), its SNs checked before the reader
        sees them."""
        remote = Guid(prefix, sm.writer_id)
        entry = self.find_reader(sm.reader_id, remote)
        if entry is None:
            return Refused("unmatched_writer", f"{remote} -> {sm.reader_id}")
        topic, reader = entry
        if isinstance(sm, Data):
            if not 1 <= sm.writer_sn <= MAX_SEQUENCE_NUMBER:
                return Refused("invalid_sn", str(sm.writer_sn))
            return topic, reader.on_data(remote, sm)
        if isinstance(sm, Heartbeat):
            # spec 8.3.7.5: firstSN >= 1, lastSN >= firstSN - 1
            if not 1 <= sm.first_sn <= sm.last_sn + 1 <= MAX_SEQUENCE_NUMBER + 1:
                return Refused("invalid_sn", f"HEARTBEAT [{sm.first_sn}, {sm.last_sn}]")
            return topic, reader.on_heartbeat(remote, sm)
        if not 1 <= sm.gap_start <= sm.gap_list.base <= MAX_SEQUENCE_NUMBER:
            return Refused("invalid_sn", f"GAP {sm.gap_start} {sm.gap_list.base}")
        return topic, reader.on_gap(remote, sm)

    def may_answer(self, reader_id: EntityId, remote: Guid, now: float) -> bool:
        """Whether our reader ``reader_id`` may send writer ``remote`` the ACKNACK it made
        (its answer budget, ``ReliableReader.may_answer``)."""
        entry = self.find_reader(reader_id, remote)
        return entry is not None and entry[1].may_answer(remote, now)

    def find_reader(self, reader_id: EntityId, remote: Guid) -> tuple[Topic, Reader] | None:
        """Our reader ``reader_id`` if it is matched with writer ``remote``."""
        if reader_id == ENTITYID_UNKNOWN:  # spec 8.4.15.3: to every matched reader of it
            for entry in self.readers.values():
                if entry[1].matched(remote):
                    return entry
            return None
        found = self.readers.get(reader_id)
        if found is None or not found[1].matched(remote):
            return None
        return found

    def on_timer(self, now: float) -> list[Outgoing]:
        """The heartbeats that are due, writer by writer."""
        out: list[Outgoing] = []
        for _, writer in self.writers.values():
            out.extend(writer.on_timer(now))
        return out

    def deadline(self) -> float | None:
        """The earliest heartbeat deadline; None when all is acked."""
        deadlines = [d for _, w in self.writers.values() if (d := w.deadline()) is not None]
        return min(deadlines) if deadlines else None

    def status(self) -> tuple[dict[str, Any], dict[str, Any]]:
        """JSON-ready writer and reader rows, by topic name."""
        writers = {t.name: _writer_status(w) for t, w in self.writers.values()}
        readers = {t.name: _fields_of(r.counters) for t, r in self.readers.values()}
        return writers, readers


def _make_writer(guid: Guid, topic: Topic, incarnation: int) -> Writer:
    if topic.qos.reliability == Reliability.RELIABLE:
        return ReliableWriter(
            guid,
            depth=min(max(topic.qos.history_depth, 1), MAX_HISTORY_DEPTH),
            transient_local=topic.qos.durability == Durability.TRANSIENT_LOCAL,
            incarnation=incarnation,
        )
    return BestEffortWriter(guid, next_sn=first_sequence_number(incarnation))


def _make_reader(guid: Guid, topic: Topic) -> Reader:
    if topic.qos.reliability == Reliability.RELIABLE:
        return ReliableReader(guid)
    return BestEffortReader(guid)


def _fields_of(obj: Any) -> dict[str, Any]:
    """The fields of a slotted counters dataclass as a dict."""
    return {name: getattr(obj, name) for name in obj.__slots__}


def _writer_status(writer: Writer) -> dict[str, Any]:
    out: dict[str, Any] = {"last_sn": writer.last_sn, **_fields_of(writer.counters)}
    if isinstance(writer, ReliableWriter):
        out["unacked_readers"] = sum(1 for p in writer.proxies.values() if p.acked < writer.last_sn)
    return out
