"""The unit the endpoints hand to the plane: one submessage for one remote participant."""

from __future__ import annotations

from dataclasses import dataclass

from swarmd.rtps.message import Submessage
from swarmd.rtps.types import GuidPrefix


@dataclass(frozen=True, slots=True)
class Outgoing:
    """``submessage`` is for participant ``peer``; the plane batches these per peer into
    datagrams behind an INFO_DST, so endpoints never see addresses."""

    peer: GuidPrefix
    submessage: Submessage
