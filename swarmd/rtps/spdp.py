"""SPDP participant announcements: DATA(p) and its dispose form DATA(p[UD]).

What goes on the wire follows the reference's validated layout (shared reference section
1.14): INFO_DST (directed replies only) + INFO_TS + DATA(p) with a PL_CDR_LE payload. The
dispose DATA(p[UD]) carries KEY_HASH and STATUS_INFO=3 inline plus the key payload
(flags E|Q|K), a shape both Cyclone DDS and Fast DDS act on (section 1.11).

swarmd's own data travels in vendor-specific PIDs 0x8A01..0x8A03 under vendor id 53.57
("SW"); they are interpreted only when the sender's vendor id is swarmd's, and stock stacks
skip them (0x8000 set, 0x4000 clear). See docs/wire.md.

Invariant: ``decode_spdp`` raises ``DecodeError`` and nothing else, for any input.
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Final

from swarmd.rtps.buffer import Reader, Writer
from swarmd.rtps.errors import DecodeError
from swarmd.rtps.locator import Locator
from swarmd.rtps.message import (
    Data,
    Header,
    InfoDst,
    InfoTs,
    Submessage,
    decode_message,
    encode_message,
)
from swarmd.rtps.parameters import (
    Parameter,
    ParameterList,
    Pid,
    pack_duration,
    pack_locator,
    pack_octets,
    pack_properties,
    pack_string,
    pack_u32,
    pull_parameter_list,
    push_parameter_list,
    value_duration,
    value_i32,
    value_locator,
    value_octets,
    value_properties,
    value_string,
    value_u32,
)
from swarmd.rtps.types import (
    ENTITYID_PARTICIPANT,
    ENTITYID_SPDP_READER,
    ENTITYID_SPDP_WRITER,
    PROTOCOLVERSION_SWARMD,
    UNKNOWN_GUID_PREFIX,
    VENDORID_SWARMD,
    Duration,
    GuidPrefix,
    ProtocolVersion,
    Time,
    VendorId,
)

# Encapsulation identifiers (spec 10.5; always big-endian on the wire)
PL_CDR_BE: Final = b"\x00\x02"
PL_CDR_LE: Final = b"\x00\x03"

# PID_BUILTIN_ENDPOINT_SET bits (spec 8.5.3.1; reference section 1.7)
BES_PARTICIPANT_ANNOUNCER: Final = 1 << 0
BES_PARTICIPANT_DETECTOR: Final = 1 << 1
BES_PUBLICATION_ANNOUNCER: Final = 1 << 2
BES_PUBLICATION_DETECTOR: Final = 1 << 3
BES_SUBSCRIPTION_ANNOUNCER: Final = 1 << 4
BES_SUBSCRIPTION_DETECTOR: Final = 1 << 5
BES_PARTICIPANT_MESSAGE_WRITER: Final = 1 << 10
BES_PARTICIPANT_MESSAGE_READER: Final = 1 << 11
# SPDP writer and reader only: stock peers then never start SEDP with us (reference 1.7)
BES_SPDP_ONLY: Final = BES_PARTICIPANT_ANNOUNCER | BES_PARTICIPANT_DETECTOR

# Spec default when PID_PARTICIPANT_LEASE_DURATION is absent (Cyclone 0.10 assumes the same)
DEFAULT_LEASE_DURATION: Final = Duration(100, 0)

STATUS_INFO_DISPOSED: Final = 0x01
STATUS_INFO_UNREGISTERED: Final = 0x02

# swarmd's vendor-specific PIDs: 0x8000 set (vendor range), 0x4000 clear (stock stacks
# must be free to ignore them; Cyclone rejects a whole sample for an unknown 0x4000 PID).
PID_SWARMD_BUNDLE_DIGEST: Final = 0x8A01
PID_SWARMD_HEARD: Final = 0x8A02
PID_SWARMD_LINK_QUALITY: Final = 0x8A03
# the authenticator: freshness (epoch u32, seq u32) + Ed25519 signature (64 octets), always
# the last parameter before PID_SENTINEL (swarmd.auth.spdp, docs/wire.md)
PID_SWARMD_AUTHENTICATOR: Final = 0x8A04
# the commander's vouch: u32 window in ms, then an octet sequence (a bitmap over bundle
# indices of the members it heard directly within that window; docs/discovery.md)
PID_SWARMD_VOUCHED: Final = 0x8A05
MAX_VOUCH_WINDOW_MS: Final = 60_000
# which of the sender's own ROS 2 participants (the bundle's, in bundle order) its relay
# has alive: an octet sequence, LSB of byte 0 = the first (docs/ros2.md, "Node liveness")
PID_SWARMD_ROS2_ALIVE: Final = 0x8A06
SWARMD_PIDS: Final = frozenset(
    {
        PID_SWARMD_BUNDLE_DIGEST,
        PID_SWARMD_HEARD,
        PID_SWARMD_LINK_QUALITY,
        PID_SWARMD_AUTHENTICATOR,
        PID_SWARMD_VOUCHED,
        PID_SWARMD_ROS2_ALIVE,
    }
)

MAX_LINK_QUALITY_PERMILLE: Final = 1000


@dataclass(frozen=True, slots=True)
class Vouch:
    """PID 0x8A05: the members the commander heard directly within ``window_ms``."""

    window_ms: int
    bitmap: bytes  # over bundle indices, LSB of byte 0 = index 0 (as the heard digest)


@dataclass(frozen=True, slots=True)
class SpdpParticipant:
    """The content of one participant's DATA(p) (SPDPdiscoveredParticipantData)."""

    guid_prefix: GuidPrefix
    protocol_version: ProtocolVersion = PROTOCOLVERSION_SWARMD
    vendor_id: VendorId = VENDORID_SWARMD
    domain_id: int | None = 0
    domain_tag: str | None = None
    metatraffic_unicast_locators: tuple[Locator, ...] = ()
    metatraffic_multicast_locators: tuple[Locator, ...] = ()
    default_unicast_locators: tuple[Locator, ...] = ()
    default_multicast_locators: tuple[Locator, ...] = ()
    lease_duration: Duration = DEFAULT_LEASE_DURATION
    builtin_endpoints: int = BES_SPDP_ONLY
    manual_liveliness_count: int | None = None
    entity_name: str | None = None
    user_data: bytes | None = None
    properties: tuple[tuple[str, str], ...] = ()
    # swarmd vendor PIDs (only read when vendor_id is swarmd's)
    bundle_digest: bytes | None = None
    heard: bytes | None = None  # bitmap over bundle participant indices, LSB of byte 0 = index 0
    link_quality_permille: int | None = None
    vouched: Vouch | None = None  # the commander's vouch (PID 0x8A05)
    ros2_alive: bytes | None = None  # PID 0x8A06: its relay's alive ROS 2 participants
    authenticator: bytes | None = None  # 72 octets, encoded last (swarmd.auth.spdp)
    # every other parameter, in wire order (stock vendors' PIDs, security tokens, ...)
    extra_parameters: tuple[Parameter, ...] = field(default=())

    @property
    def is_swarmd(self) -> bool:
        return self.vendor_id == VENDORID_SWARMD

    def to_parameters(self, little: bool = True) -> tuple[Parameter, ...]:
        """The parameter list in swarmd's canonical order (reference section 1.14)."""
        pv, vid = self.protocol_version, self.vendor_id
        out = [
            Parameter(Pid.PROTOCOL_VERSION, bytes((pv.major, pv.minor, 0, 0))),
            Parameter(Pid.VENDORID, vid.value + b"\x00\x00"),
        ]
        if self.domain_id is not None:
            out.append(Parameter(Pid.DOMAIN_ID, pack_u32(self.domain_id, little)))
        if self.domain_tag is not None:
            out.append(Parameter(Pid.DOMAIN_TAG, pack_string(self.domain_tag, little)))
        out.append(
            Parameter(Pid.PARTICIPANT_GUID, self.guid_prefix.value + ENTITYID_PARTICIPANT.value)
        )
        for pid, locators in (
            (Pid.METATRAFFIC_UNICAST_LOCATOR, self.metatraffic_unicast_locators),
            (Pid.METATRAFFIC_MULTICAST_LOCATOR, self.metatraffic_multicast_locators),
            (Pid.DEFAULT_UNICAST_LOCATOR, self.default_unicast_locators),
            (Pid.DEFAULT_MULTICAST_LOCATOR, self.default_multicast_locators),
        ):
            out.extend(Parameter(pid, pack_locator(loc, little)) for loc in locators)
        out.append(
            Parameter(Pid.PARTICIPANT_LEASE_DURATION, pack_duration(self.lease_duration, little))
        )
        out.append(Parameter(Pid.BUILTIN_ENDPOINT_SET, pack_u32(self.builtin_endpoints, little)))
        if self.manual_liveliness_count is not None:
            out.append(
                Parameter(
                    Pid.PARTICIPANT_MANUAL_LIVELINESS_COUNT,
                    self.manual_liveliness_count.to_bytes(
                        4, "little" if little else "big", signed=True
                    ),
                )
            )
        if self.entity_name is not None:
            out.append(Parameter(Pid.ENTITY_NAME, pack_string(self.entity_name, little)))
        if self.user_data is not None:
            out.append(Parameter(Pid.USER_DATA, pack_octets(self.user_data, little)))
        if self.properties:
            out.append(Parameter(Pid.PROPERTY_LIST, pack_properties(self.properties, little)))
        out.extend(self.extra_parameters)
        if self.bundle_digest is not None:
            out.append(Parameter(PID_SWARMD_BUNDLE_DIGEST, pack_octets(self.bundle_digest, little)))
        if self.heard is not None:
            out.append(Parameter(PID_SWARMD_HEARD, pack_octets(self.heard, little)))
        if self.link_quality_permille is not None:
            out.append(
                Parameter(PID_SWARMD_LINK_QUALITY, pack_u32(self.link_quality_permille, little))
            )
        if self.vouched is not None:
            out.append(
                Parameter(
                    PID_SWARMD_VOUCHED,
                    pack_u32(self.vouched.window_ms, little)
                    + pack_octets(self.vouched.bitmap, little),
                )
            )
        if self.ros2_alive is not None:
            out.append(Parameter(PID_SWARMD_ROS2_ALIVE, pack_octets(self.ros2_alive, little)))
        if self.authenticator is not None:
            # raw, not an octet sequence: fixed size, and last so a receiver finds it at a
            # fixed offset from the end of the datagram before decoding anything
            out.append(Parameter(PID_SWARMD_AUTHENTICATOR, self.authenticator))
        return tuple(out)

    @classmethod
    def from_parameters(cls, plist: ParameterList) -> SpdpParticipant:
        """Interpret a DATA(p) parameter list. Raises ``DecodeError`` only.

        A repeated singular PID keeps its first value, as Cyclone does; locator PIDs repeat.
        """
        little = plist.little
        kw: dict[str, object] = {}
        locators: dict[str, list[Locator]] = {}
        extras: list[Parameter] = []
        vendor_params: list[Parameter] = []
        for p in plist.params:
            handler = _FIELD_DECODERS.get(p.pid)
            if handler is None:
                (vendor_params if p.pid in SWARMD_PIDS else extras).append(p)
                continue
            name, decode = handler
            if name in _LOCATOR_FIELDS:
                locators.setdefault(name, []).append(value_locator(p, little))
            elif name not in kw:
                kw[name] = decode(p, little)
        guid = kw.pop("guid_prefix", None)
        if not isinstance(guid, GuidPrefix):
            raise DecodeError("DATA(p) without PID_PARTICIPANT_GUID")
        legacy_bes = kw.pop("legacy_builtin_endpoints", None)
        if "builtin_endpoints" not in kw:
            kw["builtin_endpoints"] = legacy_bes if legacy_bes is not None else 0
        # Absent PID_DOMAIN_ID means "the receiver's own domain" (spec 9.6.2.2)
        kw.setdefault("domain_id", None)
        for name, values in locators.items():
            kw[name] = tuple(values)
        if kw.get("vendor_id") == VENDORID_SWARMD:
            for p in vendor_params:
                name, decode = _SWARMD_DECODERS[p.pid]
                if name not in kw:
                    kw[name] = decode(p, little)
        elif vendor_params:
            # another vendor's 0x8A0x PIDs mean something else to it: keep them opaque, in
            # wire order, in one pass. (A sort keyed by ``params.index`` was quadratic: one
            # forged 64 KiB DATA(p) of 16,000 parameters under an invented prefix cost
            # seconds of the daemon's loop; docs/security.md, "Foreign participants".)
            extras = [p for p in plist.params if p.pid not in _MODELLED]
        return cls(guid, extra_parameters=tuple(extras), **kw)  # type: ignore[arg-type]


