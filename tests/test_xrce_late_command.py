"""Never late at the PX4 edge over uXRCE-DDS (docs/security.md, "The PX4 link": "A command
frame delivered late"): a command frame the agent handed to PX4 while the link was down must
not reach PX4 after its sender gave it up and the operator was told.

PX4 1.15 and later read the ``vehicle_command`` service's requests on the agent's reliable
stream (golden session: the replier's READ_DATA asks for stream 0x80), and a reliable
stream repeats every unacknowledged message until the client acknowledges it (DDS-XRCE 1.0
§8.4.2). Before, a take-off whose four ARMs went into a link outage failed ``arm_no_ack``
and, when the link came back inside PX4's session, the agent delivered all four ARMs to
PX4 (then the DISARM): the vehicle armed after the operator was told the take-off failed.

The real pieces on one virtual clock, no sockets: ``VehicleCore`` (take-off) under a
``Driver``, ``XrceBackend.send`` (the translator, the agent) under a ``Driver``, and the
PX4 stand-in (PX4's client session + the shared vehicle model) under a third; a switch
drops every datagram both ways while the link is down.
"""

from __future__ import annotations

import math
import random
from collections.abc import Callable
from typing import Any

import pytest
from swarmd_lab.px4.sim_model import SimConfig
from swarmd_lab.px4.xrce_standin import Px4XrceStandin, StandinConfig
from swarmd_lab.sim.clock import Timer, VirtualClock

from swarmd.driver import Driver
from swarmd.px4.constants import MavCmd
from swarmd.px4.messages import Observation, VehicleCommand
from swarmd.px4.readiness import ReadinessConfig
from swarmd.px4.vehicle import TaskFinished, TaskKind, VehicleCore, VehicleEvent, VehicleRequest
from swarmd.px4.xrce_backend import XrceBackend
from swarmd.xrce.agent import XrceAgent
from swarmd.xrce.client import XrceClient
from swarmd.xrce.events import Address, SampleReceived, XrceEvent

# the stand-in's core topic set has no home_position (docs/px4.md): readiness without it
READY = ReadinessConfig(require_home=False)
LATENCY_S = 0.0005  # one way, a UART at 921,600 baud or the loopback
KEY = 1


class _Loop:
    """What ``Driver`` needs of an event loop, on the virtual clock."""

    def __init__(self, clock: VirtualClock) -> None:
        self.clock = clock

    def time(self) -> float:
        return self.clock.now

    def call_at(self, at: float, callback: Callable[[], None]) -> Timer:
        return self.clock.call_at(at, callback)


class _Standin:
    """The stand-in as a driver's core: its log is read by the test, it has no events."""

    def __init__(self, px4: Px4XrceStandin) -> None:
        self.px4 = px4

    def receive_datagram(self, data: bytes, source: Address, now: float) -> None:
        self.px4.receive_datagram(data, source, now)

    def handle_timer(self, now: float) -> None:
        self.px4.handle_timer(now)

    def get_timer(self) -> float | None:
        return self.px4.get_timer()

    def datagrams_to_send(self) -> list[tuple[bytes, Address]]:
        return self.px4.datagrams_to_send()

    def next_event(self) -> None:
        return None


class _Wire:
    """One virtual clock, and a link that carries each datagram after ``LATENCY_S`` while
    it is up and drops it while it is down."""

    def __init__(self) -> None:
        self.clock = VirtualClock()
        self.loop: Any = _Loop(self.clock)
        self.link_up = True

    def carry(self, deliver: Callable[[], None]) -> None:
        if self.link_up:
            self.clock.call_at(self.clock.now + LATENCY_S, deliver)

    def run(self, until: float) -> None:
        while (t := self.clock.next_time()) is not None and t <= until:
            self.clock.run_next()
        self.clock.now = max(self.clock.now, until)


