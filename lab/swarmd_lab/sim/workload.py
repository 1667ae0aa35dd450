"""The paper's 1 Hz workload (section 5.1): every member publishes one message per second
to the commander (participant 0) on ``swarm/ready``, best effort.

A member's publisher starts with the drone and numbers its samples from 1 every second;
a sample leaves only while the member has discovered the commander (DDS sends to matched
readers only), and counts as received only while the commander has discovered the member
(a reader drops DATA from writers it has not matched). The paper's success criterion is
"the commander receives the 20th 1 Hz message of every member" (design notes, Measuring).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Final

from swarmd.rtps.message import Data, Header, InfoTs, encode_message
from swarmd.rtps.types import (
    VENDORID_SWARMD,
    EntityId,
    EntityKind,
    GuidPrefix,
    ProtocolVersion,
    Time,
)
from swarmd_lab.sim.channel import Datagram, Kind
from swarmd_lab.sim.clock import VirtualClock
from swarmd_lab.sim.node import Ledger

COMMANDER: Final = 0
PERIOD_S: Final = 1.0
TARGET_SEQ: Final = 20
# a Readiness sample in XCDR1 (node name, seq, flags, empty reason, link Q): ~48 bytes
READINESS_PAYLOAD_BYTES: Final = 48


def data_datagram_size() -> int:
    """UDP payload of one 1 Hz sample: RTPS header + INFO_TS + DATA, encoded for real."""
    header = Header(ProtocolVersion(2, 3), VENDORID_SWARMD, GuidPrefix(bytes(12)))
    data = Data(
        EntityId.user(1, EntityKind.READER_NO_KEY),
        EntityId.user(1, EntityKind.WRITER_NO_KEY),
        1,
        serialized_payload=b"\x00\x01\x00\x00" + bytes(READINESS_PAYLOAD_BYTES),
    )
    return len(encode_message(header, [InfoTs(Time(0, 0)), data]))


class Workload:
    """Publishes the members' 1 Hz samples and tallies what the commander receives."""

    def __init__(
        self,
        clock: VirtualClock,
        ledger: Ledger,
        send: Callable[[Datagram], None],
        n: int,
        *,
        extra_bytes: int = 0,
    ) -> None:
        """``extra_bytes`` is added to every sample's datagram: the data plane's
        authentication (``swarmd.dataplane.seal.NET_OVERHEAD_BYTES``) for swarmd-auth."""
        self._clock = clock
        self._ledger = ledger
        self._send = send
        self.n = n
        self.size = data_datagram_size() + extra_bytes
        self.sent = 0
        self.received = 0
        self.got_target = [False] * n
        self._seq = [0] * n

    def start_member(self, member: int, now: float) -> None:
        if member == COMMANDER:
            return
        self._clock.call_at(now + PERIOD_S, lambda: self._publish(member))

    def _publish(self, member: int) -> None:
        now = self._clock.now
        self._seq[member] += 1
        seq = self._seq[member]
        if self._ledger.known[member][COMMANDER]:
            self.sent += 1
            self._send(Datagram(member, COMMANDER, self.size, Kind.DATA, (member, seq)))
        self._clock.call_at(now + PERIOD_S, lambda: self._publish(member))

    def receive(self, receiver: int, dgram: Datagram, now: float) -> None:
        payload = dgram.payload
        assert isinstance(payload, tuple)  # noqa: S101 - the workload's own (member, seq)
        member, seq = int(payload[0]), int(payload[1])
        if receiver != COMMANDER or not self._ledger.known[COMMANDER][member]:
            return
        self.received += 1
        if seq == TARGET_SEQ:
            self.got_target[member] = True

    def delivery_success(self) -> float:
        """Fraction of members whose 20th sample reached the commander."""
        members = self.n - 1
        if members == 0:
            return 1.0
        return sum(self.got_target[1:]) / members