def _decode_guid_prefix(p: Parameter, little: bool) -> GuidPrefix:
    if len(p.value) < 16:
        raise DecodeError(f"PID_PARTICIPANT_GUID has {len(p.value)} bytes, needs 16")
    return GuidPrefix(p.value[:12])


def _decode_protocol_version(p: Parameter, little: bool) -> ProtocolVersion:
    if len(p.value) < 2:
        raise DecodeError("PID_PROTOCOL_VERSION too short")
    return ProtocolVersion(p.value[0], p.value[1])


def _decode_vendor_id(p: Parameter, little: bool) -> VendorId:
    if len(p.value) < 2:
        raise DecodeError("PID_VENDORID too short")
    return VendorId(p.value[:2])


def _decode_link_quality(p: Parameter, little: bool) -> int:
    q = value_u32(p, little)
    if q > MAX_LINK_QUALITY_PERMILLE:
        raise DecodeError(f"swarmd link quality {q} exceeds {MAX_LINK_QUALITY_PERMILLE}")
    return q


def _decode_vouched(p: Parameter, little: bool) -> Vouch:
    window_ms = value_u32(p, little)
    if window_ms > MAX_VOUCH_WINDOW_MS:
        raise DecodeError(f"swarmd vouch window {window_ms} ms exceeds {MAX_VOUCH_WINDOW_MS}")
    return Vouch(window_ms, value_octets(Parameter(p.pid, p.value[4:]), little))


