"""Verification budgets: how many signature checks a sender, or everyone, may cost us.

An Ed25519 verification costs ~50-130 us here and several times that on a Jetson Nano
(docs/benchmarks.md, "Security"); a forger on the Wi-Fi can send thousands of datagrams a
second for free. So a datagram reaches the signature check only after the cheap checks
(known prefix, fresh counter) *and* a token from its budget (style.md rule 6: a small pure
class keyed by ``now``, no timers of its own).
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Hashable
from typing import Final, Generic, TypeVar

from swarmd.tokenbucket import TokenBucket

K = TypeVar("K", bound=Hashable)


class BucketTable(Generic[K]):
    """One ``TokenBucket`` per key, the ``cap`` most recently used kept (a forger inventing
    keys evicts its own oldest buckets, never grows memory); evictions are counted."""

    def __init__(self, rate: float, burst: float, cap: int) -> None:
        self.rate = rate
        self.burst = burst
        self.cap = cap
        self.evicted = 0
        self._buckets: OrderedDict[K, TokenBucket] = OrderedDict()

    def take(self, key: K, now: float) -> bool:
        bucket = self._buckets.get(key)
        if bucket is None:
            while len(self._buckets) >= self.cap:
                self._buckets.popitem(last=False)
                self.evicted += 1
            bucket = self._buckets[key] = TokenBucket(self.rate, self.burst, now)
        else:
            self._buckets.move_to_end(key)
        return bucket.take(now)

    def __len__(self) -> int:
        return len(self._buckets)


# A real peer sends a few SPDP datagrams a second at most (renewals, directed replies, a
# burst when it (re)joins); 20/s with a burst of 40 never throttles it.
SENDER_RATE: Final = 20.0
SENDER_BURST: Final = 40.0
# Datagrams under a bundle prefix from an address that prefix was never verified at: a
# moved peer (rare) or a forger. All such addresses together share GLOBAL_NEW_ADDRESS_*,
# so a flood spoofing members from many addresses costs at most 50 verifications a second
# (~1 % of a core here, a few % on a Jetson Nano: docs/benchmarks.md) and never touches a
# member's known address.
NEW_ADDRESS_RATE: Final = 5.0
NEW_ADDRESS_BURST: Final = 10.0
GLOBAL_NEW_ADDRESS_RATE: Final = 50.0
GLOBAL_NEW_ADDRESS_BURST: Final = 50.0
# (prefix, address) pairs tracked for the per-address budget: a forger cycling source
# addresses evicts its own entries.
MAX_NEW_ADDRESSES: Final = 256
