"""The lost answer across a restart, with real daemons in namespaces (issue 20).

Four drones (``swarmd run`` + ``swarmd-vehicle-sim`` each, ``tests.test_flight_netns``'s
``Swarm``, lease 3 s). An nftables rule in the commander's (uav1's) namespace drops what
uav2 sends (``cut``): uav2 still receives what uav1 sends, so the TAKEOFF reaches it, but its
ACCEPTED and COMPLETED never arrive. Two rules, because they take the commander down two
paths: every packet from uav2's address (the one-way radio loss the defect is about; uav1
also loses uav2 by lease, then regains its new life), or only what uav2 sends to uav1's
user-data port (discovery still passes, so uav1 keeps uav2 up and sees the restart as a new
signed epoch, ``restarted``). ``swarmctl takeoff --only uav2`` then ends saying
``unreachable`` while uav2's vehicle is airborne, read from uav2's own ``swarmctl status``.

uav2's daemon is SIGKILLed once its outcome is in its state file, and restarted; the rule is
deleted before the restart, or after it (the new life then re-reports into the cut, and the
reliable writer's repair has to carry it once the rule goes). With the state file kept, the
commander's row ends ``completed`` (reason: the landed state uav2 completed the take-off in)
with ``after_restart``, and uav2 counts one re-reported outcome. With it deleted (the
control case), the new life has nothing to re-report, writes no outcome, and the row stays
``unreachable``. Either way the vehicle armed once and the new life received no take-off
(docs/dataplane.md, "Outcomes across a restart").

Assertions are on states, counters and the daemons' own records, never on elapsed time;
each wait has a cap so a stuck run fails instead of hanging.
"""

from __future__ import annotations

import json
import math
import signal
from pathlib import Path
from typing import Any

import pytest
from swarmd_lab.demo.observe import read_log

from swarmd.dataplane import TOPIC_OUTCOME
from swarmd.dataplane.types import CommandResult
from swarmd.dataplane.writer import HEARTBEAT_BACKOFF, HEARTBEAT_PERIOD_S, MAX_HEARTBEAT_PERIOD_S
from swarmd.statefile import load, state_path
from swarmd.swarm.commander import NOT_REACHED, UNREACHABLE
from tests.conftest import LanFactory
from tests.daemon_support import BIN
from tests.test_flight_netns import Swarm, cut, heal, until

pytestmark = [pytest.mark.netns]

# heartbeats a writer sends unanswered before its period reaches its maximum (writer.py)
HEARTBEATS_TO_MAX_PERIOD = 1 + math.ceil(
    math.log(MAX_HEARTBEAT_PERIOD_S / HEARTBEAT_PERIOD_S, HEARTBEAT_BACKOFF)
)
COMMANDER, MEMBER = 0, 1  # uav1 commands; uav2 is the member whose answer is lost


def _row(swarm: Swarm, command_id: int) -> dict[str, Any]:
    """The commander's row for uav2 in ``command_id``, as ``swarmctl status --json`` lists
    its tracked commands."""
    (tracked,) = [c for c in swarm.status(COMMANDER)["commands"] if c["command_id"] == command_id]
    node: dict[str, Any] = tracked["nodes"]["uav2"]
    return node


def _kept(swarm: Swarm) -> list[list[Any]]:
    """uav2's persisted outcomes (the state file's ``outcomes``), [] before the file exists."""
    path = state_path(swarm.state, "uav2")
    return [list(o) for o in load(path).outcomes] if path.exists() else []


def _completed(swarm: Swarm, command_id: int) -> str:
    """Wait until uav2 has persisted COMPLETED for ``command_id``; its reason: the landed
    state the take-off ended in (TAKEOFF or IN_AIR)."""

    def completed() -> list[list[Any]]:
        done = ["uav1", command_id, CommandResult.COMPLETED.value]
        return [o for o in _kept(swarm) if o[:3] == done]

    until(lambda: len(completed()) == 1, lambda: _kept(swarm))
    ((*_, landed),) = completed()
    return str(landed)


def _ready_and_cut(swarm: Swarm, *, user_data_only: bool) -> None:
    """Once every drone is ready, the rule in uav1's namespace: what uav2 sends to uav1,
    everything, or only to uav1's user-data port (discovery then keeps uav2 up at uav1,
    which sees the restart as a new epoch, not a loss)."""
    until(
        lambda: len(swarm.table()) == swarm.n and all(r["ready"] for r in swarm.table().values()),
        lambda: swarm.table(),
    )
    # cut right after a fresh report, so uav2's row is still fresh when the take-off is issued
    count = swarm.table()["uav2"]["count"]
    until(lambda: swarm.table()["uav2"]["count"] > count, lambda: swarm.table())
    ports = [swarm.files.bundle.user_port(swarm.files.bundle.participants[COMMANDER])]
    cut([swarm.lan[COMMANDER]], [swarm.lan[MEMBER]], udp_ports=ports if user_data_only else ())


