"""DDS-XRCE 1.0 (OMG formal/20-02-01) constants: message and submessage ids, flags, object
kinds, status codes and object ids (§8.3.2, §8.3.4, §7.7.3), shared by the submessage codecs
(``swarmd.xrce.submessages``) and the message codec (``swarmd.xrce.message``)."""

from __future__ import annotations

from enum import IntEnum
from typing import Final

XRCE_COOKIE: Final = b"XRCE"
XRCE_VERSION: Final = b"\x01\x00"  # §8.3.5.1 xrce_version 1.0
VENDOR_SWARMD: Final = b"\x0f\x53"  # not eProsima's 01 0f; no OMG vendor id is assigned to us

SESSION_ID_NONE_WITH_KEY: Final = 0x00
SESSION_ID_NONE_WITHOUT_KEY: Final = 0x80  # §8.3.2.1: session-less, key left out
STREAM_NONE: Final = 0x00
STREAM_BEST_EFFORT_MIN: Final = 0x01  # §8.3.2.2: 0x01..0x7F best effort, 0x80..0xFF reliable
STREAM_RELIABLE_MIN: Final = 0x80

FLAG_E: Final = 0x01  # little-endian payload
FLAG_REUSE: Final = 0x02  # CREATE §8.3.5.2
FLAG_REPLACE: Final = 0x04
FLAG_LAST_FRAGMENT: Final = 0x02  # FRAGMENT §8.3.5.14
FORMAT_MASK: Final = 0x0E  # WRITE_DATA / DATA data format §8.3.5.8
FORMAT_DATA: Final = 0x00

MAX_SUBMESSAGES: Final = 64  # a 512-byte MTU holds at most 508 / 4 = 127 headers; bound work


class SubmessageId(IntEnum):
    """§8.3.4.1."""

    CREATE_CLIENT = 0
    CREATE = 1
    GET_INFO = 2
    DELETE = 3
    STATUS_AGENT = 4
    STATUS = 5
    INFO = 6
    WRITE_DATA = 7
    READ_DATA = 8
    DATA = 9
    ACKNACK = 10
    HEARTBEAT = 11
    RESET = 12
    FRAGMENT = 13
    TIMESTAMP = 14
    TIMESTAMP_REPLY = 15
    PERFORMANCE = 16


class ObjectKind(IntEnum):
    """§7.7.2 ObjectKind (low nibble of an ObjectId)."""

    INVALID = 0x00
    PARTICIPANT = 0x01
    TOPIC = 0x02
    PUBLISHER = 0x03
    SUBSCRIBER = 0x04
    DATAWRITER = 0x05
    DATAREADER = 0x06
    REQUESTER = 0x07
    REPLIER = 0x08
    TYPE = 0x0A
    QOSPROFILE = 0x0B
    APPLICATION = 0x0C
    AGENT = 0x0D
    CLIENT = 0x0E


class Repr(IntEnum):
    """§7.7.3 representation formats."""

    REF = 0x01
    XML = 0x02
    BIN = 0x03


class Status(IntEnum):
    """§8.3.5.6 ResultStatus.status."""

    OK = 0x00
    OK_MATCHED = 0x01
    ERR_DDS_ERROR = 0x80
    ERR_MISMATCH = 0x81
    ERR_ALREADY_EXISTS = 0x82
    ERR_DENIED = 0x83
    ERR_UNKNOWN_REFERENCE = 0x84
    ERR_INVALID_DATA = 0x85
    ERR_INCOMPATIBLE = 0x86
    ERR_RESOURCES = 0x87


INFO_CONFIGURATION: Final = 0x01
INFO_ACTIVITY: Final = 0x02
OBJECT_ID_AGENT: Final = 0xFFFD  # id 0xFFF, kind AGENT: the GET_INFO target of PX4's ping
OBJECT_ID_CLIENT: Final = 0xFFFE  # id 0xFFF, kind CLIENT: DELETE of the session


def object_id(ident: int, kind: int) -> int:
    """§7.7.2: the 2-octet ObjectId is a 12-bit id and a 4-bit kind, big-endian."""
    return ((ident & 0xFFF) << 4) | (kind & 0xF)


def object_kind(oid: int) -> int:
    return oid & 0xF


def object_ident(oid: int) -> int:
    return oid >> 4
