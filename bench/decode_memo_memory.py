"""What the SPDP decode memo and the interned locator lists can be made to hold (session 16).

    nice -n 10 .venv/bin/python bench/decode_memo_memory.py [--count 256] [--lists 500]

``swarmd.discovery.received`` keeps decoded datagrams (the memo) and locator lists (interned)
for reuse. A forger's decodable DATA(p)s, distinct each, fill both. Reported, with
tracemalloc after a collection (memory, not time): the octets retained after ``--count``
datagrams of each shape, and after ``--lists`` datagrams of two distinct 1,100-locator lists
each (``MAX_INTERNED_LOCATOR_LISTS`` is 1,024 lists), both with the memo's caps as on main
(entries only; every list interned) and as they are now. Shapes: ``parameters``, the
stock-vendor DATA(p) padded with empty parameters (``tests.attacker.forge
.bloated_participant``); ``locators``, a swarmd-vendor DATA(p) of as many unicast locators as
fit. Only reports; ``tests/test_decode_memo_memory.py`` asserts the bound.
"""

from __future__ import annotations

import argparse
import gc
import sys
import tracemalloc
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from swarmd.discovery import received  # noqa: E402
from swarmd.rtps.locator import Locator  # noqa: E402
from swarmd.rtps.spdp import SpdpParticipant, encode_spdp  # noqa: E402
from swarmd.rtps.types import VENDORID_SWARMD, GuidPrefix  # noqa: E402
from tests.attacker.forge import MAX_UDP_PAYLOAD, bloated_participant  # noqa: E402

LIST_LOCATORS = 1100  # two lists of 1,100 fit in one 64 KiB DATA(p)
MAIN = {
    "DECODE_MEMO_OCTETS": 1 << 62,
    "DECODE_MEMO_MAX_DATAGRAM": 1 << 62,
    "MAX_INTERNED_LIST_LOCATORS": 1 << 62,
}


def _prefix(i: int) -> GuidPrefix:
    return GuidPrefix(b"\xf0\x0d" + i.to_bytes(10, "big"))


def _parameters(i: int) -> bytes:
    return bloated_participant(_prefix(i), size=MAX_UDP_PAYLOAD)


def _locators(i: int) -> bytes:
    locs = tuple(
        Locator.udpv4(f"10.{i % 250}.{k // 250}.{k % 250 + 1}", 7000 + i % 1000)
        for k in range(LIST_LOCATORS)
    )
    part = SpdpParticipant(
        _prefix(i),
        vendor_id=VENDORID_SWARMD,
        domain_id=None,
        metatraffic_unicast_locators=locs,
        default_unicast_locators=locs[::-1],
    )
    return encode_spdp(part, sequence_number=1, timestamp=None)


@contextmanager
def _as_main(on: bool) -> Iterator[None]:
    saved = {name: getattr(received, name) for name in MAIN}
    if on:
        for name, value in MAIN.items():
            setattr(received, name, value)
    try:
        yield
    finally:
        for name, value in saved.items():
            setattr(received, name, value)


def retained(make: Callable[[int], bytes], count: int) -> int:
    """Octets still held after decoding ``count`` distinct datagrams, each made and dropped
    inside the traced region as a received one would be."""
    received.clear_memo()
    received._locator_lists.clear()  # noqa: SLF001 - a bench of this very table
    gc.collect()
    tracemalloc.start()
    try:
        base = tracemalloc.get_traced_memory()[0]
        for i in range(count):
            received.decode(make(i))
        gc.collect()
        return int(tracemalloc.get_traced_memory()[0] - base)
    finally:
        tracemalloc.stop()
        received.clear_memo()
        received._locator_lists.clear()  # noqa: SLF001


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--count", type=int, default=256, help="datagrams per shape")
    parser.add_argument("--lists", type=int, default=500, help="datagrams of distinct lists")
    args = parser.parse_args()
    size = len(_parameters(0))
    print(f"retained after decoding (tracemalloc; {size} octets a datagram)")
    print(f"{'case':44} {'as main':>12} {'now':>12}")
    cases: list[tuple[str, Callable[[int], bytes], int]] = [
        (f"parameters x {args.count}", _parameters, args.count),
        (f"locators x {args.lists} (distinct lists)", _locators, args.lists),
    ]
    for name, make, count in cases:
        with _as_main(True):
            before = retained(make, count)
        after = retained(make, count)
        print(f"{name:44} {before / 1e6:>10.1f}MB {after / 1e6:>10.1f}MB")


if __name__ == "__main__":
    main()
