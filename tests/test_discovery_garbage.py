"""Network input never raises out of the engine: parse, or drop and count (h11's invariant)."""

from __future__ import annotations

from pathlib import Path

from hypothesis import given, settings
from hypothesis import strategies as st
from swarmd_lab.testing import engine_for, make_bundle, peer_datagram

from swarmd.discovery import DiscoveryEngine, PacketDropped
from swarmd.discovery.events import DropReason

BUNDLE = make_bundle(4)
VALID = [
    peer_datagram(BUNDLE, 1, heard=(0, 2)),
    peer_datagram(BUNDLE, 2, destination=BUNDLE.participants[0].guid_prefix),
    (Path(__file__).parent / "fixtures" / "cyclone-0.10.2" / "spdp-alive.bin").read_bytes(),
]


def fresh() -> DiscoveryEngine:
    return engine_for(BUNDLE, 0, seed=1, q=0.7)


def feed(
    engine: DiscoveryEngine, data: bytes, now: float, source: tuple[str, int] = ("10.9.9.9", 7400)
) -> None:
    engine.receive_datagram(data, source, now)
    while (t := engine.get_timer()) is not None and t <= now:
        engine.handle_timer(t)
    engine.datagrams_to_send()
    engine.status(now)


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=600))
def test_arbitrary_bytes_never_raise(data: bytes) -> None:
    engine = fresh()
    feed(engine, data, 0.01)
    counters = engine.counters()
    assert counters["rx_datagrams"] == 1


SOURCES = st.tuples(
    st.one_of(
        st.ip_addresses(v=4).map(str),
        st.ip_addresses(v=6).map(str),
        st.text(max_size=40),  # the driver passes what recvfrom gave; the engine only keeps it
    ),
    st.integers(-(2**31), 2**31),
)


@settings(max_examples=300, deadline=None)
@given(st.one_of(st.binary(max_size=600), st.sampled_from(VALID)), SOURCES, st.floats(0, 30))
def test_arbitrary_bytes_from_arbitrary_sources_never_raise(
    data: bytes, source: tuple[str, int], now: float
) -> None:
    engine = fresh()
    feed(engine, data, now, source)
    feed(engine, data, now + 0.5, source)  # and again: a repeat takes other paths
    assert engine.counters()["rx_datagrams"] == 2


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
    assert event == PacketDropped(DropReason.DECODE_ERROR, ("10.9.9.9", 7400))
    assert engine.counters()["dropped"]["decode_error"] == 1