_Decoder = Callable[[Parameter, bool], object]
_LOCATOR_FIELDS: Final = frozenset(
    {
        "metatraffic_unicast_locators",
        "metatraffic_multicast_locators",
        "default_unicast_locators",
        "default_multicast_locators",
    }
)
# PID -> (SpdpParticipant field, decoder). Dispatch by dict: one lookup per parameter.
_FIELD_DECODERS: Final[dict[int, tuple[str, _Decoder]]] = {
    Pid.PARTICIPANT_GUID: ("guid_prefix", _decode_guid_prefix),
    Pid.PROTOCOL_VERSION: ("protocol_version", _decode_protocol_version),
    Pid.VENDORID: ("vendor_id", _decode_vendor_id),
    Pid.DOMAIN_ID: ("domain_id", value_u32),
    Pid.DOMAIN_TAG: ("domain_tag", value_string),
    Pid.METATRAFFIC_UNICAST_LOCATOR: ("metatraffic_unicast_locators", value_locator),
    Pid.METATRAFFIC_MULTICAST_LOCATOR: ("metatraffic_multicast_locators", value_locator),
    Pid.DEFAULT_UNICAST_LOCATOR: ("default_unicast_locators", value_locator),
    Pid.DEFAULT_MULTICAST_LOCATOR: ("default_multicast_locators", value_locator),
    Pid.PARTICIPANT_LEASE_DURATION: ("lease_duration", value_duration),
    Pid.BUILTIN_ENDPOINT_SET: ("builtin_endpoints", value_u32),
    Pid.PARTICIPANT_BUILTIN_ENDPOINTS: ("legacy_builtin_endpoints", value_u32),
    Pid.PARTICIPANT_MANUAL_LIVELINESS_COUNT: ("manual_liveliness_count", value_i32),
    Pid.ENTITY_NAME: ("entity_name", value_string),
    Pid.USER_DATA: ("user_data", value_octets),
    Pid.PROPERTY_LIST: ("properties", value_properties),
}
_SWARMD_DECODERS: Final[dict[int, tuple[str, _Decoder]]] = {
    PID_SWARMD_BUNDLE_DIGEST: ("bundle_digest", value_octets),
    PID_SWARMD_HEARD: ("heard", value_octets),
    PID_SWARMD_LINK_QUALITY: ("link_quality_permille", _decode_link_quality),
    PID_SWARMD_AUTHENTICATOR: ("authenticator", lambda p, _little: p.value),
    PID_SWARMD_VOUCHED: ("vouched", _decode_vouched),
    PID_SWARMD_ROS2_ALIVE: ("ros2_alive", value_octets),
}
# PIDs that SpdpParticipant models as fields; anything else lands in extra_parameters
_MODELLED: Final = frozenset(_FIELD_DECODERS)


