"""A PX4-like XRCE client for the loopback tests: swarmd's own client engine
(``swarmd.xrce.client.XrceClient``) on a real UDP socket, publishing a ready vehicle's topics
(PX4 1.16 layouts) with ``vehicle_status.system_id`` = its system id, and recording the
``vehicle_command`` samples the agent sends it. Not the PX4 stand-in (that flies; this only
stands ready): enough to see which session a command reaches and whether readiness moves."""

from __future__ import annotations

import asyncio
import contextlib
import socket
from collections.abc import Callable
from typing import Final

from swarmd.driver import Driver
from swarmd.xrce.client import XrceClient
from swarmd.xrce.events import Address, SampleReceived, XrceEvent
from swarmd.xrce.px4 import TOPIC_MESSAGES, dds_topic, dds_type, encode_fields
from swarmd.xrce.px4_layouts import LAYOUTS

RELEASE: Final = "1.16"
PUBLISH_PERIOD_S: Final = 0.2
COMMAND_TOPIC: Final = dds_topic("vehicle_command", "in")
# a vehicle on the ground, ready: PREARM passed, a full battery, a 3D fix, landed
READY_SAMPLES: Final[dict[str, dict[str, float | int | bool]]] = {
    "vehicle_status": {"nav_state": 4, "pre_flight_checks_pass": True},
    "battery_status": {"remaining": 0.9, "voltage_v": 16.0},
    "vehicle_land_detected": {"landed": True},
    "vehicle_gps_position": {
        "fix_type": 3, "satellites_used": 12, "eph": 0.9,
        "latitude_deg": 47.3977418, "longitude_deg": 8.5455938, "altitude_msl_m": 488.0,
    },
}  # fmt: skip


def _topic(topic: str) -> str:
    return dds_topic(topic, "out", LAYOUTS[RELEASE][TOPIC_MESSAGES[topic]][1])


def _sample(topic: str, values: dict[str, float | int | bool]) -> bytes:
    return encode_fields(LAYOUTS[RELEASE][TOPIC_MESSAGES[topic]], values)


class _Datagrams(asyncio.DatagramProtocol):
    def __init__(self, vehicle: XrceVehicle) -> None:
        self.vehicle = vehicle

    def datagram_received(self, data: bytes, addr: tuple[str, int]) -> None:
        if self.vehicle.driver is not None:
            self.vehicle.driver.datagram_received(data, (addr[0], addr[1]))


class XrceVehicle:
    """One client process: ``start`` opens its socket and session, publishes every 0.2 s."""

    def __init__(self, key: int, system_id: int, agent: tuple[str, int]) -> None:
        self.key = key
        self.system_id = system_id
        self.agent = agent
        self.engine = XrceClient(
            key.to_bytes(4, "big"),
            subscriptions={COMMAND_TOPIC: dds_type("VehicleCommand")},
            publications={_topic(t): dds_type(TOPIC_MESSAGES[t]) for t in READY_SAMPLES},
            participant_name="/px4_micro_xrce_dds",
        )
        self.commands: list[bytes] = []
        self.driver: Driver[bytes, tuple[bytes, Address], XrceEvent] | None = None
        self._transport: asyncio.DatagramTransport | None = None
        self._task: asyncio.Task[None] | None = None

    @property
    def address(self) -> tuple[str, int]:
        assert self._transport is not None
        host, port = self._transport.get_extra_info("sockname")[:2]
        return (host, port)

    async def start(self, sock: socket.socket | None = None) -> None:
        """Open the session; ``sock``: a bound UDP socket to use (another namespace's)."""
        loop = asyncio.get_running_loop()
        if sock is None:
            self._transport, _ = await loop.create_datagram_endpoint(
                lambda: _Datagrams(self), remote_addr=self.agent
            )
        else:
            sock.connect(self.agent)
            sock.setblocking(False)
            self._transport, _ = await loop.create_datagram_endpoint(
                lambda: _Datagrams(self), sock=sock
            )
        self.driver = Driver(
            self.engine, transmit=self._send, on_event=self._event, name="vehicle", loop=loop
        )
        engine, agent = self.engine, self.agent
        self.driver.call(lambda now: engine.connect(agent, now))
        self._task = loop.create_task(self._publish())

    def kill(self) -> None:
        """Gone without a DELETE, as a crashed or rebooted PX4."""
        if self._task is not None:
            self._task.cancel()
        if self.driver is not None:
            self.driver.close()
            self.driver = None
        if self._transport is not None:
            self._transport.close()
            self._transport = None

    async def _publish(self) -> None:
        samples = {
            _topic(t): _sample(
                t, {**v, "system_id": self.system_id} if t == "vehicle_status" else v
            )
            for t, v in READY_SAMPLES.items()
        }
        with contextlib.suppress(asyncio.CancelledError):
            while True:
                await asyncio.sleep(PUBLISH_PERIOD_S)
                if self.driver is None or self.engine.state != "established":
                    continue
                for name, data in samples.items():
                    self.driver.call(self._publisher(name, data))

    def _publisher(self, topic: str, data: bytes) -> Callable[[float], int]:
        engine = self.engine
        return lambda now: engine.publish(topic, data, now)

    def _send(self, out: tuple[bytes, Address]) -> None:
        if self._transport is not None:
            self._transport.sendto(out[0])

    def _event(self, event: XrceEvent) -> None:
        if isinstance(event, SampleReceived) and event.topic_name == COMMAND_TOPIC:
            self.commands.append(event.data)
