"""One agent, one vehicle (issue 17) over real loopback sockets: swarmd's XRCE backend as the
agent, swarmd's own client engine as PX4 and as every intruder (``tests/xrce_vehicle.py``).

The four failing scenarios of issue 17, each against a vehicle that stands ready: a second
client with another key; the vehicle's key from a second process; another key claiming the
vehicle's system id (its vehicle_status spoofs ours); a local process re-creating a session
with the vehicle's key every 0.5 s. In each the vehicle stays bound and ready (readiness
never flips), the intruder is refused and counted, and no command reaches it. Then, through
a whole daemon: the key generated at the first start (0600, logged) and kept across restarts,
the refusals in ``swarmctl status`` (text and JSON), and a restarted PX4 accepted once its old
session is dead.

Waiting for a state with a generous cap is not a timing assertion; nothing here asserts how
fast anything happened.
"""

from __future__ import annotations

import asyncio
import socket
import stat
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
import structlog

from swarmd.cli.status_cmd import render_px4_backend
from swarmd.config import load_config
from swarmd.daemon import Daemon
from swarmd.px4.bridge import Px4Bridge
from swarmd.px4.messages import VehicleCommand
from swarmd.px4.readiness import Readiness, ReadinessConfig, Reason
from swarmd.px4.xrce_backend import XrceBackend
from swarmd.rawclock import run_on_raw_clock
from tests.daemon_support import in_process_daemon, loopback_config, run_domain, write_bundle
from tests.xrce_vehicle import XrceVehicle

KEY = 0x0BAD_CAFE
OTHER_KEY = 2
SYSID = 1
WAIT_S = 30.0
ATTEMPTS = 6  # refusals each scenario waits for (the persistent intruders retry every 1 s)
MAV_CMD_COMPONENT_ARM_DISARM = 400


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port


async def _until(cond: Callable[[], bool], what: Callable[[], object]) -> None:
    loop = asyncio.get_running_loop()
    deadline = loop.time() + WAIT_S
    while not cond():
        if loop.time() > deadline:
            raise AssertionError(f"gave up waiting: {what()}")
        await asyncio.sleep(0.05)


def _arm() -> VehicleCommand:
    return VehicleCommand.make(MAV_CMD_COMPONENT_ARM_DISARM, p1=1.0)


SCENARIOS = {
    # issue 17: "two clients with keys 1 and 2 and system ids 1 and 2"
    "another_key": (OTHER_KEY, 2, False),
    # "two processes using key 1": each new session replaced the other
    "same_key_second_process": (KEY, SYSID, False),
    # "a second client with key 2 claiming system id 1", its vehicle_status spoofing ours
    "another_key_claims_our_system_id": (OTHER_KEY, SYSID, False),
    # "a local unprivileged user ... took the vehicle link over with the configured key
    # every 0.5 s": a fresh socket and CREATE_CLIENT every 0.5 s
    "same_key_recreated_every_half_second": (KEY, SYSID, True),
}


@pytest.mark.parametrize("scenario", list(SCENARIOS))
def test_a_second_client_is_refused_and_nothing_crosses(scenario: str) -> None:
    key, system_id, recreate = SCENARIOS[scenario]

    async def main() -> None:
        port = _free_udp_port()
        agent = ("127.0.0.1", port)
        backend = XrceBackend("xrce-agent", f"udp:127.0.0.1:{port}", sysid=SYSID, expected_key=KEY)
        bridge = Px4Bridge(backend, readiness_config=ReadinessConfig(require_home=False))
        await bridge.start()
        verdicts: list[Readiness] = []
        bridge.on_readiness_change(verdicts.append)
        vehicle = XrceVehicle(KEY, SYSID, agent)
        intruders: list[XrceVehicle] = []
        try:
            await vehicle.start()
            await _until(lambda: bridge.readiness().ready, bridge.readiness)
            bound_to = backend.client
            flips_before = len(verdicts)
            sent = 0
            while backend.counters["clients_refused"] < ATTEMPTS:
                if recreate or not intruders:
                    if recreate and intruders:
                        intruders[-1].kill()
                    intruders.append(XrceVehicle(key, system_id, agent))
                    await intruders[-1].start()
                backend.send(_arm())
                sent += 1
                await asyncio.sleep(0.5)
                assert sent < WAIT_S / 0.5, backend.stats()
            await _until(lambda: len(vehicle.commands) == sent, lambda: (sent, vehicle.commands))
            stats = backend.stats()
            # the vehicle stays bound and ready: no new session, no readiness change
            assert backend.client == bound_to and stats["sessions"] == 1
            assert verdicts[flips_before:] == [] and bridge.readiness().ready
            # the intruder is refused, counted and named; nothing reaches it
            assert all(i.engine.state == "connecting" for i in intruders)
            # refused at the agent, never answered: an intruder hears nothing (no key oracle)
            assert sum(i.engine.refused for i in intruders) == 0
            reason = "wrong_key" if key != KEY else "vehicle_alive"
            assert stats["refused"] == {reason: stats["clients_refused"]}
            assert stats["last_refused"].endswith(f"key {key:08x} ({reason})")
            assert all(i.commands == [] for i in intruders)
            assert stats["foreign_samples"] == 0  # nothing of theirs ever got in
        finally:
            for v in (vehicle, *intruders):
                v.kill()
            await bridge.close()

    run_on_raw_clock(main())


