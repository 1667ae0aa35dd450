"""Two commands to one drone, with real daemons in namespaces (docs/px4.md, "Two requests,
one vehicle"; docs/dataplane.md, "Validity", "Exactly once").

Three drones on one bridge (``swarmd run`` + ``swarmd-vehicle-sim`` each, lease 3 s; uav1
commands, uav2 is the drone told twice, uav3 a bystander). The commands cross the swarm's
real multicast and unicast; ``tests.test_flight_netns.cut`` drops a drone's traffic with
nftables in the receiver's namespace and ``heal`` deletes the rule.

- *A LAND while the take-off runs*: TAKEOFF, then LAND, while the take-off is arming (sent
  back to back: ARM on the wire, no NAV_TAKEOFF yet) or taking off (sent once the simulator
  armed: NAV_TAKEOFF on the wire, the motors spooling up, lift-off 1.5 s after the arm).
  The take-off ends FAILED ``superseded: land``, the LAND COMPLETED, the simulator never
  lifts off and disarms, and no NAV_TAKEOFF follows the NAV_LAND on its wire record.
- *A LAND that cannot arrive*: the take-off runs on uav2 when the link is cut both ways; the
  LAND sent then is withdrawn at its validity and told ``unreachable``; after the heal it
  never runs (uav2 never receives it, and the vehicle flies on), and the take-off's
  COMPLETED, held by the cut, arrives.
- *A TAKEOFF refused busy, resent across a heal*: a HOLD and a TAKEOFF back to back, uav2's
  answers cut: the TAKEOFF meets the running HOLD and is REJECTED ``busy``. The link is
  then cut both ways past a lease, so uav2 drops its reader state for uav1's writer; at the
  heal the commander resumes uav2 and pushes the same TAKEOFF (same id, still valid) again.
  uav2 drops it as a duplicate (``command_duplicate``): the vehicle, ready on the ground
  all along, never arms.

These run as namespace tests, not as flights: a flight scenario that sent two commands to
one drone would change the scenarios every run of the flight matrix was made with
(docs/benchmarks.md, "Flight").

Assertions are on states, counters and the daemons' and simulator's own records, never on
elapsed time; each wait has a cap so a stuck run fails instead of hanging.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import pytest
from swarmd_lab.netns import Lan

from swarmd.control import request
from swarmd.dataplane import TOPIC_COMMAND
from swarmd.swarm.commander import NOT_REACHED, UNREACHABLE
from tests.conftest import LanFactory
from tests.daemon_support import BIN
from tests.test_flight_netns import LEASE_S, cut, heal, until
from tests.test_takeoff_netns import Drones

pytestmark = [pytest.mark.netns]

COMMANDER, MEMBER, BYSTANDER = 0, 1, 2


class Trio(Drones):
    """Three drones (uav1 commands), each a ``swarmd run`` and a vehicle simulator, on a
    short lease; ready when built. ``member_sim``: uav2's simulator's extra arguments."""

    def __init__(self, lan: Lan, workdir: Path, member_sim: Sequence[str] = ()) -> None:
        super().__init__(lan, workdir, [[], list(member_sim), []], lease_s=LEASE_S)
        until(
            lambda: (
                len(self.table()) == self.n
                and all(r["ready"] for r in self.table().values())
                and self.table()["uav2"]["count"] >= 2
            ),
            lambda: self.table(),
        )

    def request(self, i: int, what: str, **args: Any) -> dict[str, Any]:
        """A control request to drone ``i``'s daemon."""
        result: dict[str, Any] = request(str(self.socks[i]), what, **args)
        return result

    def send(self, kind: str, *, valid_for_s: float | None = None) -> int:
        """The commander sends ``kind`` to uav2 (not followed); its command id."""
        args: dict[str, Any] = {"kind": kind, "only": ["uav2"]}
        if kind == "takeoff":
            args["alt_m"] = 5
        if valid_for_s is not None:
            args["valid_for_s"] = valid_for_s
        sent = self.request(COMMANDER, "command", **args)
        assert sent["sent"], sent
        return int(sent["command_id"])

    def row(self, command_id: int) -> dict[str, Any]:
        """The commander's row for uav2 in ``command_id`` (``swarmctl status --json``)."""
        (tracked,) = [c for c in self.status()["commands"] if c["command_id"] == command_id]
        node: dict[str, Any] = tracked["nodes"]["uav2"]
        return node

    def ran(self) -> dict[int, tuple[str, str]]:
        """What uav2 decided for each command id of uav1 (its ``outcomes``' ``ran``)."""
        rows = self.request(MEMBER, "outcomes")["ran"]
        return {
            r["command_id"]: (r["state"], r["reason"]) for r in rows if r["commander"] == "uav1"
        }

    def wire(self) -> list[str]:
        """The commands uav2's simulator received, in order (its ``command`` log lines)."""
        return [e["command"] for e in self.sim_events(MEMBER, "command")]

    def executor(self) -> dict[str, int]:
        counters: dict[str, int] = self.status(MEMBER)["executor"]["counters"]
        return counters

    def outcomes_json(self, i: int, *args: str) -> dict[str, Any]:
        """``swarmctl outcomes [ID] --json`` on drone ``i`` (exit code kept in the body)."""
        shown = self.lan[i].run(
            [str(BIN / "swarmctl"), "outcomes", *args, "--json", "--socket", str(self.socks[i])],
            timeout=30,
            check=False,
        )
        assert shown.returncode in (0, 1), shown.stderr
        body: dict[str, Any] = json.loads(shown.stdout)
        body["_exit"] = shown.returncode
        return body


