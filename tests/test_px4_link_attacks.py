"""Issue 10, attack 6, on real sockets: a forged autopilot on the PX4 link.

swarmd's MAVLink backend listens on loopback (``udpin:127.0.0.1:0``) with the vehicle
simulator (a simulator, not PX4) as its autopilot; a forger is another UDP socket on the
same host (a local user), or, as root, a raw socket that spoofs the simulator's own source
address. Every loop is bounded in count; waits are on conditions with a generous deadline.
"""

from __future__ import annotations

import asyncio
import json
import os
import socket
import struct
import subprocess
import sys
import time
from collections.abc import Callable
from contextlib import suppress

import pytest
from swarmd_lab.netns import Lan
from swarmd_lab.px4.sim_model import SimConfig
from swarmd_lab.px4.vehicle_sim import SimProtocol, start_sim

from swarmd.cli.swarmctl import main as swarmctl
from swarmd.px4.bridge import Px4Bridge, Px4Config
from swarmd.px4.constants import COMP_ID_AUTOPILOT1, COMP_ID_ONBOARD_COMPUTER, MavCmd
from swarmd.px4.mavlink_backend import MavlinkBackend
from swarmd.px4.mavlink_codec import MavlinkCodec
from swarmd.px4.messages import Heartbeat, VehicleCommand
from swarmd.px4.provision import setup_signing
from swarmd.px4.readiness import Reason
from swarmd.px4.signing import derive_key, timestamp_from_unix
from swarmd.px4.takeoff import TakeoffSucceeded
from swarmd.px4.transport import UdpLink, parse_connection

BOUND_S = 20.0
FORGED = 20  # datagrams per forgery: bounded
KEY = derive_key(bytes(range(32)), "alpha", "uav1")
WRONG_KEY = derive_key(bytes(range(32)), "alpha", "mallory")
ARMED = Heartbeat(autopilot=12, vehicle_type=2, base_mode=128 | 1, custom_mode=0, system_status=4)


async def wait_until(check: Callable[[], bool]) -> None:
    async def poll() -> None:
        while not check():  # noqa: ASYNC110 - a test probe of counters, not protocol logic
            await asyncio.sleep(0.02)

    await asyncio.wait_for(poll(), BOUND_S)


def backend(bridge: Px4Bridge) -> MavlinkBackend:
    assert isinstance(bridge.backend, MavlinkBackend)
    return bridge.backend


def port_of(bridge: Px4Bridge) -> int:
    link = backend(bridge).link
    assert isinstance(link, UdpLink) and link.local_port is not None
    return link.local_port


def pin_counts(bridge: Px4Bridge) -> dict[str, object]:
    stats = bridge.status()["backend"]["autopilot"]
    assert isinstance(stats, dict)
    return stats


def signing_counts(bridge: Px4Bridge) -> dict[str, int]:
    stats = bridge.status()["backend"]["signing"]
    assert isinstance(stats, dict)
    return {k: int(v) for k, v in stats.items()}


def forged_frames(key: bytes | None, msg: Heartbeat | VehicleCommand, n: int) -> list[bytes]:
    """``n`` frames from "the autopilot" (sysid 1, component 1), signed with ``key`` if any."""
    codec = MavlinkCodec(1, COMP_ID_AUTOPILOT1, signing_key=key)
    codec.advance_clock(timestamp_from_unix(time.time()))
    return [codec.encode(msg) for _ in range(n)]


class Forger:
    """A local user's UDP socket: sends forged frames, records what it is sent."""

    def __init__(self) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.setblocking(False)
        self.address = f"127.0.0.1:{self.sock.getsockname()[1]}"

    def send(self, frames: list[bytes], port: int) -> None:
        for frame in frames:
            self.sock.sendto(frame, ("127.0.0.1", port))

    def received(self) -> int:
        n = 0
        with suppress(BlockingIOError):
            while n < 10_000:
                self.sock.recv(4096)
                n += 1
        return n

    def close(self) -> None:
        self.sock.close()