def _kill(swarm: Swarm, *, state_kept: bool) -> None:
    """uav2's daemon dies (no goodbye); its vehicle flies on. Its state file stays or goes."""
    swarm.daemons.procs[MEMBER].send_signal(signal.SIGKILL)
    swarm.daemons.procs[MEMBER].wait(timeout=10)
    if not state_kept:
        state_path(swarm.state, "uav2").unlink()


@pytest.mark.parametrize(
    "heal_first", [True, False], ids=["heal-then-restart", "restart-then-heal"]
)
@pytest.mark.parametrize("state_kept", [True, False], ids=["state-kept", "state-lost"])
@pytest.mark.parametrize("user_data_only", [False, True], ids=["all", "user-data"])
def test_an_answer_lost_before_a_restart_is_told_after_it(
    lan_factory: LanFactory,
    workdir: Path,
    state_kept: bool,
    heal_first: bool,
    user_data_only: bool,
) -> None:
    swarm = Swarm(lan_factory(4), workdir)
    _ready_and_cut(swarm, user_data_only=user_data_only)
    commander = swarm.lan[COMMANDER]
    seq_before = swarm.status(COMMANDER)["peer_changes"]["last_seq"]

    up = swarm.swarmctl("takeoff", "--only", "uav2", "--alt", "5", "--json")
    body = json.loads(up.stdout)
    cid = body["command_id"]
    # the operator is told what the commander knows: no answer while it was valid
    told = body["nodes"]["uav2"]
    assert (told["state"], told["reason"], told["after_restart"]) == (
        UNREACHABLE,
        NOT_REACHED,
        False,
    ), body
    assert up.returncode != 0, up.stdout
    # ... but uav2 took it: its own status says its vehicle is in the air, and its answers
    # (the outcome kept next to the executed id) are in its state file
    until(
        lambda: swarm.status(MEMBER)["px4"]["readiness"]["landed_state"] == "IN_AIR",
        lambda: swarm.status(MEMBER)["px4"],
    )
    landed = _completed(swarm, cid)
    assert swarm.armed(MEMBER) == 1
    epoch_before = swarm.status(MEMBER)["dataplane"]["epoch"]

    _kill(swarm, state_kept=state_kept)  # with its answers unheard
    if heal_first:
        assert heal([commander]) > 0  # the cut really dropped uav2's traffic
    swarm.daemons.start(MEMBER)

    def new_life() -> dict[str, Any]:
        st: dict[str, Any] = swarm.status(MEMBER)
        assert st["dataplane"]["epoch"] != epoch_before  # an old socket's answer: not yet
        return st

    rereported = 1 if state_kept else 0
    if not heal_first:
        # the new life finds the commander through the cut and re-reports into it
        until(
            lambda: (
                "uav1" in {p["name"] for p in new_life()["peers"] if p["state"] == "discovered"}
                and new_life()["dataplane"]["outcomes_rereported"] == rereported
            ),
            lambda: swarm.status(MEMBER),
        )
        assert _row(swarm, cid)["state"] == UNREACHABLE  # nothing got through the cut
        assert heal([commander]) > 0

    # the commander knows uav2's new life and hears its reports again
    def heard_again() -> bool:
        epoch = new_life()["dataplane"]["epoch"]
        row = swarm.table()["uav2"]
        return bool(
            swarm.status(COMMANDER)["dataplane"]["peer_epochs"].get("uav2") == epoch
            and row["peer_up"]
            and row["landed_state"] == "IN_AIR"
        )

    until(heard_again, lambda: (swarm.table().get("uav2"), swarm.status(COMMANDER)["dataplane"]))
    if state_kept:
        # the re-report arrives: the row says what uav2 did, told after its restart
        until(lambda: _row(swarm, cid)["state"] == "completed", lambda: _row(swarm, cid))
        until(
            lambda: new_life()["dataplane"]["writers"][TOPIC_OUTCOME]["unacked_readers"] == 0,
            lambda: new_life()["dataplane"]["writers"],
        )
        outcome_writer = new_life()["dataplane"]["writers"][TOPIC_OUTCOME]
        print(f"uav2's new life, outcome writer: {outcome_writer}")
        assert outcome_writer["written"] == 1  # the re-report, and nothing else
        if not heal_first:  # its first copy went into the cut: a repair carried it
            assert outcome_writer["data_resent"] + outcome_writer["handed_over"] >= 1
    else:
        # nothing to re-report: the new life wrote no outcome, so none can come; the row
        # is read once the commander hears the new life's readiness (the same link)
        assert new_life()["dataplane"]["writers"][TOPIC_OUTCOME]["written"] == 0
        count = swarm.table()["uav2"]["count"]
        until(lambda: swarm.table()["uav2"]["count"] > count + 1, lambda: swarm.table())

    seen = [
        (c["change"], c["reason"])
        for c in swarm.status(COMMANDER)["peer_changes"]["changes"]
        if c["seq"] > seq_before and c["peer"] == "uav2"
    ]
    print(f"uav1 saw uav2: {seen}")

    shown = swarm.swarmctl("status", "--json")
    assert shown.returncode == 0, shown.stderr
    (tracked,) = [c for c in json.loads(shown.stdout)["commands"] if c["command_id"] == cid]
    row = tracked["nodes"]["uav2"]
    if state_kept:
        assert (row["state"], row["reason"], row["after_restart"]) == ("completed", landed, True)
        assert tracked["done"] is True
    else:
        assert (row["state"], row["reason"], row["after_restart"]) == (
            UNREACHABLE,
            NOT_REACHED,
            False,
        )

    # the daemons' own records: uav2's lives (one log, appended) re-reported cid once, or
    # never; uav1 recorded one answer for cid, the re-report (the earlier life's ACCEPTED and
    # COMPLETED never got through), or none
    rereports = [
        (e["commander"], e["command_ids"])
        for e in read_log(swarm.daemons.logs[MEMBER])
        if e.get("event") == "command_outcomes_rereported"
    ]
    answers = [
        (e["member"], e["result"], e["known"])
        for e in read_log(swarm.daemons.logs[COMMANDER])
        if e.get("event") == "command_outcome_received" and e["command_id"] == cid
    ]
    assert rereports == ([("uav1", [cid])] if state_kept else []), rereports
    assert answers == ([("uav2", "COMPLETED", True)] if state_kept else []), answers

    # never run twice: the vehicle armed once; the new life received no take-off and ran
    # nothing; with the state kept it still knows the executed id
    member_st = new_life()
    assert member_st["dataplane"]["outcomes_rereported"] == rereported, member_st["dataplane"]
    assert member_st["executor"]["counters"].get("received_takeoff", 0) == 0
    assert member_st["dataplane"]["executed_commands"] == (1 if state_kept else 0)
    assert swarm.armed(MEMBER) == 1


