"""Five swarmd processes in five network namespaces on one bridge, plus a stock Cyclone DDS
participant: discovery, matched endpoints, SIGKILL (lost after the lease), SIGTERM (dropped
at once by DATA(p[UD])), garbage on both ports, and the Cyclone node listed as foreign.

Assertions are on states, counters and logged reasons, never on elapsed time.
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from swarmd_lab.netns import Lan

from tests.conftest import CycloneFactory, LanFactory
from tests.daemon_support import daemon_status, until, write_bundle, write_config

BIN = Path(sys.executable).parent
N = 5
LEASE_S = 3.0  # short, so a SIGKILLed daemon is declared lost quickly
WAIT_S = 30.0

pytestmark = [pytest.mark.netns, pytest.mark.interop]


def _until(cond: Callable[[], bool], what: Callable[[], str]) -> None:
    until(cond, what, WAIT_S)


def _status(sock: Path) -> dict[str, Any]:
    return daemon_status(sock)


def _states(sock: Path) -> dict[str, str]:
    return {p["name"]: p["state"] for p in _status(sock)["peers"]}


def _log(path: Path) -> list[dict[str, Any]]:
    return [json.loads(line) for line in path.read_text().splitlines() if line.startswith("{")]


def test_five_daemons_in_namespaces(
    lan_factory: LanFactory, cyclone_factory: CycloneFactory, workdir: Path
) -> None:
    lan: Lan = lan_factory(N + 1)  # host N runs the stock Cyclone participant
    files = write_bundle(
        workdir,
        N,
        domain_id=0,  # Cyclone's default domain; the namespaces keep it private
        lease_s=LEASE_S,
        ipv4=[h.address for h in lan.hosts[:N]],
    )
    names = [f"uav{i + 1}" for i in range(N)]
    socks = [workdir / f"{n}.sock" for n in names]
    logs = [workdir / f"{n}.log" for n in names]
    procs: list[subprocess.Popen[bytes]] = []
    for i, name in enumerate(names):
        cfg = write_config(
            workdir / f"{name}.yaml",
            files,
            node=name,
            interface=lan[i].ifname,  # ipv4 derived from the interface
            socket_path=str(socks[i]),
        )
        with logs[i].open("wb") as err:
            procs.append(
                lan[i].popen([str(BIN / "swarmd"), "run", "--config", str(cfg)], stderr=err)
            )
    cyclone = cyclone_factory(lan[N])

    # every daemon discovers the other four, with their endpoints matched from the bundle
    def all_discovered() -> bool:
        return all(
            sum(state == "discovered" for state in _states(s).values()) == N - 1 for s in socks
        )

    _until(all_discovered, lambda: str([_states(s) for s in socks if s.exists()]))
    for i, sock in enumerate(socks):
        proc = lan[i].run([str(BIN / "swarmctl"), "status", "--json", "--socket", str(sock)])
        st = json.loads(proc.stdout)
        assert st["node"] == names[i]
        assert st["peers_discovered"] == N - 1
        assert st["daemon"]["ipv4"] == lan[i].address
        for peer in st["peers"]:
            # uav1 commands: every member pairs ready+command+outcome with it, members
            # share nothing
            expected = 3 if 0 in (i, peer["index"]) else 0
            assert peer["matched_endpoints"] == expected, (names[i], peer)
            assert peer["locator"] == f"udp/{lan[peer['index']].address}:{7410 + 2 * peer['index']}"

    # the stock Cyclone participant is listed as foreign, never matched
    def cyclone_seen() -> bool:
        return any("Cyclone" in f["vendor"] for f in _status(socks[0])["foreign"])

    _until(cyclone_seen, lambda: str(_status(socks[0])["foreign"]))
    foreign = _status(socks[0])["foreign"]
    assert any(f["guid"].startswith(f"{cyclone.prefix}:") for f in foreign), foreign
    assert all(p["name"].startswith("uav") for p in _status(socks[0])["peers"])

    # garbage to uav2's metatraffic and SPDP ports: counted and dropped, uav2 keeps running
    before = _status(socks[1])["counters"]["dropped"]["decode_error"]
    junk = lan[0].socket()
    try:
        for payload in (b"\x00" * 3, b"RTPS", b"\xff" * 500):
            junk.sendto(payload, (lan[1].address, 7412))
            junk.sendto(payload, (lan[1].address, 7400))
    finally:
        junk.close()
    _until(
        lambda: _status(socks[1])["counters"]["dropped"]["decode_error"] >= before + 6,
        lambda: str(_status(socks[1])["counters"]),
    )
    assert procs[1].poll() is None
    assert _status(socks[1])["daemon"]["healthy"]

    # SIGTERM: uav4 sends DATA(p[UD]) and the others drop it at once;
    # SIGKILL: uav5 just goes silent and is lost when its lease runs out
    procs[3].send_signal(signal.SIGTERM)
    assert procs[3].wait(timeout=WAIT_S) == 0
    procs[4].send_signal(signal.SIGKILL)
    procs[4].wait(timeout=WAIT_S)

    def both_lost() -> bool:
        return all(_states(s)["uav4"] == "lost" and _states(s)["uav5"] == "lost" for s in socks[:3])

    _until(both_lost, lambda: str([_states(s) for s in socks[:3]]))
    for i in range(3):
        reasons = {e["peer"]: e["reason"] for e in _log(logs[i]) if e["event"] == "peer_lost"}
        assert reasons == {"uav4": "disposed", "uav5": "lease"}, names[i]
    assert not socks[3].exists()  # clean shutdown removed its control socket
