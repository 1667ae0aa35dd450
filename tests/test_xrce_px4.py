"""swarmd's XRCE backends against PX4's wire: swarmd's own PX4 stand-in
(``swarmd_lab.px4.xrce_vehicle``: PX4's client session call for call, the shared vehicle
model) always; PX4's client library (``px4_like_client``) and eProsima's MicroXRCEAgent
v2.4.2 only when ``XRCE_PEERS`` names them (tests/xrce_peers.py), else those tests skip."""

from __future__ import annotations

import asyncio
import json
import os
import re
import socket
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from typing import Any

import pytest

from swarmd.px4.bridge import Px4Bridge, Px4Config
from swarmd.px4.constants import MavCmd
from swarmd.px4.messages import VehicleCommand
from swarmd.px4.readiness import Readiness, ReadinessConfig
from swarmd.px4.takeoff import TakeoffSucceeded
from swarmd.px4.xrce_backend import XrceBackend
from tests.xrce_peers import peer_binary, peer_env, standin_argv

# the stand-in's core topic set (the golden session's) has no home_position: readiness
# without it, and the take-off altitude is measured from its GPS altitude (488 m AMSL)
READY = ReadinessConfig(require_home=False)
GROUND_AMSL_M = 488.0  # the shared vehicle model's home_amsl_m (and px4_like_client's)
ALT_M = 5.0


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port


@asynccontextmanager
async def _proc(*argv: str) -> AsyncIterator[asyncio.subprocess.Process]:
    p = await asyncio.create_subprocess_exec(
        *argv, stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.PIPE, env=peer_env()
    )
    try:
        yield p
    finally:
        if p.returncode is None:
            p.terminate()
            try:
                await asyncio.wait_for(p.wait(), 5)
            except TimeoutError:
                p.kill()
                await p.wait()


async def _until(pred: Any, limit_s: float, what: str) -> None:
    loop = asyncio.get_running_loop()
    end = loop.time() + limit_s
    while not pred():
        assert loop.time() < end, f"timed out waiting for {what}"
        await asyncio.sleep(0.05)


async def _commands(p: asyncio.subprocess.Process) -> list[dict[str, Any]]:
    p.terminate()
    out, _err = await p.communicate()
    lines = [json.loads(line) for line in out.decode().splitlines() if line.startswith("{")]
    return [c for c in lines if c.get("event") == "vehicle_command"]


async def _fly(bridge: Px4Bridge, client: asyncio.subprocess.Process, via: str = "topic") -> None:
    verdicts: list[Readiness] = []
    bridge.on_readiness_change(verdicts.append)
    await _until(lambda: bridge.readiness().ready, 60, "ready")  # after PX4's 500-sample sync
    outcome = await bridge.takeoff(ALT_M)
    assert isinstance(outcome, TakeoffSucceeded), outcome
    assert outcome.altitude_ref == "gps"  # no home_position from the stand-in
    assert outcome.target_amsl_m == pytest.approx(GROUND_AMSL_M + ALT_M)
    assert bridge.readiness().reason == "armed"  # not ready, and says why
    bridge.backend.send(VehicleCommand.make(MavCmd.NAV_LAND))
    await asyncio.sleep(1.0)
    cmds = await _commands(client)
    names = [(c["fields"]["command"], c["ack_result"]) for c in cmds]
    # exactly once each, acks ACCEPTED, from component 191 of our system, flagged external
    assert names == [(400, 0), (22, 0), (21, 0)], names
    param7 = cmds[1]["fields"]["param7"]  # float32 on the wire; the stand-in climbs 5 m
    assert param7 == pytest.approx(GROUND_AMSL_M + ALT_M, abs=1e-3)
    assert all(
        c["fields"]["source_component"] == 191 and c["fields"]["from_external"] for c in cmds
    )
    assert verdicts[0].ready is False and any(v.ready for v in verdicts)


@pytest.mark.parametrize("release", ["1.14", "1.15", "1.16", "1.17"])
def test_agent_with_px4_client_takes_off_and_lands(release: str) -> None:
    asyncio.run(_agent_takeoff(release))


