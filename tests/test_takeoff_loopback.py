"""The full loop in one process: three daemons on the host loopback, each with a vehicle
SIMULATOR (not PX4) on its own MAVLink port; readiness to the commander, take-off to IN_AIR.

Real sockets, real RTPS and MAVLink bytes, on the daemon's own loop clock
(CLOCK_MONOTONIC_RAW, ``swarmd.rawclock``). Exactly-once under 30 % user-data loss is tested
on the swarm core in virtual time (tests/test_swarm_core.py), with no patched method.
Waiting for a state with a generous cap is not a timing assertion; nothing here asserts
how fast anything happened.
"""

from __future__ import annotations

import asyncio
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from swarmd_lab.px4.sim_model import SimConfig
from swarmd_lab.px4.vehicle_sim import SimProtocol, start_sim

from swarmd.config import load_config
from swarmd.control import RequestInvalid
from swarmd.daemon import Daemon
from swarmd.px4.constants import LandedState
from swarmd.px4.transport import parse_connection
from swarmd.rawclock import run_on_raw_clock
from tests.daemon_support import (
    BundleFiles,
    in_process_daemon,
    run_domain,
    swarm_sections,
    write_bundle,
    write_config,
)

N = 3
WAIT_S = 30.0


def _mavlink_port(i: int) -> int:
    return 20000 + (os.getpid() % 2000) * 8 + i


class Swarm:
    def __init__(self, workdir: Path, files: BundleFiles) -> None:
        self.workdir = workdir
        self.files = files
        self.daemons: list[Daemon] = []
        self.sims: list[SimProtocol] = []

    def daemon(self, i: int) -> Daemon:
        node = f"uav{i + 1}"
        cfg = write_config(
            self.workdir / f"{node}.yaml",
            self.files,
            node=node,
            interface="lo",
            ipv4="127.0.0.1",
            socket_path=str(self.workdir / f"{node}.sock"),
            extra=swarm_sections(
                self.workdir / "state", f"udpin:127.0.0.1:{_mavlink_port(i)}", period_s=0.5
            ),
        )
        return in_process_daemon(load_config(cfg), self.files.bundle, node)

    async def start(self, sim_configs: list[SimConfig]) -> None:
        for i in range(N):
            d = self.daemon(i)
            await d.start()
            self.daemons.append(d)
        for i, config in enumerate(sim_configs):
            endpoint = parse_connection(f"udpout:127.0.0.1:{_mavlink_port(i)}")
            self.sims.append(await start_sim(config, endpoint, seed=i))

    async def stop(self) -> None:
        for sim in self.sims:
            sim.close()
        for d in self.daemons:
            await d.stop("test")

    @property
    def commander(self) -> Daemon:
        return self.daemons[0]

    def table(self) -> dict[str, dict[str, Any]]:
        rows: dict[str, dict[str, Any]] = self.commander.status()["readiness"]
        return rows


async def until(cond: Callable[[], bool], what: Callable[[], object]) -> None:
    loop = asyncio.get_running_loop()
    deadline = loop.time() + WAIT_S
    while not cond():
        if loop.time() > deadline:
            raise AssertionError(f"gave up waiting: {what()}")
        await asyncio.sleep(0.05)


def _sim(sysid: int, **kw: Any) -> SimConfig:
    return SimConfig(sysid=sysid, gps_fix_after_s=kw.pop("gps_fix_after_s", 0.2), **kw)


