"""Who a node is in its swarm, read from the bundle: what it writes and what it reads.

Roles come from the bundle, not from a flag: a node with a writer on ``swarm/command`` is a
commander, one with a writer on ``swarm/ready`` reports readiness; the commander's readiness
table has a row for every other node that writes ``swarm/ready`` when the commander reads it,
and its commands reach every other node that reads ``swarm/command``.
"""

from __future__ import annotations

from dataclasses import dataclass

from swarmd.bundle.model import Bundle, EndpointKind, Participant
from swarmd.dataplane import TOPIC_COMMAND, TOPIC_READY


def writes(p: Participant, topic: str) -> bool:
    return any(e.topic == topic and e.kind == EndpointKind.WRITER for e in p.endpoints)


def reads(p: Participant, topic: str) -> bool:
    return any(e.topic == topic and e.kind == EndpointKind.READER for e in p.endpoints)


@dataclass(frozen=True, slots=True)
class Roles:
    swarm: str
    me: str
    is_commander: bool
    reports_readiness: bool
    members: tuple[str, ...]  # the nodes whose readiness this node keeps a row for
    targets_remote: tuple[str, ...]  # the other nodes this node's commands can reach

    @classmethod
    def of(cls, bundle: Bundle, me: Participant) -> Roles:
        others = [p for p in bundle.participants if p.name != me.name]
        return cls(
            swarm=bundle.swarm,
            me=me.name,
            is_commander=writes(me, TOPIC_COMMAND),
            reports_readiness=writes(me, TOPIC_READY),
            members=tuple(
                p.name for p in others if writes(p, TOPIC_READY) and reads(me, TOPIC_READY)
            ),
            targets_remote=tuple(p.name for p in others if reads(p, TOPIC_COMMAND)),
        )

    @property
    def role(self) -> str:
        return "commander" if self.is_commander else "member"