async def _agent_takeoff(release: str) -> None:
    port = _free_udp_port()
    backend = XrceBackend("xrce-agent", f"udp:127.0.0.1:{port}", sysid=1)
    bridge = Px4Bridge(backend, readiness_config=READY)
    await bridge.start()
    try:
        async with _proc(*standin_argv(port, release)) as client:
            await _fly(bridge, client, "topic" if release == "1.14" else "service")
        st = backend.stats()
        assert st["px4_version"] is not None and release in st["px4_version"].split("/")
        assert st["layout_problem"] is None and st["dropped"] == {}
        assert st["failsafe_blockers"] == []  # failsafe_flags read, nothing blocking
    finally:
        await bridge.close()


def test_agent_sees_the_standin_and_itself_restart() -> None:
    asyncio.run(_agent_sees_the_standin_and_itself_restart())


async def _agent_sees_the_standin_and_itself_restart() -> None:
    """swarmd restarts: a new agent on the same port, the stand-in's 3 missed pings make it
    connect again; the stand-in killed: readiness goes stale; restarted: ready again."""
    port = _free_udp_port()
    backend = XrceBackend("xrce-agent", f"udp:127.0.0.1:{port}", sysid=1)
    bridge = Px4Bridge(backend, readiness_config=READY)
    await bridge.start()
    try:
        async with _proc(*standin_argv(port)) as client:
            await _until(lambda: bridge.readiness().ready, 60, "ready")
            await bridge.close()
            backend = XrceBackend("xrce-agent", f"udp:127.0.0.1:{port}", sysid=1)
            bridge = Px4Bridge(backend, readiness_config=READY)
            await bridge.start()
            await _until(lambda: bridge.readiness().ready, 60, "ready after swarmd's restart")
            client.kill()
            await client.wait()
            await _until(lambda: not bridge.readiness().ready, 10, "stale after PX4 is gone")
            assert bridge.readiness().reason == "heartbeat_stale"
        async with _proc(*standin_argv(port)):
            await _until(lambda: bridge.readiness().ready, 60, "ready after PX4 restart")
        assert backend.counters["sessions"] == 2
        # only the old session's datagrams before the stand-in noticed the new agent
        assert set(backend.stats()["dropped"]) <= {"no_session"}
    finally:
        await bridge.close()


def test_agent_accepts_every_entity_of_the_full_topic_set_and_reconnects() -> None:
    """Third-party peer: PX4's client library with every topic of dds_topics.yaml (``-a``)."""
    asyncio.run(_agent_accepts_every_entity_of_the_full_topic_set_and_reconnects())


async def _agent_accepts_every_entity_of_the_full_topic_set_and_reconnects() -> None:
    client_bin = peer_binary("px4_like_client")
    port = _free_udp_port()
    backend = XrceBackend("xrce-agent", f"udp:127.0.0.1:{port}", sysid=1)
    bridge = Px4Bridge(backend, readiness_config=READY)
    await bridge.start()
    try:
        argv = (str(client_bin), "-p", str(port), "-V", "1.16", "-a", "-D", "8")
        async with _proc(*argv) as client:
            _out, err = await asyncio.wait_for(client.communicate(), 60)
        log = err.decode()
        assert "failed" not in log and "disconnecting" not in log, log[-2000:]
        m = re.search(r"layouts: (\d+) publications, (\d+) subscriptions", log)
        assert m is not None and int(m[1]) > 20 and int(m[2]) > 20
        # every writer, reader and the replier accepted, each once (no set-up retry)
        assert log.count("successfully created") == int(m[1]) + int(m[2]) + 1
        assert "synchronized with time offset" in log  # time sync converged
        assert backend.session.startswith("ended")
        # swarmd restarts: a new agent on the same port; the client's next run connects again
        await bridge.close()
        backend = XrceBackend("xrce-agent", f"udp:127.0.0.1:{port}", sysid=1)
        bridge = Px4Bridge(backend, readiness_config=READY)
        await bridge.start()
        async with _proc(str(client_bin), "-p", str(port), "-V", "1.16", "-q") as client:
            await _until(lambda: bridge.readiness().ready, 60, "ready after restart")
            client.kill()
            await client.wait()
            await _until(lambda: not bridge.readiness().ready, 10, "stale after PX4 is gone")
            assert bridge.readiness().reason == "heartbeat_stale"
        async with _proc(str(client_bin), "-p", str(port), "-V", "1.16", "-q"):
            await _until(lambda: bridge.readiness().ready, 60, "ready after PX4 restart")
        assert backend.counters["sessions"] == 2
    finally:
        await bridge.close()


