"""Real MAVLink bytes: Px4Bridge on the asyncio MAVLink backend against the vehicle simulator.

Loopback UDP (in-process and the ``swarmd-vehicle-sim`` process) and a pseudo-terminal for
the serial path. The simulator is a simulator; nothing here claims to talk to PX4.
"""

from __future__ import annotations

import asyncio
import json
import os
import random
import signal
import subprocess
import sys
from collections.abc import Callable

import pytest
from swarmd_lab.px4.sim_model import SimConfig, SimVehicle
from swarmd_lab.px4.vehicle_sim import start_sim

from swarmd.px4.bridge import Px4Bridge, Px4Config
from swarmd.px4.constants import COMP_ID_AUTOPILOT1, LandedState
from swarmd.px4.mavlink_backend import MavlinkBackend
from swarmd.px4.mavlink_codec import MavlinkCodec
from swarmd.px4.readiness import Readiness, Reason
from swarmd.px4.takeoff import FailReason, TakeoffFailed, TakeoffSucceeded
from swarmd.px4.transport import UdpLink, parse_connection

BOUND_S = 20.0  # generous upper bound so a broken build fails instead of hanging


async def wait_readiness(bridge: Px4Bridge, predicate: Callable[[Readiness], bool]) -> Readiness:
    got: asyncio.Future[Readiness] = asyncio.get_running_loop().create_future()

    def listener(r: Readiness) -> None:
        if predicate(r) and not got.done():
            got.set_result(r)

    bridge.on_readiness_change(listener)
    return await asyncio.wait_for(got, BOUND_S)


async def wait_until(check: Callable[[], bool]) -> None:
    async def poll() -> None:
        while not check():  # noqa: ASYNC110 - a test probe of bridge state, not protocol logic
            await asyncio.sleep(0.05)

    await asyncio.wait_for(poll(), BOUND_S)


def udp_port(bridge: Px4Bridge) -> int:
    assert isinstance(bridge.backend, MavlinkBackend)
    link = bridge.backend.link
    assert isinstance(link, UdpLink) and link.local_port is not None
    return link.local_port


def test_takeoff_over_udp_reaches_in_air() -> None:
    async def scenario() -> None:
        bridge = Px4Bridge.from_config(Px4Config(connection="udpin:127.0.0.1:0", sysid=1))
        await bridge.start()
        sim = await start_sim(
            SimConfig(gps_fix_after_s=0.3),
            parse_connection(f"udpout:127.0.0.1:{udp_port(bridge)}"),
            seed=1,
        )
        try:
            verdict = await wait_readiness(bridge, lambda r: r.ready)
            assert verdict.gps_fix == 3 and verdict.home
            outcome = await asyncio.wait_for(bridge.takeoff(4.0), BOUND_S)
            assert isinstance(outcome, TakeoffSucceeded), outcome
            assert outcome.target_amsl_m == pytest.approx(488.0 + 4.0)
            await wait_until(lambda: bridge.state.landed_state == LandedState.IN_AIR)
            assert sim.model.alt_m == pytest.approx(4.0) and sim.model.armed
            position = bridge.state.position
            assert position is not None and position.relative_alt_mm == pytest.approx(4000, abs=1)
            stats = bridge.status()["backend"]
            assert stats["bad_frames"] == 0 and stats["heartbeats_sent"] >= 1
            assert sim.model.commands_received >= 2
            refused = await bridge.takeoff(4.0)  # flying now: not ready, refused
            assert isinstance(refused, TakeoffFailed) and refused.cause == Reason.ARMED
        finally:
            sim.close()
            await bridge.close()

    asyncio.run(scenario())


