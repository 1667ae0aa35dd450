"""How many client keys the bound agent may compare, per second: the budget that makes
guessing the XRCE key hopeless (docs/security.md, "The PX4 link: MAVLink and XRCE").

The key (DDS-XRCE 1.0 §8.3.5.1 ``ClientKey``) is a 32-bit identifier in the clear, and the
only thing that keeps another local process from taking the vehicle's session when none is
alive. Unbudgeted, a local user checks ~27,000 keys a second over loopback
(``bench/xrce_key_guess.py``): the generated key's space (2^31) in about 11 hours on average.
Each comparison therefore spends a token, and a CREATE_CLIENT that finds none is dropped
*unchecked*: the right key then wins nothing either, so a flood cannot test keys faster than
the budget.

Two buckets must each hold a token for a key to be checked:

- the *origin*'s: where a local user can and cannot send from. Any loopback address and any
  free port are the user's, so all of the loopback (127/8, ::1, v4-mapped 127/8) is one
  origin. Another host's address (an FMU on Ethernet) is its own origin: a process here
  cannot send from it (the kernel refuses a source address no interface has unless the
  socket is ``IP_TRANSPARENT``, which takes ``CAP_NET_ADMIN``), and neither can it write to
  the UART (``serial``). A host on another interface (the Wi-Fi) can write any source
  address, that one included: the agent's socket hears its address only on the interface
  that holds it (``px4.transport.bind_to_its_interface``), or the budget would hand that host
  the FMU's share (docs/security-history.md, "This morning's defences reviewed (session 11)"). A
  flood on the loopback spends the loopback's budget and never that of the vehicle's wire.
  The companion's own other addresses are origins a local user can send from; the table is
  capped, so they add a bounded share;
- the *source*'s (address and port): one port gets less than its origin, so one flooding
  process (or a misconfigured second client retrying fast) leaves a vehicle on the same
  origin its share.

A check is spent whatever its outcome (a wrong key, or the right one while the vehicle's
session lives), so how many later tries are checked tells a prober nothing either.

The figures: ``ORIGIN_CHECKS_PER_S`` = 3 per origin: 2^30 tries (half the generated key
space) take 11 years from the loopback alone, and 1.26 years with every origin of the capped
table spent at once (the bound ``max_checks_per_s``, 27 a second; only with the agent on every
interface and 8 addresses to send from). PX4 resends an unanswered CREATE_CLIENT from one
port every ``UXR_CONFIG_MIN_SESSION_CONNECTION_INTERVAL`` (1000 ms by default, Micro XRCE-DDS
client) and opens a new port for each set-up attempt: one check per try, within its
source's share (a build with a shorter interval gets its first 3 tries checked at once).
"""

from __future__ import annotations

from collections.abc import Hashable
from typing import Final, TypeVar

from swarmd.loopback import plain_address
from swarmd.tokenbucket import TokenBucket

# per origin: 3 keys a second, 6 at once (a PX4 and a restarted PX4 within a second)
ORIGIN_CHECKS_PER_S: Final = 3.0
ORIGIN_BURST: Final = 6.0
# per source (address and port): PX4's retry rate (one CREATE_CLIENT a second from one port),
# a third of its origin's, so one flooding port leaves a vehicle there its share
SOURCE_CHECKS_PER_S: Final = 1.0
SOURCE_BURST: Final = 3.0
# Origins remembered at once: the loopback, the UART or the FMU's address, and the
# companion's own addresses a local user can send from with the agent on every interface.
# Beyond it, new origins share one bucket: the cap bounds the sum (``max_checks_per_s``).
MAX_ORIGINS: Final = 8
# Sources remembered at once: a flood from every port would grow the table without bound.
# A source whose bucket is full again is forgotten first (nothing is lost: a fresh bucket is
# full); past the cap the oldest goes, which can only give one source back its burst; its
# origin's bucket still bounds the total.
MAX_SOURCES: Final = 256
SHARED_ORIGIN: Final = "(other origins)"
LOOPBACK_ORIGIN: Final = "loopback"
_K = TypeVar("_K")


def origin_of(source: Hashable) -> str:
    """The origin of a datagram's source: ``loopback`` for every loopback address, the
    address for another host, ``str(source)`` for a link with no address (``serial``)."""
    if not isinstance(source, tuple) or not source or not isinstance(source[0], str):
        return str(source)
    ip = plain_address(source[0])  # an IPv6 scope is not part of the address
    if ip is None:
        return source[0].partition("%")[0]
    return LOOPBACK_ORIGIN if ip.is_loopback else str(ip)


class KeyCheckBudget:
    """Whether the agent may compare one more client key from ``source`` at ``now``.

    Pure and keyed by ``now`` (style.md rule 6): it schedules nothing; a bucket refills when
    asked. ``allow`` spends a token of the source and of its origin when both have one.
    """

    def __init__(self) -> None:
        self._origins: dict[str, TokenBucket] = {}
        self._sources: dict[Hashable, TokenBucket] = {}
        self.checks = 0  # keys compared
        self.over_budget = 0  # CREATE_CLIENTs dropped unchecked

    @staticmethod
    def max_checks_per_s() -> float:
        """The most keys a second any mix of sources can have checked, in the long run."""
        return (MAX_ORIGINS + 1) * ORIGIN_CHECKS_PER_S

    def allow(self, source: Hashable, now: float) -> bool:
        origin_bucket = self._origin_bucket(origin_of(source), now)
        source_bucket = self._source_bucket(source, now)
        # both must hold a token before either is spent: a refused try costs neither
        if not (source_bucket.has_token(now) and origin_bucket.has_token(now)):
            self.over_budget += 1
            return False
        source_bucket.spend()
        origin_bucket.spend()
        self.checks += 1
        return True

    def _origin_bucket(self, origin: str, now: float) -> TokenBucket:
        bucket = self._origins.get(origin)
        if bucket is not None:
            return bucket
        if len(self._origins) >= MAX_ORIGINS:
            _forget_full(self._origins, now)
        if len(self._origins) >= MAX_ORIGINS:
            origin = SHARED_ORIGIN
            if origin in self._origins:
                return self._origins[origin]
        bucket = TokenBucket(ORIGIN_CHECKS_PER_S, ORIGIN_BURST, now)
        self._origins[origin] = bucket
        return bucket

    def _source_bucket(self, source: Hashable, now: float) -> TokenBucket:
        bucket = self._sources.get(source)
        if bucket is not None:
            return bucket
        if len(self._sources) >= MAX_SOURCES:
            _forget_full(self._sources, now)
        while len(self._sources) >= MAX_SOURCES:
            del self._sources[next(iter(self._sources))]  # the oldest
        bucket = TokenBucket(SOURCE_CHECKS_PER_S, SOURCE_BURST, now)
        self._sources[source] = bucket
        return bucket


def _forget_full(table: dict[_K, TokenBucket], now: float) -> None:
    """Drop every bucket that is full again: it is the same as none."""
    for key in [k for k, b in table.items() if b.is_full(now)]:
        del table[key]
