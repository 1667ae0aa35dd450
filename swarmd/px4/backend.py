"""The seam between swarmd's PX4 logic and the wire that reaches the flight controller.

Readiness (``readiness.py``) and take-off (``takeoff.py``) speak only
``swarmd.px4.messages``; a backend turns its wire into those observations and
``VehicleCommand`` into its wire. Two backends fit:

- ``MavlinkBackend`` (``mavlink_backend.py``): COMMAND_LONG / COMMAND_ACK and PX4's telemetry
  streams over UDP or a UART, plus the companion's 1 Hz HEARTBEAT (PX4 logs "Onboard
  controller lost" without it).
- ``XrceBackend`` (``xrce_backend.py``, modes ``xrce-agent`` and ``xrce-client``):
  ``VehicleCommand`` -> ``rt/fmu/in/vehicle_command`` (``from_external=True``), and
  ``rt/fmu/out/vehicle_status[_vN]``, ``vehicle_land_detected``, ``vehicle_gps_position``,
  ``home_position``, ``battery_status``, ``vehicle_command_ack`` -> the same observations
  (``xrce_translate.py``, table in docs/px4.md). Nothing in readiness or take-off changes.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Protocol

from swarmd.px4.messages import Observation, VehicleCommand

ObservationSink = Callable[[Observation, float], None]
"""Called on the event loop with each autopilot observation and ``loop.time()``."""


class VehicleBackend(Protocol):
    """How the bridge reaches one vehicle."""

    name: str  # "mavlink" | "xrce-dds"

    async def start(self, sink: ObservationSink) -> None:
        """Open the link; deliver every observation from the autopilot to ``sink``."""
        ...

    def send(self, command: VehicleCommand) -> None:
        """Queue one command for the autopilot; never blocks, never raises on I/O."""
        ...

    def stats(self) -> dict[str, Any]:
        """Counters for ``swarmctl status`` (JSON-ready)."""
        ...

    async def close(self) -> None:
        """Stop sending and release the link; idempotent."""
        ...