async def start(key: bytes | None) -> Px4Bridge:
    bridge = Px4Bridge.from_config(
        Px4Config(connection="udpin:127.0.0.1:0", sysid=1, signing_key=key)
    )
    await bridge.start()
    return bridge


async def start_vehicle(bridge: Px4Bridge, key: bytes | None) -> SimProtocol:
    return await start_sim(
        SimConfig(gps_fix_after_s=0.2),
        parse_connection(f"udpout:127.0.0.1:{port_of(bridge)}"),
        seed=3,
        signing_key=key,
    )


def test_forged_armed_heartbeats_from_another_port_are_dropped_and_arm_never_reaches_them() -> None:
    async def scenario() -> None:
        bridge = await start(None)
        sim = await start_vehicle(bridge, None)
        forger = Forger()
        try:
            await wait_until(lambda: bridge.readiness().ready)
            pinned = pin_counts(bridge)["pinned"]
            assert pinned == f"127.0.0.1:{sim.local_port}"
            forger.send(forged_frames(None, ARMED, FORGED), port_of(bridge))
            await wait_until(lambda: pin_counts(bridge)["dropped_address"] == FORGED)
            verdict = bridge.readiness()
            assert verdict.ready and verdict.armed is False  # nothing forged reached it
            outcome = await asyncio.wait_for(bridge.takeoff(3.0), BOUND_S)
            assert isinstance(outcome, TakeoffSucceeded), outcome
            assert sim.model.armed
            assert forger.received() == 0  # the ARM (and every reply) went to the pin only
            assert pin_counts(bridge)["pinned"] == pinned
        finally:
            forger.close()
            sim.close()
            await bridge.close()

    asyncio.run(scenario())


def test_with_signing_a_forger_first_on_the_port_pins_nothing() -> None:
    async def scenario() -> None:
        bridge = await start(KEY)
        forger = Forger()
        sim: SimProtocol | None = None
        try:
            # before the real autopilot speaks: unsigned and wrong-key "autopilots"
            forger.send(forged_frames(None, ARMED, FORGED), port_of(bridge))
            forger.send(forged_frames(WRONG_KEY, ARMED, FORGED), port_of(bridge))
            await wait_until(
                lambda: (
                    signing_counts(bridge)["dropped_unsigned"] == FORGED
                    and signing_counts(bridge)["dropped_bad_signature"] == FORGED
                )
            )
            assert pin_counts(bridge)["pinned"] is None
            assert bridge.readiness().reason is Reason.NO_HEARTBEAT
            assert forger.received() == 0  # nothing pinned: nothing sent anywhere
            sim = await start_vehicle(bridge, KEY)
            await wait_until(lambda: bridge.readiness().ready)
            assert pin_counts(bridge)["pinned"] == f"127.0.0.1:{sim.local_port}"
            # end to end signed: the simulator checks our ARM and take-off as PX4 would
            outcome = await asyncio.wait_for(bridge.takeoff(3.0), BOUND_S)
            assert isinstance(outcome, TakeoffSucceeded), outcome
            assert sim.codec.signing_counts is not None
            assert sim.codec.signing_counts["ok"] >= 3
            assert sim.codec.signing_counts["bad_signature"] == 0
            assert forger.received() == 0
        finally:
            forger.close()
            if sim is not None:
                sim.close()
            await bridge.close()

    asyncio.run(scenario())


def test_with_signing_a_vehicle_with_the_wrong_key_is_never_ready() -> None:
    async def scenario() -> None:
        bridge = await start(KEY)
        sim = await start_vehicle(bridge, WRONG_KEY)
        try:
            await wait_until(lambda: signing_counts(bridge)["dropped_bad_signature"] >= 5)
            assert bridge.readiness().reason is Reason.NO_HEARTBEAT
            assert pin_counts(bridge)["pinned"] is None
        finally:
            sim.close()
            await bridge.close()

    asyncio.run(scenario())