def _two_way(swarm: Trio) -> list[Any]:
    """Cut uav1 <-> uav2 both ways (every packet, discovery too); the hosts to heal."""
    commander, member = swarm.lan[COMMANDER], swarm.lan[MEMBER]
    cut([commander], [member])
    cut([member], [commander])
    return [commander, member]


# ---- 1. a LAND while the take-off runs ---------------------------------------------------


@pytest.mark.parametrize("phase", ["arming", "taking-off"])
def test_a_land_while_the_takeoff_runs_supersedes_it(
    lan_factory: LanFactory, workdir: Path, phase: str
) -> None:
    swarm = Trio(lan_factory(3), workdir)
    takeoff = swarm.send("takeoff")
    if phase == "taking-off":
        # PX4 (the simulator) armed: the take-off's NAV_TAKEOFF follows at once, and lift-off
        # is 1.5 s after the arm (docs/px4.md, the simulator), so the take-off still runs
        until(lambda: len(swarm.sim_events(MEMBER, "armed")) == 1, swarm.wire)
    land = swarm.send("land")

    until(lambda: swarm.row(land)["state"] == "completed", lambda: swarm.status()["commands"])
    until(lambda: swarm.row(takeoff)["state"] == "failed", lambda: swarm.row(takeoff))
    assert swarm.row(takeoff)["reason"] == "superseded: land"
    ran = swarm.ran()
    assert ran[takeoff] == ("failed", "superseded: land"), ran
    assert ran[land] == ("completed", ""), ran

    # the vehicle: PX4's pre-flight disarm (COM_DISARM_PRFLT, 10 s after the arm) ends the
    # LAND that began on the ground; it never lifted off
    until(lambda: len(swarm.sim_events(MEMBER, "disarmed")) == 1, swarm.wire)
    modes = [e["new"] for e in swarm.sim_events(MEMBER, "mode")]
    assert modes[-1] == "AUTO.LAND", modes
    texts = [e["text"] for e in swarm.sim_events(MEMBER, "statustext")]
    assert "Takeoff detected" not in texts, texts
    assert swarm.table()["uav2"]["landed_state"] == "ON_GROUND"
    # its wire: one NAV_LAND, and no NAV_TAKEOFF after it (the superseded take-off sent
    # nothing more: no retransmission, no DISARM)
    wire = swarm.wire()
    print(f"{phase}: uav2's simulator received {wire}")
    assert wire.count("NAV_LAND") == 1, wire
    after_land = wire[wire.index("NAV_LAND") + 1 :]
    assert "NAV_TAKEOFF" not in after_land and "COMPONENT_ARM_DISARM" not in after_land, wire
    if phase == "taking-off":
        assert wire.index("NAV_TAKEOFF") < wire.index("NAV_LAND"), wire
        (armed,) = swarm.sim_events(MEMBER, "armed")
        (landing,) = [e for e in swarm.sim_events(MEMBER, "command") if e["command"] == "NAV_LAND"]
        # the margin this case has: lift-off is 1.5 s after the arm in the simulator
        print(
            f"taking-off: NAV_LAND reached the simulator "
            f"{landing['t'] - armed['t']:.3f} s after the arm"
        )
    assert len(swarm.sim_events(MEMBER, "armed")) == 1

    # the operator's record, on the commander and on the drone
    issued = swarm.outcomes_json(COMMANDER)
    by_id = {c["command_id"]: c["nodes"]["uav2"] for c in issued["issued"]}
    assert (by_id[takeoff]["state"], by_id[takeoff]["reason"]) == ("failed", "superseded: land")
    assert by_id[land]["state"] == "completed"
    assert issued["_exit"] == 1  # a shown command was not executed: the take-off
    kept = swarm.outcomes_json(MEMBER)
    mine = {r["command_id"]: (r["state"], r["reason"]) for r in kept["ran"]}
    assert mine == {takeoff: ("failed", "superseded: land"), land: ("completed", "")}, mine
    assert swarm.executor().get("received_takeoff", 0) == 1
    assert swarm.sim_events(BYSTANDER, "armed") == []  # the copies name their target


