"""The full loop in network namespaces: per drone a ``swarmd run`` and a ``swarmd-vehicle-sim``
(a MAVLink vehicle SIMULATOR, not PX4) on the namespace's loopback, drones on one bridge.

- readiness reaches the commander's table (``swarmctl status``);
- ``--require-all`` with a drone whose simulated sensor fails pre-arm sends nothing (exit 3);
- take-off reaches the ready drones, each simulator goes airborne, the not-ready drones are
  refused with their reason, a raw command to one is refused by the drone itself;
- a killed simulator (PX4 link loss) flips the drone's readiness on the commander's table
  within 3 s, read from the daemons' own monotonic timestamps in ``status``;
- with 30 % of user-data packets dropped by an nftables rule in every namespace, each
  member executes the take-off exactly once.

Assertions are on states, counters and the daemons' timestamps, never on how fast the test
itself ran.
"""

from __future__ import annotations

import json
import signal
import subprocess
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from swarmd_lab.netns import Lan

from swarmd.control import DaemonUnreachable, RequestError, request
from swarmd.rawclock import raw_clock
from tests.conftest import LanFactory
from tests.daemon_support import (
    BIN,
    BundleFiles,
    Daemons,
    start_vehicle_sim,
    swarm_sections,
    write_bundle,
)
from tests.daemon_support import until as wait_until

WAIT_S = 40.0
LINK_LOSS_BOUND_S = 3.0  # the bound: PX4 link loss flips readiness within 3 s

pytestmark = [pytest.mark.netns]


class Drones:
    """N drones on a LAN: uav1 commands; ``sim_args[i]`` go to drone i's simulator."""

    def __init__(
        self, lan: Lan, workdir: Path, sim_args: list[list[str]], *, lease_s: float = 6.0
    ) -> None:
        self.lan = lan
        self.workdir = workdir
        self.n = len(sim_args)
        self.names = [f"uav{i + 1}" for i in range(self.n)]
        self.socks = [workdir / f"{n}.sock" for n in self.names]
        self.state = workdir / "state"  # the daemons' (dataplane state_dir)
        self.files: BundleFiles = write_bundle(
            workdir / "bundle", self.n, domain_id=0, lease_s=lease_s, t_min_s=0.2, t_max_s=0.6
        )
        self.daemons = Daemons(
            lan,
            workdir,
            self.files,
            self.names,
            extra=swarm_sections(self.state, "udpin:127.0.0.1:14540"),
        )
        self.sims: list[subprocess.Popen[bytes]] = []
        for i, name in enumerate(self.names):
            self.daemons.start(i)
            log = workdir / f"{name}-sim.log"
            self.sims.append(start_vehicle_sim(lan[i], i + 1, log, *sim_args[i]))

    def status(self, i: int = 0) -> dict[str, Any]:
        result: dict[str, Any] = request(str(self.socks[i]), "status")
        return result

    def table(self) -> dict[str, dict[str, Any]]:
        try:
            rows: dict[str, dict[str, Any]] = self.status()["readiness"]
        except (DaemonUnreachable, RequestError):
            return {}
        return rows

    def swarmctl(self, *args: str, timeout: float = 60.0) -> subprocess.CompletedProcess[str]:
        return self.lan[0].run(
            [str(BIN / "swarmctl"), *args, "--socket", str(self.socks[0])],
            timeout=timeout,
            check=False,
        )

    def sim_events(self, i: int, event: str) -> list[dict[str, Any]]:
        lines = (self.workdir / f"{self.names[i]}-sim.log").read_text().splitlines()
        parsed = [json.loads(x) for x in lines if x.startswith("{")]
        return [e for e in parsed if e.get("event") == event]


def until(cond: Callable[[], bool], what: Callable[[], object]) -> None:
    wait_until(cond, what, WAIT_S, not_yet=(DaemonUnreachable, KeyError))


def _ready(rows: dict[str, dict[str, Any]], name: str) -> bool:
    return bool(rows.get(name, {}).get("ready"))