def test_simulator_process_prearm_failure_and_link_loss() -> None:
    async def scenario() -> None:
        bridge = Px4Bridge.from_config(Px4Config(connection="udpin:127.0.0.1:0"))
        await bridge.start()
        argv = [
            sys.executable, "-m", "swarmd_lab.px4.vehicle_sim",
            "--connect", f"udpout:127.0.0.1:{udp_port(bridge)}",
            "--gps-fix-after", "0", "--fail-prearm", "--json-log", "--seed", "4",
        ]  # fmt: skip
        stale_seen = False
        proc = await asyncio.create_subprocess_exec(*argv, stderr=asyncio.subprocess.PIPE)
        try:
            # listeners hear (ready, reason) changes; the detail is read on demand
            await wait_until(lambda: bridge.readiness().prearm is False)
            verdict = bridge.readiness()
            assert verdict.reason is Reason.PREARM_FAILED
            assert verdict.detail.startswith("PREARM_CHECK not set")
            outcome = await bridge.takeoff(5.0)
            assert isinstance(outcome, TakeoffFailed)
            assert (outcome.reason, outcome.cause) == (FailReason.NOT_READY, "prearm_failed")
            proc.send_signal(signal.SIGTERM)
            stale = await wait_readiness(bridge, lambda r: r.reason is Reason.HEARTBEAT_STALE)
            stale_seen = True
            assert stale.heartbeat_age_s is not None and stale.heartbeat_age_s < 3.0
        finally:
            if proc.returncode is None and not stale_seen:
                proc.kill()
            _, err = await asyncio.wait_for(proc.communicate(), BOUND_S)
            await bridge.close()
        lines = [json.loads(line) for line in err.decode().splitlines() if line.startswith("{")]
        assert lines and all(line["simulator"] is True for line in lines)
        assert lines[0]["note"] == "MAVLink vehicle SIMULATOR, not PX4"
        assert proc.returncode == 0

    asyncio.run(scenario())


def test_bad_simulator_options_give_one_line() -> None:
    result = subprocess.run(
        [sys.executable, "-m", "swarmd_lab.px4.vehicle_sim", "--connect", "tcp:1.2.3.4:1"],
        capture_output=True,
        text=True,
        timeout=BOUND_S,
    )
    assert result.returncode == 2
    assert result.stderr.count("\n") == 1 and "fix:" in result.stderr


class PtyVehicle:
    """The simulator behind the master side of a pseudo-terminal (a UART stand-in)."""

    def __init__(self, fd: int) -> None:
        self.fd = fd
        self.loop = asyncio.get_running_loop()
        self.model = SimVehicle(SimConfig(gps_fix_after_s=0.2), random.Random(2), self.loop.time())
        self.codec = MavlinkCodec(1, COMP_ID_AUTOPILOT1)
        self.timer: asyncio.TimerHandle | None = None
        self.loop.add_reader(fd, self.readable)
        self.pump()

    def readable(self) -> None:
        try:
            data = os.read(self.fd, 4096)
        except OSError:
            return
        now = self.loop.time()
        for frame in self.codec.feed(data):  # a byte stream: no datagram boundaries
            self.model.receive(frame.msg, (frame.src_system, frame.src_component), now)
        self.pump()

    def tick(self) -> None:
        self.model.handle_timer(self.loop.time())
        self.pump()

    def pump(self) -> None:
        for msg in self.model.messages_to_send():
            os.write(self.fd, self.codec.encode(msg))
        if self.timer is not None:
            self.timer.cancel()
        self.timer = self.loop.call_at(self.model.get_timer(), self.tick)

    def close(self) -> None:
        if self.timer is not None:
            self.timer.cancel()
        self.loop.remove_reader(self.fd)


def test_takeoff_over_a_serial_line() -> None:
    async def scenario() -> None:
        master, slave = os.openpty()
        path = os.ttyname(slave)
        vehicle = PtyVehicle(master)
        bridge = Px4Bridge.from_config(Px4Config(connection=f"serial:{path}:921600"))
        try:
            await bridge.start()
            await wait_readiness(bridge, lambda r: r.ready)
            outcome = await asyncio.wait_for(bridge.takeoff(None), BOUND_S)
            assert isinstance(outcome, TakeoffSucceeded), outcome
            assert outcome.target_amsl_m is None  # NaN: PX4's MIS_TAKEOFF_ALT
            assert bridge.status()["backend"]["bad_frames"] == 0
        finally:
            await bridge.close()
            vehicle.close()
            os.close(master)
            os.close(slave)

    asyncio.run(scenario())
