"""The channel model's effects, each on a tiny hand-placed topology (no timing asserts)."""

from __future__ import annotations

import numpy as np
import pytest
from swarmd_lab.sim.channel import MULTICAST, Channel, ChannelConfig, Datagram, Kind
from swarmd_lab.sim.clock import VirtualClock
from swarmd_lab.sim.phy import ACK_BYTES, Radio, airtime_s, per

Received = list[tuple[int, int, float]]


def make(
    xs: list[float], config: ChannelConfig | None = None, seed: int = 1
) -> tuple[VirtualClock, Channel, Received]:
    clock = VirtualClock()
    got: Received = []
    positions = np.array([[x, 0.0] for x in xs])
    ch = Channel(
        clock,
        positions,
        config or ChannelConfig(),
        seed=seed,
        deliver=lambda j, d, t: got.append((j, d.src, t)),
    )
    return clock, ch, got


def drain(clock: VirtualClock, ch: Channel, until: float = 5.0) -> None:
    while True:
        te, ta = clock.next_time(), ch.next_access()
        if ta is not None and (te is None or ta < te):
            if ta >= until:
                return
            ch.access()
        elif te is not None and te < until:
            clock.run_next()
        else:
            return


def test_airtime_grows_with_size_and_shrinks_with_rate() -> None:
    assert airtime_s(500, 6) > airtime_s(100, 6)
    assert airtime_s(500, 54) < airtime_s(500, 6)
    # an ACK at 24 Mb/s: preamble 20 us + 2 symbols + 6 us signal extension (802.11g)
    assert airtime_s(ACK_BYTES, 24) == pytest.approx(34e-6)


def test_per_rises_with_distance() -> None:
    radio = Radio()
    snr = radio.snr_db(np.array([10.0, 60.0, 120.0, 200.0]))
    errors = per(snr, 500, 6)
    assert list(errors) == sorted(errors)
    assert errors[0] < 1e-6 and errors[-1] > 0.5


def test_per_draws_lose_more_frames_far_away() -> None:
    clock, ch, got = make([0.0, 5.0, 175.0])
    for k in range(200):
        clock.call_at(k * 0.01, lambda: ch.send(Datagram(0, MULTICAST, 400, Kind.DISCOVERY)))
    drain(clock, ch)
    near = sum(1 for j, _, _ in got if j == 1)
    far = sum(1 for j, _, _ in got if j == 2)
    assert near == 200
    assert far < near
    assert ch.counters.phy_rx_fail_error == 200 - far


def test_multicast_goes_once_without_ack() -> None:
    clock, ch, got = make([0.0, 2.0, 4.0])
    ch.send(Datagram(0, MULTICAST, 300, Kind.DISCOVERY))
    drain(clock, ch)
    assert ch.counters.phy_tx == 1
    assert sorted(j for j, _, _ in got) == [1, 2]


def test_unicast_is_acknowledged_and_delivered_once() -> None:
    clock, ch, got = make([0.0, 2.0, 4.0])
    ch.send(Datagram(0, 2, 300, Kind.DISCOVERY))
    drain(clock, ch)
    assert ch.counters.phy_tx == 2  # data + ACK
    assert ch.counters.ack_by_kind[Kind.DISCOVERY] == 1
    assert [(j, s) for j, s, _ in got] == [(2, 0)]


def test_unicast_to_an_unreachable_node_is_retried_then_dropped() -> None:
    clock, ch, got = make([0.0, 2000.0])
    ch.send(Datagram(0, 1, 300, Kind.DISCOVERY))
    drain(clock, ch)
    c = ch.counters
    assert c.phy_tx == 1 + ChannelConfig().retry_limit
    assert c.phy_retx == ChannelConfig().retry_limit
    assert c.phy_drop_retry == 1
    assert got == []


def test_hidden_terminals_collide_at_the_middle_node() -> None:
    # carrier sense shrunk to ~34 m: A (0 m) and C (60 m) cannot hear each other, B (30 m)
    # hears both. Frames last ~0.6 ms, backoffs differ by at most 135 us: they overlap.
    config = ChannelConfig(cs_threshold_dbm=-70.0)
    clock, ch, got = make([0.0, 30.0, 60.0], config)
    ch.send(Datagram(0, MULTICAST, 400, Kind.DISCOVERY))
    ch.send(Datagram(2, MULTICAST, 400, Kind.DISCOVERY))
    drain(clock, ch)
    assert ch.counters.collisions == 1
    assert [(j, s) for j, s, _ in got if j == 1] == []
    assert ch.counters.phy_rx_fail_collision >= 2


def test_without_the_second_sender_the_middle_node_receives() -> None:
    config = ChannelConfig(cs_threshold_dbm=-70.0)
    clock, ch, got = make([0.0, 30.0, 60.0], config)
    ch.send(Datagram(0, MULTICAST, 400, Kind.DISCOVERY))
    drain(clock, ch)
    assert ch.counters.collisions == 0
    assert (1, 0) in [(j, s) for j, s, _ in got]


def test_carrier_sense_defers_instead_of_colliding() -> None:
    clock, ch, got = make([0.0, 2.0, 4.0])
    ch.send(Datagram(0, MULTICAST, 400, Kind.DISCOVERY))
    clock.call_at(0.0002, lambda: ch.send(Datagram(2, MULTICAST, 400, Kind.DISCOVERY)))
    drain(clock, ch)
    assert ch.counters.collisions == 0
    assert sorted((j, s) for j, s, _ in got) == [(0, 2), (1, 0), (1, 2), (2, 0)]


def test_full_mac_queue_drops_new_datagrams() -> None:
    clock, ch, got = make([0.0, 2.0], ChannelConfig(queue_limit=5))
    for _ in range(12):
        ch.send(Datagram(0, MULTICAST, 300, Kind.DISCOVERY))
    assert ch.counters.mac_drop_overflow == 7
    drain(clock, ch)
    assert len(got) == 5


def test_stale_datagrams_expire_in_the_queue() -> None:
    clock, ch, got = make([0.0, 2.0], ChannelConfig(queue_max_delay_s=0.001))
    for _ in range(20):
        ch.send(Datagram(0, MULTICAST, 1000, Kind.DISCOVERY))
    drain(clock, ch)
    assert ch.counters.mac_drop_expired > 0
    assert len(got) + ch.counters.mac_drop_expired == 20


def test_oversized_datagram_is_refused_with_one_line() -> None:
    _, ch, _ = make([0.0, 2.0])
    with pytest.raises(ValueError, match="does not fragment"):
        ch.send(Datagram(0, 1, 4000, Kind.DISCOVERY))