def test_the_simulator_drops_commands_without_a_good_signature() -> None:
    async def scenario() -> None:
        sim = await start_sim(
            SimConfig(gps_fix_after_s=0.0), parse_connection("udpin:127.0.0.1:0"), signing_key=KEY
        )
        forger = Forger()
        arm = VehicleCommand.make(MavCmd.COMPONENT_ARM_DISARM, p1=1.0)

        def command(key: bytes | None) -> bytes:
            codec = MavlinkCodec(1, COMP_ID_ONBOARD_COMPUTER, signing_key=key)
            codec.advance_clock(timestamp_from_unix(time.time()))
            return codec.encode(VehicleCommand(arm.command, arm.params, 0, 1, 1))

        try:
            forger.send([command(None)] * 3 + [command(WRONG_KEY)] * 3, sim.local_port)
            await wait_until(
                lambda: (
                    (sim.codec.signing_counts or {}).get("bad_signature", 0) == 3
                    and (sim.codec.signing_counts or {}).get("unsigned", 0) == 3
                )
            )
            assert sim.model.commands_received == 0 and not sim.model.armed
            forger.send([command(KEY)], sim.local_port)
            await wait_until(lambda: sim.model.commands_received == 1)
        finally:
            forger.close()
            sim.close()

    asyncio.run(scenario())


# ---- a spoofed source address (root: raw sockets) ------------------------------------------


def spoof(frames: list[bytes], source_port: int, port: int) -> None:
    """UDP datagrams to 127.0.0.1:``port`` that claim to come from 127.0.0.1:``source_port``."""
    raw = socket.socket(socket.AF_INET, socket.SOCK_RAW, socket.IPPROTO_RAW)
    lo = socket.inet_aton("127.0.0.1")
    try:
        for frame in frames:
            udp = struct.pack("!HHHH", source_port, port, 8 + len(frame), 0) + frame
            ip = struct.pack("!BBHHHBBH4s4s", 0x45, 0, 20 + len(udp), 0, 0, 64, 17, 0, lo, lo)
            raw.sendto(ip + udp, ("127.0.0.1", 0))
    finally:
        raw.close()


needs_root = pytest.mark.skipif(os.geteuid() != 0, reason="raw sockets need root")


@needs_root
@pytest.mark.parametrize("signing", [False, True], ids=["unsigned-link", "signed-link"])
def test_a_spoofed_source_passes_the_pin_and_only_signing_stops_it(signing: bool) -> None:
    async def scenario() -> None:
        key = KEY if signing else None
        bridge = await start(key)
        sim = await start_vehicle(bridge, key)
        try:
            await wait_until(lambda: bridge.readiness().ready)
            spoof(forged_frames(None, ARMED, FORGED), sim.local_port, port_of(bridge))
            if signing:
                await wait_until(lambda: signing_counts(bridge)["dropped_unsigned"] == FORGED)
                verdict = bridge.readiness()
                assert verdict.ready and verdict.armed is False
            else:
                # the residual risk docs/security.md names: the pin is an address, and a
                # local root can forge addresses; the forged "armed" gets through
                await wait_until(lambda: bridge.readiness().reason is Reason.ARMED)
        finally:
            sim.close()
            await bridge.close()

    asyncio.run(scenario())


# ---- giving the key to the autopilot: SETUP_SIGNING ---------------------------------------


def test_setup_signing_provisions_an_unkeyed_vehicle_and_rotation_needs_the_current_key() -> None:
    async def scenario() -> None:
        sim = await start_sim(
            SimConfig(gps_fix_after_s=0.2), parse_connection("udpin:127.0.0.1:0"), seed=5
        )
        target = parse_connection(f"udpout:127.0.0.1:{sim.local_port}")
        try:
            keyed: Callable[[], bool] = lambda: sim.codec.verifier is not None  # noqa: E731
            assert not keyed()  # no key yet: signing off
            assert await setup_signing(target, 1, KEY, timeout_s=BOUND_S)
            assert keyed()
            # a keyed vehicle ignores an unsigned new key (an attacker's), keeps its own
            assert not await setup_signing(target, 1, WRONG_KEY, timeout_s=1.5)
            assert (sim.codec.signing_counts or {}).get("unsigned", 0) >= 1
            assert await setup_signing(target, 1, WRONG_KEY, current_key=KEY, timeout_s=BOUND_S)
            # swarmd with the rotated key: ready, signed end to end (udpout: speaks first)
            bridge = Px4Bridge.from_config(
                Px4Config(connection=str(target), sysid=1, signing_key=WRONG_KEY)
            )
            await bridge.start()
            try:
                await wait_until(lambda: bridge.readiness().ready)
                assert signing_counts(bridge)["ok"] >= 1
            finally:
                await bridge.close()
        finally:
            sim.close()

    asyncio.run(scenario())