# ---- 2. a LAND that cannot arrive --------------------------------------------------------


def test_a_land_withdrawn_while_cut_never_runs_after_the_heal(
    lan_factory: LanFactory, workdir: Path
) -> None:
    # PX4 refuses the first two ARMs (TEMPORARILY_REJECTED, retried 0.5 s later): the
    # take-off's lift-off, and its COMPLETED, come more than 2.5 s after its first ARM
    swarm = Trio(lan_factory(3), workdir, member_sim=["--reject-arms", "2"])
    takeoff = swarm.send("takeoff")
    # the take-off runs on uav2 (its first ARM is on the wire) when the link is cut both ways
    until(lambda: "COMPONENT_ARM_DISARM" in swarm.wire(), swarm.wire)
    hosts = _two_way(swarm)
    seq_before = swarm.status()["peer_changes"]["last_seq"]

    # the operator's LAND, valid 2 s: it cannot arrive; swarmctl follows it to its end
    shown = swarm.swarmctl("land", "--only", "uav2", "--valid-for", "2", "--json")
    body = json.loads(shown.stdout)
    land = int(body["command_id"])
    told = body["nodes"]["uav2"]
    assert (told["state"], told["reason"]) == (UNREACHABLE, NOT_REACHED), body
    assert shown.returncode != 0, shown.stdout
    # the take-off flew on beyond the cut: uav2's own status, its answers held by the cut
    until(
        lambda: swarm.status(MEMBER)["px4"]["readiness"]["landed_state"] == "IN_AIR",
        lambda: swarm.status(MEMBER)["px4"],
    )
    assert swarm.row(takeoff)["state"] != "completed"
    # uav1 loses uav2 by lease: nothing of uav2's crosses the cut
    until(
        lambda: any(
            c["peer"] == "uav2" and c["change"] == "lost"
            for c in swarm.status()["peer_changes"]["changes"]
            if c["seq"] > seq_before
        ),
        lambda: swarm.status()["peer_changes"],
    )

    assert heal(hosts) > 0  # the cut really dropped traffic
    until(lambda: swarm.row(takeoff)["state"] == "completed", lambda: swarm.row(takeoff))
    # uav2 is heard again (a readiness report after the heal) and still never saw the LAND
    count = swarm.table()["uav2"]["count"]
    until(lambda: swarm.table()["uav2"]["count"] > count + 1, lambda: swarm.table())
    assert land not in swarm.ran(), swarm.ran()
    assert swarm.ran()[takeoff][0] == "completed"
    assert "NAV_LAND" not in swarm.wire(), swarm.wire()
    assert len(swarm.sim_events(MEMBER, "armed")) == 1
    row = swarm.row(land)
    assert (row["state"], row["reason"]) == (UNREACHABLE, NOT_REACHED), row
    counters = swarm.executor()
    assert counters.get("received_takeoff", 0) == 1, counters
    assert counters.get("refused_expired", 0) == 0, counters  # no copy of it ever came
    # the commander withdrew it at its validity's end: no repair carried it across the heal
    writer = swarm.status()["dataplane"]["writers"][TOPIC_COMMAND]
    # the LAND's, and the take-off's when the cut came before uav2 acknowledged it
    assert writer["withdrawn"] >= 1, writer
    kept = swarm.outcomes_json(COMMANDER, str(land))
    (shown_land,) = kept["issued"]
    assert shown_land["nodes"]["uav2"]["state"] == UNREACHABLE, kept
    assert kept["_exit"] == 1  # a shown command was not executed