def test_readiness_takeoff_refusal_and_link_loss(lan_factory: LanFactory, workdir: Path) -> None:
    lan = lan_factory(4)
    drones = Drones(lan, workdir, [[], [], [], ["--fail-prearm"]])

    # readiness reported: three ready, uav4 refused by its own pre-arm check
    until(
        lambda: (
            all(_ready(drones.table(), n) for n in ("uav1", "uav2", "uav3"))
            and drones.table()["uav4"]["reason"] == "prearm_failed"
            and drones.table()["uav2"]["count"] >= 2
        ),
        drones.table,
    )
    rows = drones.table()
    assert rows["uav1"]["local"] and not rows["uav2"]["local"]
    assert rows["uav2"]["landed_state"] == "ON_GROUND" and rows["uav2"]["gps_fix"] == 3
    shown = drones.swarmctl("status")
    assert shown.returncode == 0, shown.stderr
    assert "swarm readiness 3/4 ready" in shown.stdout
    assert "prearm_failed" in shown.stdout

    # --require-all: uav4 never becomes ready, so nothing is sent (exit 3)
    strict = drones.swarmctl("takeoff", "--require-all", "--timeout", "2")
    assert strict.returncode == 3, strict.stdout + strict.stderr
    assert "uav4 (prearm_failed)" in strict.stdout
    assert drones.status()["commands"] == []

    # one drone, all confirmed airborne: exit 0
    one = drones.swarmctl("takeoff", "--only", "uav2", "--alt", "5", "--json")
    assert one.returncode == 0, one.stdout + one.stderr
    body = json.loads(one.stdout)
    assert body["exit_code"] == 0 and body["nodes"]["uav2"]["state"] == "completed"
    assert body["nodes"]["uav2"]["latency_s"] is not None
    assert len(drones.sim_events(1, "armed")) == 1

    # PX4 link loss: the simulator dies; the commander's table flips within 3 s of it
    killed_at = raw_clock()  # the daemons' loops' clock (swarmd.rawclock), on this host
    drones.sims[2].send_signal(signal.SIGKILL)
    drones.sims[2].wait(timeout=10)
    until(lambda: drones.table()["uav3"]["reason"] == "heartbeat_stale", drones.table)
    st = drones.status()
    flipped_at = st["clock_s"] - st["readiness"]["uav3"]["since_s"]
    assert 0.0 < flipped_at - killed_at <= LINK_LOSS_BOUND_S, (killed_at, st["readiness"])

    # the rest: only the ready drone flies; the others are refused with their reason
    rest = drones.swarmctl("takeoff", "--alt", "5")
    assert rest.returncode == 1, rest.stdout + rest.stderr
    out = rest.stdout
    assert "uav3 (heartbeat_stale)" in out and "uav4 (prearm_failed)" in out
    assert "uav2 (armed)" in out  # already flying
    lines = {ln.split()[0]: ln.split() for ln in out.splitlines() if ln.startswith("  uav")}
    assert lines["uav1"][1] == "COMPLETED", out
    assert lines["uav4"][1:3] == ["REFUSED", "prearm_failed"], out
    until(
        lambda: (
            drones.table()["uav1"]["landed_state"] == "IN_AIR"
            and drones.table()["uav2"]["landed_state"] == "IN_AIR"
        ),
        drones.table,
    )
    assert len(drones.sim_events(0, "armed")) == 1
    assert drones.sim_events(3, "armed") == []

    # sent to uav4 anyway: the drone itself refuses, with its live reason
    raw = request(str(drones.socks[0]), "command", kind="takeoff", only=["uav4"], alt_m=5)
    cid = raw["command_id"]
    until(lambda: request(str(drones.socks[0]), "outcomes", command_id=cid)["done"], lambda: cid)
    n4 = request(str(drones.socks[0]), "outcomes", command_id=cid)["nodes"]["uav4"]
    assert (n4["state"], n4["reason"]) == ("rejected", "prearm_failed")


def _drop_user_data(lan: Lan, files: BundleFiles, percent: int) -> None:
    """nftables in every drone's namespace: drop ``percent`` % of arriving user-data UDP."""
    ports = ", ".join(str(files.bundle.user_port(p)) for p in files.bundle.participants)
    ruleset = f"""\
table inet swt_loss {{
  chain input {{
    type filter hook input priority 0; policy accept;
    udp dport {{ {ports} }} numgen random mod 100 < {percent} counter drop
  }}
}}
"""
    for host in lan:
        subprocess.run(  # noqa: S603 - fixed argv, ruleset on stdin
            host.command(["nft", "-f", "-"]), input=ruleset, text=True, check=True, timeout=10
        )


def _dropped(lan: Lan) -> int:
    total = 0
    for host in lan:
        out = host.run(["nft", "list", "table", "inet", "swt_loss"]).stdout
        total += sum(int(w) for w in _after(out.split(), "packets"))
    return total


def _after(words: list[str], key: str) -> list[str]:
    return [words[i + 1] for i, w in enumerate(words[:-1]) if w == key]


def test_exactly_once_with_30_percent_user_data_loss(
    lan_factory: LanFactory, workdir: Path
) -> None:
    lan = lan_factory(4)
    drones = Drones(lan, workdir, [[], [], [], []])
    _drop_user_data(lan, drones.files, 30)  # the namespaces (and the rule) die with the LAN
    until(
        lambda: (
            len(drones.table()) == drones.n and all(r["ready"] for r in drones.table().values())
        ),
        drones.table,
    )

    done = drones.swarmctl("takeoff", "--require-all", "--alt", "4", "--json")
    assert done.returncode == 0, done.stdout + done.stderr
    nodes = json.loads(done.stdout)["nodes"]
    assert {n: s["state"] for n, s in nodes.items()} == dict.fromkeys(drones.names, "completed")
    for i in range(1, drones.n):
        st = drones.status(i)
        assert st["executor"]["counters"]["received_takeoff"] == 1, st["executor"]
        assert st["dataplane"]["executed_commands"] == 1
        assert len(drones.sim_events(i, "armed")) == 1
    assert _dropped(lan) > 0  # the loss really happened
