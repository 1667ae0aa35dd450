"""The RTPS user-data plane: readiness, commands and outcomes between preloaded endpoints.

Sans-IO (no asyncio, socket or time); ``DataPlane`` is the one class an owner drives.
See docs/dataplane.md.
"""

from swarmd.dataplane.commands import CommandIdsExhausted, ForeignCommandId
from swarmd.dataplane.endpoints import TOPIC_COMMAND, TOPIC_OUTCOME, TOPIC_READY
from swarmd.dataplane.events import (
    CommandCopyVoided,
    CommandReceived,
    DataPlaneEvent,
    Event,
    OutcomeReceived,
    PacketDropped,
    ReadinessReceived,
)
from swarmd.dataplane.ledger import MAX_EXECUTED_COMMANDS
from swarmd.dataplane.pairs import PairKeys
from swarmd.dataplane.plane import DataPlane
from swarmd.dataplane.types import (
    Command,
    CommandKind,
    CommandOutcome,
    CommandResult,
    PayloadError,
    Readiness,
    decode_sample,
    encode_sample,
)

__all__ = [
    "MAX_EXECUTED_COMMANDS",
    "TOPIC_COMMAND",
    "TOPIC_OUTCOME",
    "TOPIC_READY",
    "Command",
    "CommandCopyVoided",
    "CommandKind",
    "CommandOutcome",
    "CommandReceived",
    "CommandResult",
    "DataPlane",
    "DataPlaneEvent",
    "CommandIdsExhausted",
    "ForeignCommandId",
    "Event",
    "OutcomeReceived",
    "PacketDropped",
    "PairKeys",
    "PayloadError",
    "Readiness",
    "ReadinessReceived",
    "decode_sample",
    "encode_sample",
]
