"""Baseline models on a lossless, instantaneous channel: frame counts follow their timing."""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable

import pytest
from swarmd_lab.sim.channel import MULTICAST, Datagram
from swarmd_lab.sim.clock import VirtualClock
from swarmd_lab.sim.dds_model import CYCLONE, FASTDDS, DdsNode, DdsTiming
from swarmd_lab.sim.node import Ledger, NodeContext, SimNode
from swarmd_lab.sim.zenoh_model import ZenohNode

WINDOW = 60.0


LATENCY_S = 0.001


class Lossless:
    """Delivers every datagram after 1 ms to its destination (multicast: to everyone else)."""

    def __init__(self, n: int) -> None:
        self.clock = VirtualClock()
        self.ledger = Ledger(n)
        self.nodes: list[SimNode] = []
        self.sent: Counter[tuple[int, str, bool]] = Counter()

    def send(self, d: Datagram) -> None:
        assert isinstance(d.payload, tuple)
        self.sent[(d.src, str(d.payload[0]), d.dst == MULTICAST)] += 1
        targets = (
            [j for j in range(len(self.nodes)) if j != d.src] if d.dst == MULTICAST else [d.dst]
        )
        for j in targets:
            self.clock.call_at(self.clock.now + LATENCY_S, self._delivery(j, d))

    def _delivery(self, j: int, d: Datagram) -> Callable[[], None]:
        return lambda: self._deliver(j, d)

    def _deliver(self, j: int, d: Datagram) -> None:
        self.nodes[j].receive(d, self.clock.now)

    def context(self, i: int) -> NodeContext:
        return NodeContext(i, self.ledger.n, self.clock, self.send, self.ledger, seed=1)

    def _starter(self, node: SimNode) -> Callable[[], None]:
        return lambda: node.start(0.0)

    def run(self) -> None:
        for node in self.nodes:
            self.clock.call_at(0.0, self._starter(node))
        while (t := self.clock.next_time()) is not None and t < WINDOW:
            self.clock.run_next()


def dds_net(timing: DdsTiming, n: int = 3) -> Lossless:
    net = Lossless(n)
    net.nodes = [DdsNode(net.context(i), timing, writers=1, readers=1) for i in range(n)]
    net.run()
    return net


@pytest.mark.parametrize(
    ("timing", "multicasts"),
    [
        # Fast DDS: 5 at 0..0.4 s, then every 3 s from 3.4 s: 3.4 + 3k < 60 -> 19 more
        (FASTDDS, 5 + 19),
        # Cyclone: at 0 s, then every 8 s: 8, 16, ..., 56
        (CYCLONE, 1 + 7),
    ],
)
def test_spdp_multicasts_follow_the_announcement_timing(timing: DdsTiming, multicasts: int) -> None:
    net = dds_net(timing)
    for i in range(3):
        assert net.sent[(i, "spdp", True)] == multicasts


@pytest.mark.parametrize(("timing", "replies"), [(FASTDDS, 1), (CYCLONE, 4)])
def test_new_participants_get_the_documented_directed_replies(
    timing: DdsTiming, replies: int
) -> None:
    net = dds_net(timing)
    for i in range(3):
        assert net.sent[(i, "spdp", False)] == replies * 2  # two peers each


@pytest.mark.parametrize("timing", [FASTDDS, CYCLONE])
def test_sedp_completes_with_one_round_per_pair_when_nothing_is_lost(timing: DdsTiming) -> None:
    net = dds_net(timing)
    assert net.ledger.count == net.ledger.pairs
    samples = timing.ros2_writers + 1, timing.ros2_readers + 1  # 9 and 8 -> 3 datagrams each
    for i in range(3):
        # per peer and channel: the history packed 3 samples per datagram, HB piggybacked
        assert net.sent[(i, "data", False)] == 2 * sum((s + 2) // 3 for s in samples)
        # the HEARTBEAT was piggybacked and answered: no standalone heartbeat, no resend
        assert net.sent[(i, "hb", False)] == 0
        # per peer: 2 pre-emptive ACKNACKs + 2 answers to the piggybacked HEARTBEATs
        assert net.sent[(i, "acknack", False)] == 2 * 4


def test_lost_sedp_is_recovered_by_heartbeats() -> None:
    net = Lossless(2)
    net.nodes = [DdsNode(net.context(i), FASTDDS, writers=1, readers=1) for i in range(2)]
    original = net.send
    dropped: list[Datagram] = []

    def lossy(d: Datagram) -> None:
        assert isinstance(d.payload, tuple)
        if d.payload[0] == "data" and not dropped:
            dropped.append(d)  # lose the very first SEDP datagram
            return
        original(d)

    for node in net.nodes:
        node.ctx.send = lossy
    net.run()
    assert dropped
    assert net.ledger.count == 2
    assert net.sent[(dropped[0].src, "data", False)] > 6  # the lost samples were resent


def test_zenoh_scouts_back_off_to_eight_seconds_and_opens_sessions() -> None:
    net = Lossless(3)
    net.nodes = [ZenohNode(net.context(i)) for i in range(3)]
    net.run()
    # scouts at 0, 1, 3, 7, 15, 23, 31, 39, 47, 55 s
    for i in range(3):
        assert net.sent[(i, "scout", True)] == 10
    assert net.ledger.count == net.ledger.pairs
    # both ends heard a HELLO at once and both opened (to_peer "always"): 2 handshakes of
    # 3 requests per pair, merged into one session per pair
    assert sum(v for (_, kind, _), v in net.sent.items() if kind == "req") == 2 * 3 * 3
    assert sum(v for (_, kind, _), v in net.sent.items() if kind == "declare") == 2 * 3