@dataclass(frozen=True, slots=True)
class SpdpAlive:
    """A DATA(p) as received: the participant and the context its message gave it."""

    participant: SpdpParticipant
    sequence_number: int
    destination: GuidPrefix | None = None  # INFO_DST, None when sent to everyone
    timestamp: Time | None = None


@dataclass(frozen=True, slots=True)
class SpdpDisposed:
    """A DATA(p[UD]): the participant with this prefix has left."""

    guid_prefix: GuidPrefix
    sequence_number: int
    destination: GuidPrefix | None = None
    timestamp: Time | None = None


SpdpSample = SpdpAlive | SpdpDisposed

# SPDP samples one datagram may carry (review 16). swarmd sends one DATA(p) or DATA(p[UD]) a
# datagram, and so do the stock stacks; a datagram of hundreds is someone making one
# datagram do the work (and the events, and the log lines) of hundreds: a captured
# member's, under one signature, or an invented participant's, within the decode budget.
MAX_SPDP_SAMPLES: Final = 4


def _decode_payload_plist(payload: bytes) -> ParameterList:
    encapsulation = payload[:2]
    if encapsulation == PL_CDR_LE:
        little = True
    elif encapsulation == PL_CDR_BE:
        little = False
    else:
        raise DecodeError(f"SPDP payload encapsulation {encapsulation.hex()} is not PL_CDR")
    return pull_parameter_list(Reader(payload, 4, little=little))


