"""Foreign participants: DATA(p) heard from outside the bundle (stock DDS nodes, another
swarm's drones, a forger's invented GUID prefixes), remembered in a capped table, reported
at a bounded rate, and, with authentication on, decoded at a bounded rate.

Nothing here can move a bundle peer: a foreign participant is only ever counted, listed
(``DiscoveryEngine.foreign``, ``swarmctl status``) and reported (``ForeignParticipantSeen``).
"""

from __future__ import annotations

from collections import Counter
from typing import Final

from swarmd.discovery.events import DropReason, ForeignParticipantSeen
from swarmd.discovery.peers import MAX_FOREIGN, ForeignTable, clamp_lease
from swarmd.discovery.views import ForeignView
from swarmd.rtps.spdp import SpdpParticipant
from swarmd.rtps.types import GuidPrefix
from swarmd.tokenbucket import TokenBucket

# A flood of DATA(p) under invented GUID prefixes (issue 10, attack 9) makes every datagram a
# "new foreign participant"; report about one a second (burst 10), each report carrying how
# many it stands for (``ForeignParticipantSeen.suppressed``), so the log is a summary.
MAX_FOREIGN_REPORTS_PER_S: Final = 1.0
FOREIGN_REPORT_BURST: Final = 10.0
# With authentication on, datagrams under prefixes outside the bundle (stock DDS nodes, a
# forger's invented participants, garbage) are decoded at most this often: a decode costs
# ~50 us (docs/benchmarks.md), so a 5,000/s flood would otherwise cost a quarter of a core.
# A stock participant renews about once a second; beyond the budget it is only counted.
FOREIGN_DECODES_PER_S: Final = 50.0
FOREIGN_DECODE_BURST: Final = 50.0
# ... and at most this many octets a second (review 16): a decode's work grows with the
# datagram's octets (~0.15 us an octet at worst, ~0.09 for a stock Cyclone DATA(p):
# bench/foreign_decode_cost.py), so a count of datagrams alone let 50 forged 64 KiB
# datagrams a second cost ~0.5 s of the loop's second. 50 Wi-Fi frames of 1,500 octets: a
# stock participant's DATA(p) (~300-700 octets) is held back by the count first, and one
# datagram of any size (at most 65,507 octets over IPv4) fits the burst.
FOREIGN_DECODE_OCTETS_PER_S: Final = 50.0 * 1500
FOREIGN_DECODE_OCTET_BURST: Final = 50.0 * 1500


class ForeignParticipants:
    """The table of foreign participants, its report rate limit and the decode budget.

    ``dropped`` is the receive path's drop counter (a sighting is a dropped DATA(p)), shared
    so that ``counters()`` has one count per ``DropReason``."""

    __slots__ = (
        "_dropped",
        "_reports",
        "decode_budget",
        "decode_octets",
        "suppressed",
        "suppressed_total",
        "table",
    )

    def __init__(self, dropped: Counter[DropReason], now: float) -> None:
        self.table = ForeignTable(MAX_FOREIGN)
        self._dropped = dropped
        self._reports = TokenBucket(MAX_FOREIGN_REPORTS_PER_S, FOREIGN_REPORT_BURST, now)
        self.suppressed = 0  # new foreign participants since the last ForeignParticipantSeen
        self.suppressed_total = 0  # all of them folded into a later report (a counter)
        # unauthenticated datagrams outside the bundle we may still decode (auth on only)
        self.decode_budget = TokenBucket(FOREIGN_DECODES_PER_S, FOREIGN_DECODE_BURST, now)
        self.decode_octets = TokenBucket(
            FOREIGN_DECODE_OCTETS_PER_S, FOREIGN_DECODE_OCTET_BURST, now
        )

    def may_decode(self, octets: int, now: float) -> bool:
        """Whether a datagram of ``octets`` under a prefix outside the bundle may be decoded
        now (auth on): a token of the count budget and its size in the octet budget, both
        spent only when both are there."""
        count, size = self.decode_budget, self.decode_octets
        if not count.has_token(now) or size.balance(now) < octets:
            return False
        count.spend()
        size.spend(octets)
        return True

    def see(
        self, part: SpdpParticipant, reason: DropReason, now: float
    ) -> ForeignParticipantSeen | None:
        """Count and record a sighting; the event to report if it is new and the report
        budget allows (else it is folded into the next report's ``suppressed``)."""
        self._dropped[reason] += 1
        new = self.table.see(
            part.guid_prefix,
            vendor=part.vendor_id.name,
            name=part.entity_name,
            reason=reason,
            lease_s=clamp_lease(part.lease_duration.total_seconds()),
            now=now,
        )
        if not new:
            return None
        if not self._reports.take(now):
            self.suppressed += 1
            self.suppressed_total += 1
            return None
        event = ForeignParticipantSeen(
            part.guid_prefix,
            part.vendor_id.name,
            part.entity_name,
            reason,
            self.suppressed,
        )
        self.suppressed = 0
        return event

    def disposed(self, prefix: GuidPrefix) -> None:
        """A foreign participant left (its DATA(p[UD])): forget it."""
        self.table.remove(prefix)

    def views(self, now: float) -> tuple[ForeignView, ...]:
        """Participants heard but never matched and not silent past their lease, least
        recently heard first."""
        return tuple(
            ForeignView(
                e.guid_prefix, e.vendor, e.name, e.reason, e.first_seen, e.last_seen, e.frames
            )
            for e in self.table.alive(now)
        )
