"""The sans-IO discovery engine (paper section 4): passive timer, SPDP, preloaded EDP.

No I/O, no clock, no asyncio: see ``engine.py`` for the theory of operation.
"""

from swarmd.discovery.config import EngineConfig
from swarmd.discovery.engine import DiscoveryEngine
from swarmd.discovery.events import (
    DropReason,
    Event,
    ForeignParticipantSeen,
    PacketDropped,
    PeerDiscovered,
    PeerLocatorsChanged,
    PeerLost,
    PeerRestarted,
    PeerRos2Liveness,
    PhaseChanged,
)
from swarmd.discovery.inputs import LinkSample
from swarmd.discovery.peers import PeerState
from swarmd.discovery.phases import Phase
from swarmd.discovery.views import ForeignView, PeerView

__all__ = [
    "DiscoveryEngine",
    "DropReason",
    "EngineConfig",
    "Event",
    "ForeignParticipantSeen",
    "ForeignView",
    "LinkSample",
    "PacketDropped",
    "PeerDiscovered",
    "PeerLocatorsChanged",
    "PeerLost",
    "PeerRos2Liveness",
    "PeerRestarted",
    "PeerState",
    "PeerView",
    "Phase",
    "PhaseChanged",
]