def _spdp_sample(
    header: Header, data: Data, destination: GuidPrefix | None, timestamp: Time | None
) -> SpdpSample:
    status = 0
    key_hash: bytes | None = None
    if data.inline_qos is not None:
        info = data.inline_qos.get(Pid.STATUS_INFO)
        if info is not None:
            if len(info.value) < 4:
                raise DecodeError("PID_STATUS_INFO too short")
            status = info.value[3]
        kh = data.inline_qos.get(Pid.KEY_HASH)
        if kh is not None:
            if len(kh.value) < 16:
                raise DecodeError("PID_KEY_HASH too short")
            key_hash = kh.value[:16]
    if status & (STATUS_INFO_DISPOSED | STATUS_INFO_UNREGISTERED):
        if key_hash is None and data.serialized_payload is not None:
            key_plist = _decode_payload_plist(data.serialized_payload)
            guid = key_plist.get(Pid.PARTICIPANT_GUID)
            if guid is not None and len(guid.value) >= 16:
                key_hash = guid.value[:16]
        if key_hash is None:
            raise DecodeError("DATA(p[UD]) carries neither PID_KEY_HASH nor a participant GUID key")
        prefix = GuidPrefix(key_hash[:12])
        if prefix != header.guid_prefix:
            raise DecodeError(f"DATA(p[UD]) for {prefix} sent by {header.guid_prefix}")
        return SpdpDisposed(prefix, data.writer_sn, destination, timestamp)
    if data.serialized_payload is None or data.key:
        raise DecodeError("DATA(p) without serialized data")
    participant = SpdpParticipant.from_parameters(_decode_payload_plist(data.serialized_payload))
    if participant.guid_prefix != header.guid_prefix:
        # Cyclone ignores such a sample too ("mismatch with RTPS source", ddsi_discovery_spdp.c)
        raise DecodeError(
            f"participant GUID {participant.guid_prefix} differs from RTPS source "
            f"{header.guid_prefix}"
        )
    return SpdpAlive(participant, data.writer_sn, destination, timestamp)


