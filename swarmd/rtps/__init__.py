"""The RTPS wire codec: pure functions over bytes, no I/O, no clock.

Decoders raise ``DecodeError`` and nothing else, for any input whatsoever.
"""

from swarmd.rtps.errors import DecodeError
from swarmd.rtps.locator import Locator
from swarmd.rtps.message import (
    AckNack,
    Data,
    Gap,
    Header,
    Heartbeat,
    InfoDst,
    InfoTs,
    Message,
    SequenceNumberSet,
    SkippedSubmessage,
    Submessage,
    decode_message,
    encode_message,
)
from swarmd.rtps.parameters import Parameter, ParameterList, Pid
from swarmd.rtps.spdp import (
    BES_SPDP_ONLY,
    SpdpAlive,
    SpdpDisposed,
    SpdpParticipant,
    SpdpSample,
    decode_spdp,
    encode_spdp,
    encode_spdp_dispose,
)
from swarmd.rtps.types import (
    VENDORID_SWARMD,
    Duration,
    EntityId,
    Guid,
    GuidPrefix,
    ProtocolVersion,
    Time,
    VendorId,
)

__all__ = [
    "BES_SPDP_ONLY",
    "VENDORID_SWARMD",
    "AckNack",
    "Data",
    "DecodeError",
    "Duration",
    "EntityId",
    "Gap",
    "Guid",
    "GuidPrefix",
    "Header",
    "Heartbeat",
    "InfoDst",
    "InfoTs",
    "Locator",
    "Message",
    "Parameter",
    "ParameterList",
    "Pid",
    "ProtocolVersion",
    "SequenceNumberSet",
    "SkippedSubmessage",
    "SpdpAlive",
    "SpdpDisposed",
    "SpdpParticipant",
    "SpdpSample",
    "Submessage",
    "Time",
    "VendorId",
    "decode_message",
    "decode_spdp",
    "encode_message",
    "encode_spdp",
    "encode_spdp_dispose",
]
