"""What the decode memo can be made to hold (session 16, h-insider16).

``received.decode`` keeps decoded datagrams for reuse (a simulator hands one multicast to
N - 1 engines in a row). It was capped at 256 entries only, and a datagram may be 64 KiB: a
forger's stock-vendor DATA(p) of ~16,000 empty parameters, one decode a second within the
foreign budget, decodes into ~1.8 MB of objects (its parameters are kept), so 256 of them
held 452 MB of a Jetson Nano's 4 GB, shared with the GPU; 500 of two distinct 1,100-locator
lists each 199 MB, memo and interned lists (``bench/decode_memo_memory.py``). Now the memo also
caps its octets (``DECODE_MEMO_OCTETS``) and takes no datagram over
``DECODE_MEMO_MAX_DATAGRAM``; long locator lists are not interned.

Memory is measured with tracemalloc after a collection; each datagram is a new bytes object
made inside the traced region, as a received one would be, and dropped by the test. No
timing.
"""

from __future__ import annotations

import gc
import tracemalloc
from collections.abc import Callable

import pytest

from swarmd.discovery import received
from swarmd.rtps.locator import Locator
from swarmd.rtps.spdp import SpdpParticipant, encode_spdp
from swarmd.rtps.types import VENDORID_SWARMD, GuidPrefix
from tests.attacker.forge import MAX_UDP_PAYLOAD, bloated_participant
from tests.test_discovery_auth import drain, receiver

# more than the memo's 256 entries; on main 10 of 64 KiB already held 17.7 MB
SIZES = [(MAX_UDP_PAYLOAD, 20), (4096, 300), (1500, 300)]
# What a flood of decodable forgeries may leave behind in the decode memo and the interned
# locator lists: a few MB (main: one 64 KiB forgery alone ~1.8 MB, 256 of them 452 MB)
RETAINED_MAX = 8_000_000
TEMPLATE_PREFIX = GuidPrefix(b"\xf0\x0d" + b"\xee" * 10)


def _prefix(i: int) -> bytes:
    return b"\xf0\x0d" + i.to_bytes(10, "big")


def _locators(size: int) -> bytes:
    """A swarmd-vendor DATA(p) of a participant of no bundle with as many unicast locators
    (metatraffic and default alike) as fit in ``size`` octets."""

    def encoded(n: int) -> bytes | None:
        locs = tuple(Locator.udpv4(f"10.9.{k // 250}.{k % 250 + 1}", 7000 + k) for k in range(n))
        part = SpdpParticipant(
            TEMPLATE_PREFIX,
            vendor_id=VENDORID_SWARMD,
            domain_id=None,
            metatraffic_unicast_locators=locs,
            default_unicast_locators=locs,
        )
        try:
            data = encode_spdp(part, sequence_number=1, timestamp=None)
        except ValueError:  # over a submessage's 65,535 octets
            return None
        return data if len(data) <= size else None

    low, high = 1, 1200
    while low < high:
        mid = (low + high + 1) // 2
        low, high = (mid, high) if encoded(mid) is not None else (low, mid - 1)
    found = encoded(low)
    assert found is not None
    return found


SHAPES: dict[str, Callable[[int], bytes]] = {
    "parameters": lambda size: bloated_participant(TEMPLATE_PREFIX, size=size),
    "locators": _locators,
}


@pytest.mark.parametrize(("size", "count"), SIZES)
@pytest.mark.parametrize("shape", sorted(SHAPES))
def test_a_flood_of_decodable_forgeries_retains_a_bounded_amount_of_memory(
    shape: str, size: int, count: int
) -> None:
    """Attacker 1, no key: distinct DATA(p)s of invented participants, each decoded (one a
    second: within the foreign decode budget of docs/security.md), each kept by the memo."""
    template = SHAPES[shape](size)
    assert template.count(TEMPLATE_PREFIX.value) == 2  # the RTPS header and the GUID
    e = receiver()
    received.clear_memo()
    gc.collect()
    tracemalloc.start()
    try:
        base = tracemalloc.get_traced_memory()[0]
        retained = 0
        for i in range(count):
            data = template.replace(TEMPLATE_PREFIX.value, _prefix(i))
            e.receive_datagram(data, ("10.0.0.66", 7400), float(i))
            drain(e)
            del data
            if i % 10 == 9 or i == count - 1:
                gc.collect()
                retained = tracemalloc.get_traced_memory()[0] - base
                assert retained <= RETAINED_MAX, f"{retained:,} B after {i + 1} datagrams"
        # every one was decoded (and listed as a foreign participant), none refused
        assert e.counters()["dropped"]["foreign_budget"] == 0
        assert e.counters()["dropped"]["not_in_bundle"] == count
    finally:
        tracemalloc.stop()
        received.clear_memo()