def decode_spdp(datagram: bytes) -> tuple[Header, list[SpdpSample]]:
    """Decode a datagram and return its header and every SPDP sample in it.

    Submessages other than SPDP DATA are ignored (but must be well-formed). More than
    ``MAX_SPDP_SAMPLES`` SPDP DATA in one datagram is refused before any is read. Raises
    ``DecodeError`` and nothing else, for any input.
    """
    try:
        message = decode_message(datagram)
        spdp = sum(
            1
            for sm in message.submessages
            if isinstance(sm, Data) and sm.writer_id == ENTITYID_SPDP_WRITER
        )
        if spdp > MAX_SPDP_SAMPLES:
            raise DecodeError(f"{spdp} SPDP samples in one datagram, more than {MAX_SPDP_SAMPLES}")
        destination: GuidPrefix | None = None
        timestamp: Time | None = None
        samples: list[SpdpSample] = []
        for sm in message.submessages:
            if isinstance(sm, InfoDst):
                destination = None if sm.guid_prefix == UNKNOWN_GUID_PREFIX else sm.guid_prefix
            elif isinstance(sm, InfoTs):
                timestamp = sm.timestamp
            elif isinstance(sm, Data) and sm.writer_id == ENTITYID_SPDP_WRITER:
                samples.append(_spdp_sample(message.header, sm, destination, timestamp))
        return message.header, samples
    except DecodeError:
        raise
    except (
        ValueError,
        IndexError,
        struct.error,
        OverflowError,
        TypeError,
    ) as exc:  # pragma: no cover
        raise DecodeError(f"malformed SPDP message: {exc}") from None


def _prefix_submessages(destination: GuidPrefix | None, timestamp: Time | None) -> list[Submessage]:
    out: list[Submessage] = []
    if destination is not None:
        out.append(InfoDst(destination))
    out.append(InfoTs(timestamp))
    return out


def encode_spdp(
    participant: SpdpParticipant,
    *,
    sequence_number: int,
    timestamp: Time | None,
    destination: GuidPrefix | None = None,
) -> bytes:
    """One datagram: [INFO_DST] + INFO_TS + DATA(p). ``timestamp`` None sends INFO_TS with I set."""
    if sequence_number < 1:
        raise ValueError("SPDP sequence numbers start at 1 (Fast DDS drops SN <= 0)")
    w = Writer(little=True)
    w.push_bytes(PL_CDR_LE + b"\x00\x00")
    push_parameter_list(w, participant.to_parameters(little=True))
    data = Data(
        ENTITYID_SPDP_READER,
        ENTITYID_SPDP_WRITER,
        sequence_number,
        serialized_payload=w.getvalue(),
    )
    header = Header(participant.protocol_version, participant.vendor_id, participant.guid_prefix)
    return encode_message(header, [*_prefix_submessages(destination, timestamp), data])


def encode_spdp_dispose(
    guid_prefix: GuidPrefix,
    *,
    sequence_number: int,
    timestamp: Time | None,
    destination: GuidPrefix | None = None,
    vendor_id: VendorId = VENDORID_SWARMD,
    protocol_version: ProtocolVersion = PROTOCOLVERSION_SWARMD,
    authenticator: bytes | None = None,
) -> bytes:
    """One datagram: [INFO_DST] + INFO_TS + DATA(p[UD]) (flags E|Q|K, reference 1.11).

    ``authenticator`` goes last in the key payload's parameter list, so it ends the datagram
    as in a DATA(p) (swarmd.auth.spdp)."""
    if sequence_number < 1:
        raise ValueError("SPDP sequence numbers start at 1")
    guid = guid_prefix.value + ENTITYID_PARTICIPANT.value
    key = Writer(little=True)
    key.push_bytes(PL_CDR_LE + b"\x00\x00")
    key_params = [Parameter(Pid.PARTICIPANT_GUID, guid)]
    if authenticator is not None:
        key_params.append(Parameter(PID_SWARMD_AUTHENTICATOR, authenticator))
    push_parameter_list(key, tuple(key_params))
    status = STATUS_INFO_DISPOSED | STATUS_INFO_UNREGISTERED
    data = Data(
        ENTITYID_SPDP_READER,
        ENTITYID_SPDP_WRITER,
        sequence_number,
        inline_qos=ParameterList(
            (Parameter(Pid.KEY_HASH, guid), Parameter(Pid.STATUS_INFO, bytes((0, 0, 0, status)))),
        ),
        serialized_payload=key.getvalue(),
        key=True,
    )
    header = Header(protocol_version, vendor_id, guid_prefix)
    return encode_message(header, [*_prefix_submessages(destination, timestamp), data])