class Edge(_Wire):
    """swarmd (vehicle core + XRCE agent backend) and the PX4 stand-in, joined by a link
    that can go down."""

    def __init__(self, release: str) -> None:
        super().__init__()
        loop = self.loop
        self.events: list[VehicleEvent] = []
        self.core = VehicleCore(readiness_config=READY)
        self.backend = XrceBackend("xrce-agent", "udp:127.0.0.1:888", sysid=1, expected_key=KEY)
        self.backend._clock_offset = 0.0  # noqa: SLF001 - agent time = loop time here
        self.px4 = Px4XrceStandin(
            StandinConfig(release=release, key=KEY, vehicle=SimConfig(gps_fix_after_s=0.0)),
            random.Random(7),
            0.0,
        )
        self.core_driver: Driver[Observation, VehicleCommand, VehicleEvent] = Driver(
            self.core, transmit=self.backend.send, on_event=self.events.append, name="px4",
            loop=loop,
        )  # fmt: skip
        # what XrceBackend.start does, without the socket: the engine under its driver,
        # observations into the vehicle core
        backend = self.backend
        backend._loop = loop  # noqa: SLF001
        backend._sink = lambda obs, _now: self.core_driver.datagram_received(obs, None)  # noqa: SLF001
        backend._driver = Driver(  # noqa: SLF001
            backend.engine, transmit=self._to_px4, on_event=backend._event,  # noqa: SLF001
            name="xrce-agent", loop=loop,
        )  # fmt: skip
        self.px4_driver: Driver[bytes, tuple[bytes, Address], None] = Driver(
            _Standin(self.px4), transmit=self._to_swarmd, on_event=lambda _e: None,
            name="px4-standin", loop=loop,
        )  # fmt: skip
        self.px4_driver.call(lambda now: self.px4.connect("agent", now))
        self.px4_commands: list[tuple[float, int, float]] = []  # (t, command, param1) at PX4

    # ---- the link ---------------------------------------------------------------------

    def _to_px4(self, out: tuple[bytes, Address]) -> None:
        data = out[0]
        self.carry(lambda: self._px4_in(data))

    def _px4_in(self, data: bytes) -> None:
        self.px4_driver.datagram_received(data, "agent")
        while (note := self.px4.next_log()) is not None:
            if note["event"] == "vehicle_command":
                fields = note["fields"]
                p1 = fields["param1"]
                self.px4_commands.append(
                    (self.clock.now, int(fields["command"]), math.nan if p1 is None else p1)
                )

    def _to_swarmd(self, out: tuple[bytes, Address]) -> None:
        data = out[0]
        self.carry(lambda: self.backend._receive(data, "px4"))  # noqa: SLF001

    # ---- driving ----------------------------------------------------------------------

    def run_until_ready(self, limit: float = 30.0) -> None:
        while not self.core.readiness(self.clock.now).ready:
            assert self.clock.now < limit, self.core.readiness(self.clock.now).detail
            self.run(self.clock.now + 0.1)

    def takeoff(self, token: int = 1, alt_m: float = 5.0) -> None:
        request = VehicleRequest(token, TaskKind.TAKEOFF, alt_m)
        self.core_driver.call(lambda now: self.core.request(request, now))

    def finished(self, token: int = 1) -> TaskFinished | None:
        return next(
            (e for e in self.events if isinstance(e, TaskFinished) and e.token == token), None
        )

    def takeoff_until_done(self, token: int = 1, limit_s: float = 15.0) -> TaskFinished:
        """Request a take-off and run until it ends (bounded: ``limit_s`` virtual seconds)."""
        self.takeoff(token)
        end = self.clock.now + limit_s
        while (done := self.finished(token)) is None:
            assert self.clock.now < end, "the take-off never ended"
            self.run(self.clock.now + 0.05)
        return done

    def arms_at_px4(self) -> list[float]:
        return [t for t, c, p1 in self.px4_commands if c == MavCmd.COMPONENT_ARM_DISARM and p1 == 1]


@pytest.mark.parametrize("release", ["1.14", "1.16"])
def test_arms_written_into_a_link_outage_never_reach_px4_after_the_takeoff_gave_up(
    release: str,
) -> None:
    """The link goes down as the take-off starts and comes back 0.3 s after it gave up
    ``arm_no_ack`` (inside PX4's session: three missed 1 s pings end it). No ARM may reach
    PX4 after the give-up; PX4 stays disarmed. 1.16 sends commands as service requests on
    the reliable stream [fails on main: four ARMs delivered on the link's return, PX4
    armed]; 1.14 as the topic, on the best-effort stream (holds on main: pinned). Then
    the next take-off flies: the stream was not left with a gap."""
    edge = Edge(release)
    edge.run_until_ready()
    edge.run(edge.clock.now + 1.0)
    edge.link_up = False
    done = edge.takeoff_until_done(limit_s=5.0)
    assert not done.ok
    assert done.reason == "arm_no_ack"
    gave_up = edge.clock.now
    edge.run(gave_up + 0.3)
    edge.link_up = True
    edge.run(gave_up + 6.0)
    assert edge.backend.session == "established"  # PX4's session survived the outage
    assert edge.arms_at_px4() == []
    assert not edge.px4.vehicle.armed
    # the reliable stream (1.16's service requests) repaired them as stand-ins
    expired = edge.backend.stats().get("commands_expired", 0)
    assert expired >= 4 if release == "1.16" else expired == 0
    # and the stream moves on: the next take-off's ARM is not stuck behind them
    again = edge.takeoff_until_done(token=2)
    assert again.ok, again.reason


@pytest.mark.parametrize("release", ["1.14", "1.16"])
def test_a_takeoff_over_a_healthy_link_still_arms_and_flies(release: str) -> None:
    """The control: the same edge, the link up, the take-off succeeds (the expiry of a
    command's frames must not cost a healthy link its commands)."""
    edge = Edge(release)
    edge.run_until_ready()
    done = edge.takeoff_until_done()
    assert done.ok, done.reason
    assert len(edge.arms_at_px4()) == 1