def test_swarmctl_setup_signing_refuses_a_listening_connection(
    capsys: pytest.CaptureFixture[str],
) -> None:
    argv = ["px4", "setup-signing", "--keys", "k", "--swarm", "s", "--node", "n"]
    assert swarmctl([*argv, "--connection", "udpin:127.0.0.1:14540"]) == 65
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "udpout:127.0.0.1:14580" in err


# ---- from another host: a namespace on the LAN (px4.allow_network: the FMU-on-Ethernet case)

DRONE = r"""
import asyncio, json, sys
from swarmd.px4.bridge import Px4Bridge, Px4Config
from swarmd.px4.transport import parse_connection
from swarmd_lab.px4.sim_model import SimConfig
from swarmd_lab.px4.vehicle_sim import start_sim

async def until(check):
    for _ in range(400):  # 20 s at most
        if check():
            return
        await asyncio.sleep(0.05)
    raise TimeoutError

async def main(port):
    bridge = Px4Bridge.from_config(Px4Config(connection=f"udpin:0.0.0.0:{port}", sysid=1))
    await bridge.start()
    target = parse_connection(f"udpout:127.0.0.1:{port}")
    sim = await start_sim(SimConfig(gps_fix_after_s=0.2), target, seed=7)
    await until(lambda: bridge.readiness().ready)
    print("READY", flush=True)
    forged = int(await asyncio.get_running_loop().run_in_executor(None, sys.stdin.readline))
    pin = lambda: bridge.status()["backend"]["autopilot"]
    await until(lambda: pin()["dropped_address"] >= forged)
    verdict = bridge.readiness().as_dict()
    outcome = await asyncio.wait_for(bridge.takeoff(3.0), 20)
    print(json.dumps({"pin": pin(), "readiness": verdict, "outcome": type(outcome).__name__,
                      "armed": sim.model.armed}), flush=True)
    sim.close()
    await bridge.close()

asyncio.run(main(int(sys.argv[1])))
"""


@pytest.mark.netns
def test_a_forger_on_another_host_is_dropped_by_the_pin(lan2: Lan) -> None:
    """The drone listens on every interface (opted in): a host on the LAN sends armed
    HEARTBEATs as sysid 1 / component 1; all are dropped and counted, readiness is unchanged,
    and the take-off's ARM reaches the vehicle and nothing reaches the forger."""
    drone, forger_host = lan2[0], lan2[1]
    port = 14540
    proc = drone.popen(
        [sys.executable, "-c", DRONE, str(port)],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
    )
    assert proc.stdin is not None and proc.stdout is not None
    forger = forger_host.socket()
    try:
        forger.bind((forger_host.address, 0))
        assert proc.stdout.readline().strip() == b"READY"
        for frame in forged_frames(None, ARMED, FORGED):
            forger.sendto(frame, (drone.address, port))
        proc.stdin.write(f"{FORGED}\n".encode())
        proc.stdin.flush()
        result = json.loads(proc.stdout.readline())
        assert proc.wait(timeout=BOUND_S) == 0
        assert result["pin"]["dropped_address"] == FORGED
        assert result["pin"]["pinned"].startswith("127.0.0.1:")
        assert result["readiness"]["ready"] and result["readiness"]["armed"] is False
        assert result["outcome"] == "TakeoffSucceeded" and result["armed"]
        forger.setblocking(False)
        with pytest.raises(BlockingIOError):
            forger.recv(4096)  # nothing the drone sent ever came here
    finally:
        forger.close()
        if proc.poll() is None:
            proc.kill()
            proc.wait(timeout=BOUND_S)
        proc.stdin.close()
        proc.stdout.close()
