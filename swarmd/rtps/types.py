"""RTPS identity and time primitives: GUID prefixes, entity ids, GUIDs, vendor ids,
protocol versions, sequence numbers, and the Time_t/Duration_t pair.

DDSI-RTPS 2.5 section 9.3.1 (GUID), 9.3.2 (Time_t, Duration_t, SequenceNumber_t).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

FRACTION_PER_SECOND: Final = 1 << 32


@dataclass(frozen=True, slots=True)
class GuidPrefix:
    """The 12-byte prefix shared by every entity of one participant (spec 9.3.1.5)."""

    value: bytes

    def __post_init__(self) -> None:
        if len(self.value) != 12:
            raise ValueError(f"GUID prefix must be 12 bytes, got {len(self.value)}")

    def __str__(self) -> str:
        # Cyclone's trace format: three 32-bit big-endian words in hex without leading zeros
        v = self.value
        return ":".join(f"{int.from_bytes(v[i : i + 4], 'big'):x}" for i in (0, 4, 8))

    @classmethod
    def parse(cls, text: str) -> GuidPrefix:
        """Parse the ``a:b:c`` word form (Cyclone traces) or 24 hex digits."""
        if ":" in text:
            words = text.split(":")
            if len(words) != 3:
                raise ValueError(f"GUID prefix needs 3 words, got {text!r}")
            return cls(b"".join(int(w, 16).to_bytes(4, "big") for w in words))
        return cls(bytes.fromhex(text))

    def hex(self) -> str:
        return self.value.hex()


UNKNOWN_GUID_PREFIX: Final = GuidPrefix(bytes(12))


@dataclass(frozen=True, slots=True)
class EntityId:
    """A 4-byte entity id: 3-byte key and 1 kind byte, written as raw octets (spec 9.3.1.2)."""

    value: bytes

    def __post_init__(self) -> None:
        if len(self.value) != 4:
            raise ValueError(f"entity id must be 4 bytes, got {len(self.value)}")

    @property
    def key(self) -> bytes:
        return self.value[:3]

    @property
    def kind(self) -> int:
        return self.value[3]

    @property
    def is_builtin(self) -> bool:
        return (self.value[3] & 0xC0) == 0xC0

    def __str__(self) -> str:
        return f"{int.from_bytes(self.value, 'big'):x}"

    @classmethod
    def of(cls, number: int) -> EntityId:
        return cls(number.to_bytes(4, "big"))

    @classmethod
    def user(cls, key: int, kind: int) -> EntityId:
        """An application entity id from a 24-bit key and a kind byte (see ``EntityKind``)."""
        if not 0 <= key < (1 << 24):
            raise ValueError(f"entity key {key} outside 24 bits")
        return cls(key.to_bytes(3, "big") + bytes([kind]))


class EntityKind:
    """Entity kind octets (spec 9.3.1.2, table 9.1)."""

    UNKNOWN: Final = 0x00
    PARTICIPANT: Final = 0x01
    WRITER_WITH_KEY: Final = 0x02
    WRITER_NO_KEY: Final = 0x03
    READER_NO_KEY: Final = 0x04
    READER_WITH_KEY: Final = 0x07
    BUILTIN_FLAG: Final = 0xC0


ENTITYID_UNKNOWN: Final = EntityId(bytes(4))
ENTITYID_PARTICIPANT: Final = EntityId.of(0x000001C1)
ENTITYID_SEDP_TOPICS_WRITER: Final = EntityId.of(0x000002C2)
ENTITYID_SEDP_TOPICS_READER: Final = EntityId.of(0x000002C7)
ENTITYID_SEDP_PUBLICATIONS_WRITER: Final = EntityId.of(0x000003C2)
ENTITYID_SEDP_PUBLICATIONS_READER: Final = EntityId.of(0x000003C7)
ENTITYID_SEDP_SUBSCRIPTIONS_WRITER: Final = EntityId.of(0x000004C2)
ENTITYID_SEDP_SUBSCRIPTIONS_READER: Final = EntityId.of(0x000004C7)
ENTITYID_SPDP_WRITER: Final = EntityId.of(0x000100C2)
ENTITYID_SPDP_READER: Final = EntityId.of(0x000100C7)
ENTITYID_P2P_MESSAGE_WRITER: Final = EntityId.of(0x000200C2)
ENTITYID_P2P_MESSAGE_READER: Final = EntityId.of(0x000200C7)


@dataclass(frozen=True, slots=True)
class Guid:
    """A full 16-byte GUID: participant prefix plus entity id."""

    prefix: GuidPrefix
    entity_id: EntityId

    def to_bytes(self) -> bytes:
        return self.prefix.value + self.entity_id.value

    @classmethod
    def from_bytes(cls, data: bytes) -> Guid:
        if len(data) != 16:
            raise ValueError(f"GUID must be 16 bytes, got {len(data)}")
        return cls(GuidPrefix(data[:12]), EntityId(data[12:]))

    def __str__(self) -> str:
        return f"{self.prefix}:{self.entity_id}"


@dataclass(frozen=True, slots=True)
class VendorId:
    """Two-octet vendor id from the DDS Foundation registry (spec 8.3.3.1.3)."""

    value: bytes

    def __post_init__(self) -> None:
        if len(self.value) != 2:
            raise ValueError(f"vendor id must be 2 bytes, got {len(self.value)}")

    def __str__(self) -> str:
        return f"{self.value[0]:02x}.{self.value[1]:02x}"

    @property
    def name(self) -> str:
        return VENDOR_NAMES.get(self.value, f"unregistered {self}")


VENDORID_UNKNOWN: Final = VendorId(b"\x00\x00")
VENDORID_RTI: Final = VendorId(b"\x01\x01")
VENDORID_OPENSPLICE: Final = VendorId(b"\x01\x02")
VENDORID_OPENDDS: Final = VendorId(b"\x01\x03")
VENDORID_FASTDDS: Final = VendorId(b"\x01\x0f")
VENDORID_CYCLONE: Final = VendorId(b"\x01\x10")
# swarmd's own: "SW" in ASCII. The DDS Foundation assigns ids from the 01.xx block, so 53.57
# cannot collide with a registered vendor now or later; 00.00 (unknown) is shared by every
# unidentified stack, whose vendor PIDs we would then misread. See docs/wire.md.
VENDORID_SWARMD: Final = VendorId(b"SW")

VENDOR_NAMES: Final[dict[bytes, str]] = {
    b"\x00\x00": "unknown",
    b"\x01\x01": "RTI Connext DDS",
    b"\x01\x02": "ADLINK OpenSplice",
    b"\x01\x03": "OCI OpenDDS",
    b"\x01\x04": "MilSoft",
    b"\x01\x05": "Kongsberg InterCOM",
    b"\x01\x06": "TwinOaks CoreDX",
    b"\x01\x07": "Lakota",
    b"\x01\x08": "ICOUP",
    b"\x01\x09": "ETRI",
    b"\x01\x0a": "RTI Connext Micro",
    b"\x01\x0b": "ADLINK Cafe",
    b"\x01\x0c": "PrismTech",
    b"\x01\x0d": "ADLINK Lite",
    b"\x01\x0e": "Technicolor",
    b"\x01\x0f": "eProsima Fast DDS",
    b"\x01\x10": "Eclipse Cyclone DDS",
    b"\x01\x11": "GurumNetworks GurumDDS",
    b"SW": "swarmd",
}


@dataclass(frozen=True, slots=True)
class ProtocolVersion:
    major: int
    minor: int

    def __str__(self) -> str:
        return f"{self.major}.{self.minor}"


# 2.3 is accepted by Cyclone (minor >= 1) and Fast DDS (major == 2); see reference section 1.1
PROTOCOLVERSION_SWARMD: Final = ProtocolVersion(2, 3)

SEQUENCENUMBER_UNKNOWN: Final = -(1 << 32)  # {high=-1, low=0}


def split_sequence_number(sn: int) -> tuple[int, int]:
    """SequenceNumber_t as {high: int32, low: uint32}."""
    return sn >> 32, sn & 0xFFFFFFFF


def join_sequence_number(high: int, low: int) -> int:
    return (high << 32) | low


@dataclass(frozen=True, slots=True, order=True)
class Duration:
    """Duration_t / Time_t on the wire: whole seconds and 2^-32 fractions (spec 9.3.2)."""

    seconds: int
    fraction: int = 0

    @classmethod
    def from_seconds(cls, value: float) -> Duration:
        whole = int(value // 1)
        frac = round((value - whole) * FRACTION_PER_SECOND)
        if frac >= FRACTION_PER_SECOND:
            whole, frac = whole + 1, 0
        return cls(whole, frac)

    def total_seconds(self) -> float:
        return self.seconds + self.fraction / FRACTION_PER_SECOND

    @property
    def is_infinite(self) -> bool:
        return self == DURATION_INFINITE


DURATION_INFINITE: Final = Duration(0x7FFFFFFF, 0xFFFFFFFF)
Time = Duration  # Time_t has the same wire shape; kept as an alias so signatures say which is meant
