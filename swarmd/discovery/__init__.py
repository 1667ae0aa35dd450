"""The sans-IO discovery engine (paper section 4): passive timer, SPDP, preloaded EDP.

No I/O, no clock, no asyncio: see ``engine.py`` for the theory of operation.
"""

from swarmd.discovery.config import EngineConfig
from swarmd.discovery.engine import DiscoveryEngine
from swarmd.discovery.events import (
    Event,
    ForeignParticipantSeen,
    PacketDropped,
    PeerDiscovered,
    PeerLost,
    PhaseChanged,
)
from swarmd.discovery.phases import Phase

__all__ = [
    "DiscoveryEngine",
    "EngineConfig",
    "Event",
    "ForeignParticipantSeen",
    "PacketDropped",
    "PeerDiscovered",
    "PeerLost",
    "Phase",
    "PhaseChanged",
]
