"""Issue 18's late take-off, with real daemons in namespaces: it no longer runs.

Three drones (``swarmd run`` + ``swarmd-vehicle-sim`` each, ``tests.test_takeoff_netns``),
a lease of 20 s. uav3's radio is cut (nftables drops everything on its ``eth0``, both ways);
right after, ``swarmctl takeoff --only uav3 --valid-for 3`` (uav3's last report is still
fresh). swarmctl ends when the validity and its grace are over and says ``unreachable``.

Meanwhile a recorder on uav3's own link (an AF_PACKET socket: it sees frames before
nftables drops them, as a radio near uav3 would) has kept the commander's TAKEOFF datagram;
after the validity it releases it at uav3 (over uav3's loopback, which the cut spares):
authentic, fresh in the replay window, late. That is the delay attack; a plain cut can no
longer deliver the command at all, because the commander withdrew it when it expired. The
link returns after 8 s. uav3 never arms, its counters show the expired refusal, and its
REJECTED ``expired`` reaches the commander's row once the link is back.

Assertions are on states and counters, never on how fast the test ran.
"""

from __future__ import annotations

import json
import subprocess
import time
from pathlib import Path

import pytest

from swarmd.dataplane.validity import EXPIRED
from swarmd.rtps.ports import spdp_multicast_port
from swarmd.swarm.commander import UNREACHABLE
from tests.attacker.host import Attacker
from tests.conftest import LanFactory
from tests.daemon_support import BIN
from tests.test_takeoff_netns import Drones, until

pytestmark = [pytest.mark.netns]

CUT_S = 8.0
VALID_FOR_S = 3.0
TAKEOFF_MIN_BYTES = 150  # DATA(TAKEOFF) + HEARTBEAT + AUTH; a heartbeat alone is ~70


def _cut(drones: Drones, i: int) -> None:
    ifname = drones.lan[i].ifname
    ruleset = f"""\
table inet swt_cut {{
  chain input {{ type filter hook input priority 0; policy accept; iifname "{ifname}" drop; }}
  chain output {{ type filter hook output priority 0; policy accept; oifname "{ifname}" drop; }}
}}
"""
    subprocess.run(  # noqa: S603 - fixed argv, ruleset on stdin
        drones.lan[i].command(["nft", "-f", "-"]), input=ruleset, text=True, check=True, timeout=10
    )


def _restore(drones: Drones, i: int) -> None:
    drones.lan[i].run(["nft", "delete", "table", "inet", "swt_cut"])


def test_a_takeoff_that_cannot_reach_its_drone_in_time_never_runs(
    lan_factory: LanFactory, workdir: Path
) -> None:
    lan = lan_factory(3)
    drones = Drones(lan, workdir, [[], [], []], lease_s=20.0)
    until(
        lambda: (
            len(drones.table()) == drones.n and all(r["ready"] for r in drones.table().values())
        ),
        drones.table,
    )
    uav3 = drones.files.bundle.participant("uav3")
    user_port = drones.files.bundle.user_port(uav3)
    recorder = Attacker(lan[2], ("239.255.0.1", spdp_multicast_port(0))).start()
    try:
        _cut(drones, 2)
        cut_at = time.monotonic()
        ctl = lan[0].popen(
            [
                str(BIN / "swarmctl"),
                "takeoff",
                "--only",
                "uav3",
                "--valid-for",
                str(VALID_FOR_S),
                "--alt",
                "5",
                "--timeout",
                "30",
                "--json",
                "--socket",
                str(drones.socks[0]),
            ],
            stdout=subprocess.PIPE,
        )

        def takeoff_datagram() -> bytes | None:
            for c in recorder.capture(
                cut_at,
                lambda c: c.dst == (lan[2].address, user_port) and c.src[0] == lan[0].address,
            ):
                if len(c.payload) >= TAKEOFF_MIN_BYTES:
                    return c.payload
            return None

        until(lambda: takeoff_datagram() is not None, lambda: "no TAKEOFF seen on uav3's link")
        held = takeoff_datagram()
        assert held is not None
        # released after the validity, while uav3 still believes the commander is up
        time.sleep(max(0.0, cut_at + VALID_FOR_S + 1.5 - time.monotonic()))
        recorder.send(held, (lan[2].address, user_port))

        out, _ = ctl.communicate(timeout=40)
        body = json.loads(out)
        assert ctl.returncode == 1, body
        assert body["exit_code"] == 1
        node = body["nodes"]["uav3"]
        assert node["state"] == UNREACHABLE, body
        assert body["valid_for_s"] == VALID_FOR_S and body["done"]
        cid = body["command_id"]

        time.sleep(max(0.0, cut_at + CUT_S - time.monotonic()))
        _restore(drones, 2)
    finally:
        recorder.close()

    # the member refused the late command and counted it; its answer reaches the commander
    until(
        lambda: drones.status(2)["executor"]["counters"].get("refused_expired") == 1,
        lambda: drones.status(2)["executor"],
    )
    counters = drones.status(2)["executor"]["counters"]
    assert counters.get("outcome_rejected") == 1 and "outcome_accepted" not in counters
    assert drones.status(2)["dataplane"]["readers"]["swarm/command"]["delivered"] == 1
    until(
        lambda: (
            drones.status()["readiness"]["uav3"]["ready"]
            and next(c for c in drones.status()["commands"] if c["command_id"] == cid)["nodes"][
                "uav3"
            ]["reason"]
            == EXPIRED
        ),
        lambda: drones.status()["commands"],
    )
    # and it never armed, though the link is back and the drone is ready
    assert drones.sim_events(2, "armed") == []
    assert drones.status()["readiness"]["uav3"]["landed_state"] == "ON_GROUND"
    writer = drones.status()["dataplane"]["writers"]["swarm/command"]
    assert writer["withdrawn"] == 1