def test_swarmctl_takeoff_still_following_ends_with_the_re_report(
    lan_factory: LanFactory, workdir: Path
) -> None:
    """The operator's own ``swarmctl takeoff --valid-for 20`` is still following when uav2
    (its answers cut off, as above) restarts with its state and re-reports into the cut.
    When the rule goes, uav1 sees the new life (``restarted_before_acknowledging``) and,
    within ``UNREACHABLE_GRACE_S``, the re-report, which a repair has to carry: swarmctl
    ends ``completed``, ``after_restart``, exit 0. Before the row waited that grace (it
    was settled the moment uav1 saw the new epoch), swarmctl stopped there and said
    ``unreachable``."""
    swarm = Swarm(lan_factory(4), workdir)
    _ready_and_cut(swarm, user_data_only=False)
    sock = swarm.socks[COMMANDER]
    out = workdir / "takeoff.json"
    argv = ["takeoff", "--only", "uav2", "--alt", "5", "--valid-for", "20", "--json"]
    with out.open("wb") as sink:
        follow = swarm.lan[COMMANDER].popen(
            [str(BIN / "swarmctl"), *argv, "--socket", str(sock)], stdout=sink
        )
    until(lambda: len(swarm.status(COMMANDER)["commands"]) == 1, lambda: follow.poll())
    cid = swarm.status(COMMANDER)["commands"][0]["command_id"]
    landed = _completed(swarm, cid)
    assert _row(swarm, cid)["state"] == "pending"  # nothing got through the cut
    _kill(swarm, state_kept=True)
    swarm.daemons.start(MEMBER)

    # the new life re-reports into the cut, and its unanswered heartbeats back off to
    # MAX_HEARTBEAT_PERIOD_S (0.2 s x 1.5 per heartbeat: the 6th); uav1 sees that life when
    # the rule goes, and the re-report up to a heartbeat period later
    def backed_off() -> bool:
        st = swarm.status(MEMBER)["dataplane"]
        return bool(
            st["outcomes_rereported"] == 1
            and st["writers"][TOPIC_OUTCOME]["heartbeats_sent"] >= HEARTBEATS_TO_MAX_PERIOD
        )

    until(backed_off, lambda: swarm.status(MEMBER)["dataplane"])
    assert heal([swarm.lan[COMMANDER]]) > 0

    assert follow.wait(timeout=60) == 0, out.read_text()
    body = json.loads(out.read_text())
    row = body["nodes"]["uav2"]
    assert (row["state"], row["reason"], row["after_restart"]) == ("completed", landed, True)
    assert body["valid_left_s"] > 0  # it ended on the answer, not at the validity's end
    assert swarm.armed(MEMBER) == 1
    assert swarm.status(MEMBER)["executor"]["counters"].get("received_takeoff", 0) == 0