def test_readiness_takeoff_and_refusal(workdir: Path) -> None:
    """Ready members and the commander's own drone go airborne; a member whose simulated
    sensor fails pre-arm is refused by the commander with its own reason."""
    files = write_bundle(workdir, N, domain_id=run_domain(), lease_s=20.0)
    swarm = Swarm(workdir, files)

    async def main() -> None:
        await swarm.start([_sim(1), _sim(2), _sim(3, fail_prearm=True)])
        try:
            app = swarm.commander.app
            assert app is not None and app.is_commander
            await until(
                lambda: (
                    swarm.table()["uav2"]["ready"]
                    and swarm.table()["uav1"]["ready"]
                    and swarm.table()["uav3"]["reason"] == "prearm_failed"
                ),
                lambda: (swarm.table(), [_dp(d) for d in swarm.daemons]),
            )
            row = swarm.table()["uav2"]
            assert row["count"] >= 1 and row["landed_state"] == "ON_GROUND" and row["peer_up"]
            assert swarm.table()["uav1"]["local"]

            with pytest.raises(RequestInvalid, match="not a commandable node: uav9"):
                app.request_takeoff({"only": ["uav9"]})
            with pytest.raises(RequestInvalid, match="alt_m"):
                app.request_takeoff({"alt_m": 1000})
            member = swarm.daemons[1].app
            assert member is not None
            with pytest.raises(RequestInvalid, match="not a commander"):
                member.request_takeoff({})

            refused_all = app.request_takeoff({"require_all": True})
            assert refused_all["sent"] is False
            assert refused_all["refused"] == {"uav3": "prearm_failed"}

            sent = app.request_takeoff({"alt_m": 5.0})
            assert sent["sent"] and sent["refused"] == {"uav3": "prearm_failed"}
            assert sorted(sent["ready"]) == ["uav1", "uav2"]
            cid = sent["command_id"]
            await until(lambda: app.request_outcomes({"command_id": cid})["done"], lambda: cid)
            nodes = app.request_outcomes({"command_id": cid})["nodes"]
            assert nodes["uav1"]["state"] == "completed", nodes
            assert nodes["uav2"]["state"] == "completed", nodes
            assert nodes["uav2"]["latency_s"] is not None
            assert nodes["uav3"] == {
                "state": "refused",
                "reason": "prearm_failed",
                "latency_s": None,
                "done_s": None,
                "after_restart": False,
                "save_failed": False,
                "disarm_unconfirmed": False,
            }
            assert swarm.sims[0].model.armed and swarm.sims[1].model.armed
            assert not swarm.sims[2].model.armed
            await until(
                lambda: all(s.model.landed == LandedState.IN_AIR for s in swarm.sims[:2]),
                lambda: [s.model.landed for s in swarm.sims],
            )

            # sent to it anyway (raw command): the member refuses with its own live reason
            raw = app.request_command({"kind": "takeoff", "only": ["uav3"], "alt_m": 5})
            rid = raw["command_id"]
            await until(lambda: app.request_outcomes({"command_id": rid})["done"], lambda: rid)
            n3 = app.request_outcomes({"command_id": rid})["nodes"]["uav3"]
            assert n3["state"] == "rejected" and n3["reason"] == "prearm_failed"

            # land: every airborne drone acknowledges; the status carries it all
            land = app.request_command({"kind": "land", "only": ["uav1", "uav2"]})
            lid = land["command_id"]
            await until(lambda: app.request_outcomes({"command_id": lid})["done"], lambda: lid)
            states = app.request_outcomes({"command_id": lid})["nodes"]
            assert {n: s["state"] for n, s in states.items()} == {
                "uav1": "completed",
                "uav2": "completed",
            }
            # hold while descending: PX4's Hold (AUTO.LOITER) shows in every heartbeat
            hold = app.request_command({"kind": "hold", "only": ["uav1", "uav2"]})
            hid = hold["command_id"]
            await until(lambda: app.request_outcomes({"command_id": hid})["done"], lambda: hid)
            held = app.request_outcomes({"command_id": hid})["nodes"]
            assert {n: s["state"] for n, s in held.items()} == {
                "uav1": "completed",
                "uav2": "completed",
            }, held
            # abort in the air: the drones land (never a forced disarm)
            abort = app.request_command({"kind": "abort", "only": ["uav1", "uav2"]})
            aid = abort["command_id"]
            await until(lambda: app.request_outcomes({"command_id": aid})["done"], lambda: aid)
            aborted = app.request_outcomes({"command_id": aid})["nodes"]
            assert {n: (s["state"], s["reason"]) for n, s in aborted.items()} == {
                "uav1": ("completed", "NAV_LAND"),
                "uav2": ("completed", "NAV_LAND"),
            }, aborted
            status = swarm.commander.status()
            assert status["role"] == "commander" and status["dataplane"]["enabled"]
            assert [c["command_id"] for c in status["commands"]] == [cid, rid, lid, hid, aid]
            member_status = swarm.daemons[1].status()
            assert member_status["role"] == "member" and member_status["readiness"] == {}
            assert member_status["px4"]["enabled"]
            # the PX4 link's trust counters reach the status (swarmctl status --json)
            pin = member_status["px4"]["backend"]["autopilot"]
            assert pin["pinned"].startswith("127.0.0.1:") and pin["dropped_address"] == 0
            assert member_status["px4"]["readiness"]["landed_state"] != "ON_GROUND"
        finally:
            await swarm.stop()

    run_on_raw_clock(main())


def _dp(d: Daemon) -> dict[str, Any]:
    status: dict[str, Any] = d.status()["dataplane"]
    return status
