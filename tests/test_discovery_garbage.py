"""Network input never raises out of the engine: parse, or drop and count (h11's invariant)."""

from __future__ import annotations

import random
from pathlib import Path

from hypothesis import given, settings
from hypothesis import strategies as st

from swarmd.discovery import DiscoveryEngine, EngineConfig, PacketDropped
from swarmd.discovery.testing import make_bundle, node_ipv4, peer_datagram
from swarmd.link.sample import LinkSample

BUNDLE = make_bundle(4)
VALID = [
    peer_datagram(BUNDLE, 1, heard=(0, 2)),
    peer_datagram(BUNDLE, 2, destination=BUNDLE.participants[0].guid_prefix),
    (Path(__file__).parent / "fixtures" / "cyclone-0.10.2" / "spdp-alive.bin").read_bytes(),
]


def fresh() -> DiscoveryEngine:
    return DiscoveryEngine(
        BUNDLE,
        "uav0",
        config=EngineConfig(),
        rng=random.Random(1),
        now=0.0,
        local_ipv4=node_ipv4(0),
        link=LinkSample(q=0.7),
    )


def feed(engine: DiscoveryEngine, data: bytes, now: float) -> None:
    engine.receive_datagram(data, ("10.9.9.9", 7400), now)
    while (t := engine.get_timer()) is not None and t <= now:
        engine.handle_timer(t)
    engine.datagrams_to_send(now)
    engine.status(now)


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=600))
def test_arbitrary_bytes_never_raise(data: bytes) -> None:
    engine = fresh()
    feed(engine, data, 0.01)
    counters = engine.counters()
    assert counters["rx_datagrams"] == 1


@settings(max_examples=300, deadline=None)
@given(
    st.sampled_from(VALID),
    st.lists(st.tuples(st.integers(0, 400), st.integers(0, 255)), min_size=1, max_size=6),
    st.integers(0, 400),
)
def test_mutated_valid_frames_never_raise(
    base: bytes, flips: list[tuple[int, int]], cut: int
) -> None:
    data = bytearray(base)
    for pos, value in flips:
        if pos < len(data):
            data[pos] = value
    engine = fresh()
    feed(engine, bytes(data[: max(cut, 20)]), 0.01)
    feed(engine, bytes(data), 0.02)


def test_garbage_becomes_a_counted_packet_dropped_event() -> None:
    engine = fresh()
    while engine.next_event() is not None:
        pass
    engine.receive_datagram(b"not RTPS at all", ("10.9.9.9", 7400), 0.0)
    event = engine.next_event()
    assert event == PacketDropped("decode_error", ("10.9.9.9", 7400))
    assert engine.counters()["dropped"]["decode_error"] == 1
