"""A simulated vehicle and a companion joined on virtual time: no sockets, no event loop.

Every message crosses as real MAVLink 2 bytes (each side has its own ``MavlinkCodec``), after
a fixed latency, through an optional ``drop`` filter that tests use to lose ACKs or cut the
link. Used by the tests and by anything that wants many vehicles faster than real time.
"""

from __future__ import annotations

import heapq
import itertools
from collections.abc import Callable
from dataclasses import dataclass, field

from swarmd.px4.constants import COMP_ID_AUTOPILOT1, COMP_ID_ONBOARD_COMPUTER
from swarmd.px4.mavlink_codec import MavlinkCodec, Message, SetupSigning
from swarmd.px4.messages import BootClock, VehicleCommand
from swarmd.px4.readiness import VehicleState
from swarmd.px4.takeoff import SequenceEvent, TakeoffSequence
from swarmd_lab.px4.sim_model import SimVehicle

Direction = str  # "up" (vehicle -> companion) or "down" (companion -> vehicle)
DropFilter = Callable[[Message, Direction, float], bool]


@dataclass(order=True)
class _Delivery:
    at: float
    seq: int
    direction: Direction = field(compare=False)
    data: bytes = field(compare=False)


class VirtualLink:
    """``SimVehicle`` <-> companion (``VehicleState`` + an optional ``TakeoffSequence``)."""

    def __init__(
        self,
        sim: SimVehicle,
        state: VehicleState,
        now: float,
        *,
        latency_s: float = 0.005,
        drop: DropFilter | None = None,
    ) -> None:
        self.sim = sim
        self.state = state
        self.now = now
        self.latency_s = latency_s
        self.drop = drop
        self.sequence: TakeoffSequence | None = None
        self.events: list[SequenceEvent] = []
        self.sent_down: list[VehicleCommand] = []
        self._vehicle_codec = MavlinkCodec(sim.config.sysid, COMP_ID_AUTOPILOT1)
        self._companion_codec = MavlinkCodec(sim.config.sysid, COMP_ID_ONBOARD_COMPUTER)
        self._queue: list[_Delivery] = []
        self._seq = itertools.count()

    def attach(self, sequence: TakeoffSequence) -> None:
        """Drive ``sequence`` from now on (call ``sequence.start`` through ``start``)."""
        self.sequence = sequence

    def start(self, sequence: TakeoffSequence) -> None:
        self.attach(sequence)
        sequence.start(self.now)
        self._pump_sequence()

    def send(self, command: VehicleCommand) -> None:
        """A companion command addressed to the simulated vehicle."""
        cmd = VehicleCommand(
            command.command, command.params, command.confirmation, self.sim.config.sysid, 1
        )
        self.sent_down.append(cmd)
        if self.drop is not None and self.drop(cmd, "down", self.now):
            return
        self._enqueue("down", self._companion_codec.encode(cmd))

    def run_until(self, t_end: float, *, stop: Callable[[], bool] | None = None) -> None:
        """Advance virtual time to ``t_end`` (or until ``stop()`` holds)."""
        while True:
            if stop is not None and stop():
                return
            candidates = [self.sim.get_timer()]
            if self._queue:
                candidates.append(self._queue[0].at)
            if self.sequence is not None and (timer := self.sequence.get_timer()) is not None:
                candidates.append(timer)
            t = min(candidates)
            if t > t_end:
                self.now = t_end
                return
            self.now = max(self.now, t)
            if self._queue and self._queue[0].at <= self.now:
                self._deliver(heapq.heappop(self._queue))
            elif self.sim.get_timer() <= self.now:
                self.sim.handle_timer(self.now)
                self._pump_sim()
            elif self.sequence is not None:
                self.sequence.handle_timer(self.now)
                self._pump_sequence()

    # ---- internals ----------------------------------------------------------------------

    def _enqueue(self, direction: Direction, data: bytes) -> None:
        heapq.heappush(
            self._queue, _Delivery(self.now + self.latency_s, next(self._seq), direction, data)
        )

    def _pump_sim(self) -> None:
        for msg in self.sim.messages_to_send():
            if self.drop is not None and self.drop(msg, "up", self.now):
                continue
            self._enqueue("up", self._vehicle_codec.encode(msg))

    def _pump_sequence(self) -> None:
        if self.sequence is None:
            return
        for cmd in self.sequence.commands_to_send():
            self.send(cmd)
        while (event := self.sequence.next_event()) is not None:
            self.events.append(event)

    def _deliver(self, d: _Delivery) -> None:
        if d.direction == "down":
            for frame in self._vehicle_codec.feed(d.data, datagram=True):
                self.sim.receive(frame.msg, (frame.src_system, frame.src_component), self.now)
            self._pump_sim()
            return
        for frame in self._companion_codec.feed(d.data, datagram=True):
            if isinstance(frame.msg, VehicleCommand | SetupSigning | BootClock):
                continue  # BootClock: the MAVLink backend's (boot_watch), no observation
            self.state.observe(frame.msg, self.now)
            if self.sequence is not None:
                self.sequence.observe(frame.msg, self.now)
        self._pump_sequence()