def _daemon(workdir: Path, port: int) -> Daemon:
    files = write_bundle(workdir, 2, domain_id=run_domain())  # uav1 commands, uav2 absent
    px4 = (
        "px4:\n  enabled: true\n  backend: xrce-agent\n"
        f"  connection: udp:127.0.0.1:{port}\n  require_home: false\n"
    )
    cfg = loopback_config(workdir, files, extra=px4)
    return in_process_daemon(load_config(cfg), files.bundle, "uav1")


def _px4(daemon: Daemon) -> dict[str, Any]:
    px4: dict[str, Any] = daemon.status()["px4"]
    return px4


def test_the_daemon_generates_keeps_and_enforces_its_vehicle_key(workdir: Path) -> None:
    """No ``px4.xrce_key``: the first start generates one beside node.key (0600) and logs
    it; the vehicle with it is served, a second process with it is refused and shown in the
    status; PX4 restarted behind a new port is accepted once its old session is dead; a
    second daemon start keeps the key."""
    port = _free_udp_port()
    agent = ("127.0.0.1", port)
    key_file = workdir / "px4-xrce-key"

    async def first_start() -> int:
        daemon = _daemon(workdir, port)
        with structlog.testing.capture_logs() as logs:
            await daemon.start()
        vehicles: list[XrceVehicle] = []
        try:
            assert stat.S_IMODE(key_file.stat().st_mode) == 0o600
            key = int(key_file.read_text())
            (generated,) = [e for e in logs if e["event"] == "xrce_key_generated"]
            assert generated["xrce_key"] == key and f"UXRCE_DDS_KEY {key}" in generated["fix"]
            vehicles.append(XrceVehicle(key, SYSID, agent))
            await vehicles[-1].start()
            await _until(lambda: _px4(daemon)["readiness"]["ready"], lambda: _px4(daemon))
            vehicles.append(XrceVehicle(key, SYSID, agent))  # a second process, same key
            await vehicles[-1].start()
            await _until(
                lambda: _px4(daemon)["backend"]["refused"].get("vehicle_alive", 0) >= 2,
                lambda: _px4(daemon),
            )
            assert vehicles[-1].engine.refused == 0  # unanswered
            backend = _px4(daemon)["backend"]
            assert backend["bound"] and backend["refused"]["vehicle_alive"] >= 2
            line = render_px4_backend(backend)
            assert f"refused {backend['clients_refused']} clients (last " in line, line
            assert f"({vehicles[0].address[0]}:{vehicles[0].address[1]} key {key:08x})" in line
            # PX4 restarts: the old process is gone without a DELETE, the new one has a port
            # of its own and is refused until the old session is dead, then served
            for v in vehicles:
                v.kill()
            vehicles.append(XrceVehicle(key, SYSID, agent))
            await vehicles[-1].start()
            await _until(lambda: vehicles[-1].engine.state == "established", lambda: _px4(daemon))
            await _until(lambda: _px4(daemon)["readiness"]["ready"], lambda: _px4(daemon))
            backend = _px4(daemon)["backend"]
            assert backend["sessions"] == 2 and backend["client"].startswith(
                f"{vehicles[-1].address[0]}:{vehicles[-1].address[1]} "
            )
            return key
        finally:
            for v in vehicles:
                v.kill()
            await daemon.stop("test")

    async def second_start() -> None:
        daemon = _daemon(workdir, port)
        with structlog.testing.capture_logs() as logs:
            await daemon.start()
        try:
            assert not [e for e in logs if e["event"] == "xrce_key_generated"]
            assert _px4(daemon)["backend"]["bound"]
        finally:
            await daemon.stop("test")

    key = run_on_raw_clock(first_start())
    run_on_raw_clock(second_start())
    assert int(key_file.read_text()) == key and stat.S_IMODE(key_file.stat().st_mode) == 0o600


def test_a_bound_session_of_another_vehicle_never_makes_it_ready() -> None:
    """The right key on the wrong vehicle (PX4 of system id 2 for a drone configured as 1):
    its samples are dropped and counted, readiness stays false, the status names the id."""

    async def main() -> None:
        port = _free_udp_port()
        backend = XrceBackend("xrce-agent", f"udp:127.0.0.1:{port}", sysid=SYSID, expected_key=KEY)
        bridge = Px4Bridge(backend, readiness_config=ReadinessConfig(require_home=False))
        await bridge.start()
        vehicle = XrceVehicle(KEY, 2, ("127.0.0.1", port))
        try:
            await vehicle.start()
            await _until(lambda: backend.translator.foreign_samples >= 5, backend.stats)
            stats = backend.stats()
            assert stats["session"] == "established" and stats["foreign_system_id"] == 2
            assert stats["unidentified_samples"] > 0  # its battery, GPS, land detector
            verdict = bridge.readiness()
            assert not verdict.ready and verdict.reason is Reason.NO_HEARTBEAT, verdict
            line = render_px4_backend(stats)
            assert f"dropped {stats['foreign_samples']} samples of system id 2 (not 1)" in line
        finally:
            vehicle.kill()
            await bridge.close()

    run_on_raw_clock(main())
