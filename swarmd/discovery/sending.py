"""Sending: our DATA(p) (and DATA(p[UD]) when we leave), its sequence number, the outbox.

SPDP is a keyed history of depth 1 (DDSI-RTPS 8.5.3): our DATA(p) gets a new sequence number
whenever its content changes (the heard digest, the advertised Q and lease, the vouch) and
keeps it while it does not, which is what lets a peer tell a repeated frame from a new one.
Without a wallclock (simulator, tests) the encoded template is memoised per destination;
every datagram is sealed on its own (its freshness), when authentication is on.

The outbox is capped: a driver that stops collecting datagrams must not grow memory.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from typing import Final

from swarmd.auth.spdp import PLACEHOLDER, SpdpAuth
from swarmd.bundle.model import Bundle, Participant
from swarmd.discovery.leases import Leases
from swarmd.discovery.peers import Peer
from swarmd.discovery.renewals import Renewals
from swarmd.rtps.locator import Locator
from swarmd.rtps.spdp import BES_SPDP_ONLY, SpdpParticipant, encode_spdp, encode_spdp_dispose
from swarmd.rtps.types import Duration, GuidPrefix, Time

# The datagrams the driver has not collected yet: the newest 4096 are kept, the rest counted.
MAX_PENDING_DATAGRAMS: Final = 4096

Wallclock = Callable[[], float]


class Sender:
    """Our participant data, its sequence number, the encode memo and the outbox."""

    __slots__ = (
        "_auth",
        "_content",
        "_digest",
        "_domain_id",
        "_encoded",
        "_entity_name",
        "_leases",
        "_me",
        "_renewals",
        "_static_locators",
        "_wallclock",
        "counters",
        "outbox",
        "ros2_alive",
        "sn",
        "spdp_multicast",
        "tx_kind",
    )

    def __init__(
        self,
        bundle: Bundle,
        me: Participant,
        *,
        digest: bytes,
        static_locators: tuple[tuple[Locator, ...], tuple[Locator, ...], tuple[Locator, ...]],
        spdp_multicast: tuple[str, int],
        auth: SpdpAuth | None,
        wallclock: Wallclock | None,
        leases: Leases,
        renewals: Renewals,
    ) -> None:
        self._me = me
        self._domain_id = bundle.domain_id
        self._entity_name = f"{bundle.swarm}/{me.name}"
        self._digest = digest
        self._static_locators = static_locators
        self.spdp_multicast = spdp_multicast
        self._auth = auth
        self._wallclock = wallclock
        self._leases = leases  # the heard digest and the commander's vouch we send
        self._renewals = renewals  # the advertised Q and lease we send
        self.sn = 0
        # our ROS 2 relay's alive participants (PID 0x8A06); None: no relay, nothing sent
        self.ros2_alive: bytes | None = None
        self._content: SpdpParticipant | None = None
        self._encoded: dict[GuidPrefix | None, bytes] = {}
        self.outbox: deque[tuple[bytes, tuple[str, int]]] = deque()
        self.counters: dict[str, int] = {
            "tx_datagrams": 0,
            "tx_multicast": 0,
            "tx_unicast": 0,
            "datagrams_dropped": 0,
        }
        self.tx_kind: dict[str, int] = {
            "announce": 0,
            "reply": 0,
            "renewal": 0,
            "probe": 0,
            "seek": 0,
            "dispose": 0,
        }

    def participant_data(self, now: float) -> SpdpParticipant:
        """Our DATA(p) as of ``now``."""
        meta_uc, meta_mc, user_uc = self._static_locators
        leases = self._leases
        renewals = self._renewals
        return SpdpParticipant(
            self._me.guid_prefix,
            domain_id=self._domain_id,
            metatraffic_unicast_locators=meta_uc,
            metatraffic_multicast_locators=meta_mc,
            default_unicast_locators=user_uc,
            lease_duration=Duration.from_seconds(renewals.lease_s()),
            builtin_endpoints=BES_SPDP_ONLY,
            entity_name=self._entity_name,
            bundle_digest=self._digest,
            heard=leases.heard.to_bytes(),
            link_quality_permille=renewals.permille,
            vouched=leases.vouch(now),
            ros2_alive=self.ros2_alive,
            authenticator=None if self._auth is None else PLACEHOLDER,
        )

    def send(self, peer: Peer | None, now: float, kind: str) -> None:
        """Queue our DATA(p) to ``peer`` (directed), or to the multicast group (None)."""
        content = self.participant_data(now)
        if content != self._content:
            # SPDP is a keyed history of depth 1: a new SN whenever the content changes
            self._content = content
            self.sn += 1
            self._encoded.clear()
        destination = None if peer is None else peer.participant.guid_prefix
        target = self.spdp_multicast if peer is None else peer.target()
        if target is None:  # callers check; an undiscovered peer without an address
            return
        payload = self._encoded.get(destination) if self._wallclock is None else None
        if payload is None:
            payload = encode_spdp(
                content,
                sequence_number=self.sn,
                timestamp=self._timestamp(),
                destination=destination,
            )
            if self._wallclock is None:
                self._encoded[destination] = payload
        # the memo keeps the unsigned template; every datagram gets its own freshness
        self._queue(self._seal(payload), target, multicast=peer is None)
        self.tx_kind[kind] += 1
        if content.vouched is not None:
            self._leases.vouches_sent.mark(now)

    def dispose(
        self, directed: list[tuple[GuidPrefix, tuple[str, int]]], *, group_copies: int
    ) -> None:
        """Queue our DATA(p[UD]): once to the group, once to each of ``directed``, then the
        group's repeats (``group_copies`` in all); one sample (one SN) for all of them."""
        self.sn += 1
        prefix, timestamp = self._me.guid_prefix, self._timestamp()
        placeholder = None if self._auth is None else PLACEHOLDER
        # the copies differ only in their freshness, each sealed on its own so a receiver
        # takes whichever arrives first and counts no replay for the rest
        group = encode_spdp_dispose(
            prefix, sequence_number=self.sn, timestamp=timestamp, authenticator=placeholder
        )
        self._queue(self._seal(group), self.spdp_multicast, multicast=True)
        self.tx_kind["dispose"] += 1
        for destination, target in directed:
            payload = encode_spdp_dispose(
                prefix,
                sequence_number=self.sn,
                timestamp=timestamp,
                destination=destination,
                authenticator=placeholder,
            )
            self._queue(self._seal(payload), target, multicast=False)
            self.tx_kind["dispose"] += 1
        # the repeats after the directed frames: spaced by them when there are any
        for _ in range(group_copies - 1):
            self._queue(self._seal(group), self.spdp_multicast, multicast=True)
            self.tx_kind["dispose"] += 1

    def _seal(self, template: bytes) -> bytes:
        return template if self._auth is None else self._auth.seal(template)

    def _queue(self, payload: bytes, target: tuple[str, int], *, multicast: bool) -> None:
        if len(self.outbox) >= MAX_PENDING_DATAGRAMS:
            self.outbox.popleft()
            self.counters["datagrams_dropped"] += 1
        self.outbox.append((payload, target))
        self.counters["tx_datagrams"] += 1
        self.counters["tx_multicast" if multicast else "tx_unicast"] += 1

    def _timestamp(self) -> Time | None:
        return None if self._wallclock is None else Time.from_seconds(self._wallclock())
