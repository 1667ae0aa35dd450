"""A bundle member never seen since boot, with real daemons in namespaces (session 17
review, from the operator's seat).

Three drones in the bundle; uav1 (commander) and uav2 run ``swarmd run`` and a
``swarmd-vehicle-sim`` each, uav3 never starts. ``swarmctl takeoff`` waits for every
targeted drone to report, so its wait for uav3 lasts the whole ``--timeout``; then it
sends to the ready drones. Before, the follow shared the spent budget: swarmctl left at
its first poll with uav1 and uav2 ``pending`` ("timed out waiting for the rest") while
both took off. Now every drone gets one verdict, and ``swarmctl outcomes`` and ``status``
say the same.

Assertions are on states, never on how fast the test ran.
"""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import pytest

from swarmd.control import request
from swarmd.exitcodes import EX_FAILED, EX_OK
from tests.conftest import LanFactory
from tests.daemon_support import BIN, Daemons, start_vehicle_sim, swarm_sections, write_bundle
from tests.test_takeoff_netns import until

pytestmark = [pytest.mark.netns]

TIMEOUT_S = 6.0  # swarmctl's --timeout: the wait for uav3, then again the follow


def test_a_member_never_seen_is_refused_and_the_others_are_followed_to_the_end(
    lan_factory: LanFactory, workdir: Path
) -> None:
    lan = lan_factory(2)
    files = write_bundle(workdir / "bundle", 3, domain_id=0, lease_s=6.0, t_min_s=0.2,
                         t_max_s=0.6)  # fmt: skip
    daemons = Daemons(lan, workdir, files, ["uav1", "uav2"],
                      extra=swarm_sections(workdir / "state", "udpin:127.0.0.1:14540"))  # fmt: skip
    for i in range(2):
        daemons.start(i)
        start_vehicle_sim(lan[i], i + 1, workdir / f"uav{i + 1}-sim.log")

    def swarmctl(*args: str) -> subprocess.CompletedProcess[str]:
        return lan[0].run(
            [str(BIN / "swarmctl"), *args, "--socket", str(daemons.socks[0])],
            timeout=60,
            check=False,
        )

    def table() -> dict[str, dict[str, object]]:
        rows: dict[str, dict[str, object]] = request(str(daemons.socks[0]), "status")["readiness"]
        return rows

    until(lambda: all(table()[n]["ready"] for n in ("uav1", "uav2")), table)
    # the operator sees it in swarmctl status
    assert table()["uav3"]["reason"] == "no_report"
    assert "no_report" in swarmctl("status").stdout

    proc = swarmctl("takeoff", "--alt", "5", "--timeout", str(TIMEOUT_S), "--json")
    body = json.loads(proc.stdout)
    assert proc.returncode == EX_FAILED, proc.stderr  # uav3 was not airborne
    states = {n: (v["state"], v["reason"]) for n, v in body["nodes"].items()}
    assert states["uav3"] == ("refused", "no_report"), body
    assert states["uav1"][0] == states["uav2"][0] == "completed", (body, proc.stderr)
    assert sorted(states) == ["uav1", "uav2", "uav3"]  # every drone, once
    assert body["sent"] is True and body["done"]

    # afterwards, the view of what became of it says the same, drone by drone
    cid = body["command_id"]
    kept = swarmctl("outcomes", f"{cid:#x}", "--json")
    assert kept.returncode == EX_FAILED
    (issued,) = json.loads(kept.stdout)["issued"]
    assert {n: (v["state"], v["reason"]) for n, v in issued["nodes"].items()} == states

    # and the human view names uav3 and why, once
    human = swarmctl("outcomes", f"{cid:#x}")
    assert human.stdout.count("uav3") == 2, human.stdout  # its table row, the summary
    assert "uav3 (refused: no_report)" in human.stdout
    assert swarmctl("outcomes", "--json").returncode != EX_OK
