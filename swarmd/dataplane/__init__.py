"""The RTPS user-data plane: readiness, commands and outcomes between preloaded endpoints.

Sans-IO (no asyncio, socket or time); ``DataPlane`` is the one class an owner drives.
See docs/dataplane.md.

Its names load when first used (PEP 562): a caller that needs one leaf, such as
``swarmd.config`` checking a period against ``validity.MIN_REPORT_PERIOD_MS``, does not load
the whole plane before the daemon's discovery engine starts (docs/benchmarks.md, "Daemon
start-up").
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
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

# each name -> the module of this package that defines it
_HOME: dict[str, str] = {
    "CommandIdsExhausted": "commands",
    "ForeignCommandId": "commands",
    "TOPIC_COMMAND": "endpoints",
    "TOPIC_OUTCOME": "endpoints",
    "TOPIC_READY": "endpoints",
    "CommandCopyVoided": "events",
    "CommandReceived": "events",
    "DataPlaneEvent": "events",
    "Event": "events",
    "OutcomeReceived": "events",
    "PacketDropped": "events",
    "ReadinessReceived": "events",
    "MAX_EXECUTED_COMMANDS": "ledger",
    "PairKeys": "pairs",
    "DataPlane": "plane",
    "Command": "types",
    "CommandKind": "types",
    "CommandOutcome": "types",
    "CommandResult": "types",
    "PayloadError": "types",
    "Readiness": "types",
    "decode_sample": "types",
    "encode_sample": "types",
}

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


def __getattr__(name: str) -> Any:
    home = _HOME.get(name)
    if home is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f"{__name__}.{home}"), name)
    globals()[name] = value  # once: later lookups are plain
    return value