def test_garbage_to_the_agent_port_is_counted_and_dropped() -> None:
    asyncio.run(_garbage_to_the_agent_port_is_counted_and_dropped())


async def _garbage_to_the_agent_port_is_counted_and_dropped() -> None:
    port = _free_udp_port()
    backend = XrceBackend("xrce-agent", f"udp:127.0.0.1:{port}", sysid=1)
    bridge = Px4Bridge(backend, readiness_config=READY)
    await bridge.start()
    try:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            forged_status = bytes.fromhex("810100000701") + b"\x54\x00" + b"\x00" * 84
            for junk in (b"", b"\x81\x00", bytes(range(200)), forged_status) * 25:
                s.sendto(junk, ("127.0.0.1", port))
        await _until(lambda: backend.counters["datagrams_in"] >= 75, 10, "datagrams")
        assert sum(backend.engine.dropped.values()) >= 75
        assert bridge.readiness().reason == "no_heartbeat"  # nothing moved
    finally:
        await bridge.close()


def test_client_mode_through_micro_xrce_agent_takes_off() -> None:
    asyncio.run(_client_mode_through_micro_xrce_agent_takes_off(None))


def test_client_mode_on_another_dds_domain_takes_off() -> None:
    """PX4 on UXRCE_DDS_DOM_ID != 0 and ``px4.xrce_domain_id`` the same, from the config
    through the bridge: swarmd's participant joins PX4's domain in the agent (it was always
    0, so its readers never matched PX4's writers). The domain is per process so parallel
    runs on this host do not hear each other."""
    asyncio.run(_client_mode_through_micro_xrce_agent_takes_off(1 + os.getpid() % 200))


async def _client_mode_through_micro_xrce_agent_takes_off(domain: int | None) -> None:
    agent_bin = peer_binary("MicroXRCEAgent")  # third-party: skips without XRCE_PEERS
    port = _free_udp_port()
    async with _proc(str(agent_bin), "udp4", "-p", str(port)):
        await asyncio.sleep(0.5)
        if domain is None:
            backend = XrceBackend("xrce-client", f"udp:localhost:{port}", sysid=1)
            bridge = Px4Bridge(backend, readiness_config=READY)
            on_domain: tuple[str, ...] = ()
        else:
            config = Px4Config(f"udp:localhost:{port}", backend="xrce-client",
                               xrce_domain_id=domain, readiness=READY)  # fmt: skip
            bridge = Px4Bridge.from_config(config)
            assert isinstance(bridge.backend, XrceBackend)
            backend = bridge.backend
            on_domain = ("-d", str(domain))
        await bridge.start()
        try:
            # the stand-in as PX4 behind MicroXRCEAgent (PTCFG=1: localhost-only participant)
            async with _proc(*standin_argv(port, "1.16", "-c", "1", *on_domain)) as client:
                await _fly(bridge, client)
            assert backend.session == "established"
            assert backend.stats()["failsafe_blockers"] == []  # read through the agent too
        finally:
            await bridge.close()


def test_standin_key_and_system_id_options() -> None:
    asyncio.run(_standin_key_and_system_id_options())


async def _standin_key_and_system_id_options() -> None:
    """``-k`` is PX4's UXRCE_DDS_KEY and ``-S`` its MAV_SYS_ID: an agent bound to key 7 flies
    vehicle 3 from the stand-in started with ``-k 7 -S 3``; one started with ``-k 8`` never
    gets a session (refused), so swarmd never hears a vehicle."""
    port = _free_udp_port()
    backend = XrceBackend("xrce-agent", f"udp:127.0.0.1:{port}", sysid=3, expected_key=7)
    bridge = Px4Bridge(backend, readiness_config=READY)
    await bridge.start()
    try:
        async with _proc(*standin_argv(port, "1.16", "-k", "8", "-S", "3")):
            await asyncio.sleep(8.0)  # a session would be ready after ~6 s of time sync
            assert bridge.readiness().reason == "no_heartbeat"
            assert backend.counters["sessions"] == 0
        async with _proc(*standin_argv(port, "1.16", "-k", "7", "-S", "3")) as client:
            await _fly(bridge, client)
    finally:
        await bridge.close()