class ClientEdge(_Wire):
    """swarmd as a second client (``xrce-client``) of an agent standing in for
    MicroXRCEAgent (swarmd's own agent, unbound), joined by a link that can go down."""

    def __init__(self) -> None:
        super().__init__()
        loop = self.loop
        self.agent = XrceAgent()
        self.backend = XrceBackend("xrce-client", "udp:127.0.0.1:8888", sysid=1)
        self.commands: list[tuple[float, bytes]] = []  # vehicle_command samples at the agent
        backend = self.backend
        backend._loop = loop  # noqa: SLF001 - what start() does, without the socket
        backend._driver = Driver(  # noqa: SLF001
            backend.engine, transmit=self._to_agent, on_event=backend._event,  # noqa: SLF001
            name="xrce-client", loop=loop,
        )  # fmt: skip
        self.agent_driver: Driver[bytes, tuple[bytes, Address], XrceEvent] = Driver(
            self.agent, transmit=self._to_swarmd, on_event=self._agent_event, name="agent",
            loop=loop,
        )  # fmt: skip
        client = self.client
        backend._driver.call(lambda now: client.connect("agent", now))  # noqa: SLF001

    def _to_agent(self, out: tuple[bytes, Address]) -> None:
        data = out[0]
        self.carry(lambda: self.agent_driver.datagram_received(data, "swarmd"))

    def _to_swarmd(self, out: tuple[bytes, Address]) -> None:
        data = out[0]
        self.carry(lambda: self.backend._receive(data, "agent"))  # noqa: SLF001

    def _agent_event(self, event: XrceEvent) -> None:
        if isinstance(event, SampleReceived) and "vehicle_command" in event.topic_name:
            self.commands.append((self.clock.now, event.data))

    @property
    def client(self) -> XrceClient:
        engine = self.backend.engine
        assert isinstance(engine, XrceClient)
        return engine


def test_as_a_client_a_command_written_into_an_outage_never_reaches_the_agent_late() -> None:
    """``xrce-client``: swarmd writes ``vehicle_command`` on its own reliable stream to
    MicroXRCEAgent, which repairs what the agent did not acknowledge. An ARM written while
    the link is down for 2 s (inside the session: three missed 1 s pings end it) must not
    reach the agent after its life (0.5 s), and a command written after the outage still
    does [the first fails on main: the ARM delivered 2 s late]."""
    edge = ClientEdge()
    edge.run(2.0)
    assert edge.client.state == "established"
    edge.link_up = False
    edge.backend.send(VehicleCommand.make(MavCmd.COMPONENT_ARM_DISARM, p1=1.0))
    written = edge.clock.now
    edge.run(written + 2.0)
    edge.link_up = True
    edge.run(written + 5.0)
    assert edge.client.state == "established"  # the session survived the outage
    assert edge.commands == []
    edge.backend.send(VehicleCommand.make(MavCmd.NAV_LAND))
    edge.run(edge.clock.now + 1.0)
    assert len(edge.commands) == 1


class _CutWhenArmed(Edge):
    """The link goes down both ways the moment PX4 arms: PX4 took the first ARM, and its
    answer and everything after are lost until ``link_up`` is set again."""

    cut_at: float | None = None

    def _to_swarmd(self, out: tuple[bytes, Address]) -> None:
        if self.cut_at is None and self.px4.vehicle.armed:
            self.link_up = False
            self.cut_at = self.clock.now
        super()._to_swarmd(out)


def test_a_failed_takeoffs_disarm_written_into_an_outage_still_disarms_px4() -> None:
    """Review 17: PX4 took the first ARM, then the link went down both ways; the take-off
    gave up ``arm_no_ack`` and sent its one DISARM into the outage, which ended 0.6 s later
    (2.65 s in all: PX4's session lived). The DISARM does not start motion: it must reach
    PX4 when the link is back, as the reliable stream delivered it before the command
    life. On main it had the ARMs' 0.5 s life, went as a stand-in, and PX4 sat armed on
    the ground (until its pre-flight disarm, 10 s after arming) while the operator read
    ``arm_no_ack`` [fails on main: PX4 armed 3 s after the give-up, no DISARM at PX4]. The
    late ARMs still never reach it."""
    edge = _CutWhenArmed("1.16")
    edge.run_until_ready()
    edge.run(edge.clock.now + 1.0)
    done = edge.takeoff_until_done(limit_s=5.0)
    assert done.reason == "arm_no_ack"
    armed_at_give_up = edge.px4.vehicle.armed
    assert armed_at_give_up  # PX4 took the first ARM; only its answers were lost
    gave_up = edge.clock.now
    edge.run(gave_up + 0.6)
    edge.link_up = True
    edge.run(gave_up + 3.0)
    assert edge.backend.session == "established"
    assert not edge.px4.vehicle.armed
    disarms = [t for t, c, p1 in edge.px4_commands if c == MavCmd.COMPONENT_ARM_DISARM and p1 == 0]
    # the DISARM and the take-off's own repeat of it, both written into the outage
    # (tests/test_px4_disarm_repeat.py); a second DISARM to a disarmed PX4 is harmless
    assert 1 <= len(disarms) <= 2
    assert len(edge.arms_at_px4()) == 1  # the first ARM only: the retransmissions expired