# ---- 3. a TAKEOFF refused busy, resent across a heal -------------------------------------


def test_a_takeoff_refused_busy_never_runs_when_resent_after_a_heal(
    lan_factory: LanFactory, workdir: Path
) -> None:
    swarm = Trio(lan_factory(3), workdir)
    commander, member = swarm.lan[COMMANDER], swarm.lan[MEMBER]
    # uav2's answers (its ACKNACKs and outcomes too) are cut: the commander keeps both
    # commands unacknowledged in its history for their whole validity (30 s: past the heal)
    cut([commander], [member])
    hold = swarm.send("hold", valid_for_s=30)
    takeoff = swarm.send("takeoff", valid_for_s=30)
    # ACCEPTED at once, then the vehicle's answer: the request reaches the vehicle after
    # the state write (the writer's thread, docs/operations.md, "A slow SD card")
    until(lambda: swarm.ran().get(takeoff, ("accepted",))[0] != "accepted", lambda: swarm.ran())
    assert swarm.ran()[takeoff] == ("rejected", "busy"), swarm.ran()
    until(lambda: swarm.ran().get(hold, ("",))[0] == "completed", lambda: swarm.ran())

    # now both ways, past a lease: uav2 loses uav1 and drops its reader state for it
    cut([member], [commander])
    seq = swarm.status(MEMBER)["peer_changes"]["last_seq"]
    until(
        lambda: any(
            c["peer"] == "uav1" and c["change"] == "lost"
            for c in swarm.status(MEMBER)["peer_changes"]["changes"]
            if c["seq"] > seq
        ),
        lambda: swarm.status(MEMBER)["peer_changes"],
    )
    delivered = _reader(swarm)["delivered"]
    duplicates = _plane_counters(swarm).get("command_duplicate", 0)

    assert heal([commander, member]) > 0
    # the commander resumes uav2 and pushes its unacknowledged copies again, the TAKEOFF's
    # (same id, still valid) among them; uav2's reader, reset by the loss, delivers them
    # anew, and the plane drops each by its id before the swarm core sees it
    until(lambda: _reader(swarm)["delivered"] >= delivered + 2, lambda: swarm.status(MEMBER))
    assert swarm.executor().get("received_takeoff", 0) == 1, swarm.executor()
    # the REJECTED busy, held by the cut, reaches the operator
    until(lambda: swarm.row(takeoff)["state"] == "rejected", lambda: swarm.row(takeoff))
    assert swarm.row(takeoff)["reason"] == "busy"
    assert swarm.ran()[takeoff] == ("rejected", "busy")
    # never ran: the vehicle, ready on the ground all along, never armed
    assert swarm.sim_events(MEMBER, "armed") == []
    assert "NAV_TAKEOFF" not in swarm.wire(), swarm.wire()
    assert swarm.table()["uav2"]["ready"], swarm.table()
    assert _plane_counters(swarm).get("command_duplicate", 0) >= duplicates + 2


def _reader(swarm: Trio) -> dict[str, int]:
    """uav2's reader of uav1's commands: its counters (``delivered``: samples handed up)."""
    reader: dict[str, int] = swarm.status(MEMBER)["dataplane"]["readers"][TOPIC_COMMAND]
    return reader


def _plane_counters(swarm: Trio) -> dict[str, int]:
    counters: dict[str, int] = swarm.status(MEMBER)["dataplane"]["counters"]
    return counters
