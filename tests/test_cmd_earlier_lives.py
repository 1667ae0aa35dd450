"""``swarmctl outcomes`` on a drone lists what its daemon's earlier lives decided
(docs/operations.md, "What became of each command"; docs/dataplane.md, "Outcomes across a
restart").

The state file kept each outcome's result and reason next to its id, but no kind and no
time, and the drone's view showed only the current life. The member's ``DecisionLog`` is
now kept in the state file too (key ``decisions``: life, commander, id, kind, state,
reason, when received in Unix seconds, how long the answer took; at most
``MAX_DECIDED_COMMANDS`` = 64 over all lives), restored at start-up and shown with the life
that decided each one. Old state files (without the key) load as before.
"""

from __future__ import annotations

import asyncio
import calendar
import json
import time
from pathlib import Path
from typing import Any

from structlog.testing import capture_logs

from swarmd import statefile
from swarmd.auth.epoch import epoch_path
from swarmd.cli.outcomes_cmd import render_kept, to_json
from swarmd.dataplane.types import CommandKind, CommandResult
from swarmd.exitcodes import EX_FAILED
from swarmd.rawclock import run_on_raw_clock
from swarmd.swarm.commander import MAX_DECIDED_COMMANDS, DecisionLog, KeptDecision
from tests.daemon_support import run_domain, write_bundle
from tests.test_cmd_in_flight import Flight, _issue, _reboot
from tests.test_cmd_memory_loopback import start_pair
from tests.test_outcomes_cmd import HOSTILE, WALL_NOW, _swarmctl, _unsafe
from tests.test_takeoff_loopback import Swarm, until

# ---- on virtual time ----------------------------------------------------------------------


def test_a_restarted_member_lists_its_earlier_lifes_decisions_with_kind_and_time() -> None:
    flight = Flight(1, seed=70)
    swarm = flight.swarm
    swarm.run(3.0)
    hold = int(_issue(swarm, CommandKind.HOLD)["command_id"])
    swarm.run(1.0)
    land = int(_issue(swarm, CommandKind.LAND)["command_id"])
    swarm.run(1.0)
    before = {r["command_id"]: r for r in swarm.cores["m01"].request_outcomes({}, 0.0)["ran"]}
    reborn = _reboot(flight, "m01", state_kept=True)
    swarm.run(1.0)
    takeoff = int(_issue(swarm, CommandKind.TAKEOFF)["command_id"])
    swarm.run(1.0)

    answer = reborn.request_outcomes({}, swarm.net.now)
    assert answer["life"] == 1  # the new life's boot counter (incarnation)
    ran = answer["ran"]
    assert [(r["command_id"], r["kind"], r["life"]) for r in ran] == [
        (takeoff, "takeoff", 1),
        (land, "land", 0),
        (hold, "hold", 0),
    ]
    for r in ran[1:]:  # as the earlier life decided them, and when (one clock here)
        was = before[r["command_id"]]
        assert (r["state"], r["reason"], r["done_s"]) == (
            was["state"],
            was["reason"],
            was["done_s"],
        )
        assert r["age_s"] == round(was["age_s"] + swarm.net.now, 3)
    # the human view marks the life; --json keeps it
    lines = render_kept({"issued": [], "ran": ran, "life": 1}, WALL_NOW)
    assert lines[-1].split()[:2] == [f"{hold:#x}", "HOLD"] and lines[-1].endswith("0 (earlier)")
    assert lines[-3].endswith("1 (this)")
    assert [r["life"] for r in to_json(answer, WALL_NOW, EX_FAILED)["ran"]] == [1, 0, 0]


def _kept(i: int, life: int = 3) -> KeptDecision:
    return KeptDecision(life, "lead", i, "hold", "completed", "", 1_750_000_000.0 + i, 0.5)


def test_the_kept_decisions_are_capped_over_all_lives() -> None:
    """64 restored; each decision of the new life pushes the oldest earlier one out."""
    log = DecisionLog(4, [_kept(i) for i in range(MAX_DECIDED_COMMANDS + 10)])
    assert len(log.kept()) == MAX_DECIDED_COMMANDS and log.evicted == 10
    log.decided("lead", 999, "LAND", CommandResult.ACCEPTED, "", 5.0)
    kept = log.kept()
    assert len(kept) == MAX_DECIDED_COMMANDS and kept[0].command_id == 11
    assert (kept[-1].life, kept[-1].command_id, kept[-1].kind) == (4, 999, "land")


def test_earlier_lives_strings_stay_data() -> None:
    """A hand-edited state file's strings (or a hostile commander's name) reach the view
    through the terminal sanitiser; ``--json`` keeps them exact."""
    ran = [
        {
            "command_id": 1,
            "kind": HOSTILE,
            "commander": HOSTILE,
            "state": "completed",
            "reason": HOSTILE,
            "age_s": 3.0,
            "life": 2,
            "saved": True,
        }
    ]
    shown = {"issued": [], "ran": ran, "life": 3}
    assert _unsafe("\n".join(render_kept(shown, WALL_NOW))) == []
    assert to_json(shown, WALL_NOW, EX_FAILED)["ran"][0]["reason"] == HOSTILE


def test_an_earlier_decision_time_past_the_calendar_leaves_the_view_whole(
    tmp_path: Path,
) -> None:
    """Review 14: a hand-edited state file's decision time is any finite number, and the
    view turned one past the C library's calendar into a wall-clock time: ``gmtime`` and
    ``localtime`` raised (OverflowError, EOVERFLOW) and ``swarmctl outcomes`` ended in a
    traceback, plain and ``--json``. Now that time is shown as unknown; the rest stays.
    (Since session 15 the state file's load drops such an entry and keeps its id,
    ``tests/test_statefile_decision_times.py``; the view stays whole for any age.)"""
    path = statefile.state_path(tmp_path, "m01")
    far = [1, "lead", 7, "hold", "completed", "", 1e300, None]
    path.write_text(json.dumps({"boot": 2, "executed": [], "decisions": [far]}), "utf-8")
    state = statefile.load(path)
    assert (state.decisions, state.executed) == ([], [("lead", 7)])  # dropped, id kept
    age_s = WALL_NOW - 1e300
    ran = [{"command_id": 7, "kind": "hold", "commander": "lead", "state": "completed",
            "reason": "", "age_s": age_s, "life": 1, "saved": True}]  # fmt: skip
    shown = {"issued": [], "ran": ran, "life": 2}
    text = "\n".join(render_kept(shown, WALL_NOW))
    assert "0x7" in text and "--:--:--" in text
    assert to_json(shown, WALL_NOW, EX_FAILED)["ran"][0]["received_at"] is None


# ---- the state file ----------------------------------------------------------------------


def test_an_old_state_file_without_decisions_still_loads(tmp_path: Path) -> None:
    path = statefile.state_path(tmp_path, "m01")
    path.write_text(
        '{"boot":4,"executed":[["lead",7]],"outcomes":[["lead",7,3,"IN_AIR"]]}', "utf-8"
    )
    state = statefile.load(path)
    assert (state.boot, state.executed, state.outcomes) == (
        4,
        [("lead", 7)],
        [("lead", 7, 3, "IN_AIR")],
    )
    assert state.decisions == [] and state.recovered_from is None
    booted = statefile.boot(tmp_path, "m01")
    assert (booted.boot, booted.decisions) == (5, [])
    assert "decisions" not in json.loads(path.read_text("utf-8"))  # none kept: as before


def test_decisions_round_trip_and_a_bad_list_is_dropped_alone(tmp_path: Path) -> None:
    path = statefile.state_path(tmp_path, "m01")
    kept = [_kept(i) for i in range(MAX_DECIDED_COMMANDS + 3)]
    statefile.NodeState(path, 2, [("lead", 7)], [("lead", 7, 3, "")], kept).save()
    assert statefile.load(path).decisions == kept[-MAX_DECIDED_COMMANDS:]
    body = json.loads(path.read_text("utf-8"))
    for bad in (
        [[1, "lead", 7, "hold", "sideways", "", 1.0, None]],  # no such state
        [[1, "lead", 7, "hold", "completed", "", "noon", None]],  # a time not a number
        [[1, "lead", -7, "hold", "completed", "", 1.0, None]],
        [[1, "lead", 7, "hold", "completed", "x" * 200, 1.0, None]],
        "not a list",
    ):
        body["decisions"] = bad
        path.write_text(json.dumps(body), "utf-8")
        state = statefile.load(path)
        assert (state.executed, state.outcomes, state.decisions) == (
            [("lead", 7)],
            [("lead", 7, 3, "")],
            [],
        ), bad
        assert state.recovered_from is not None and "decisions dropped" in state.recovered_from


# ---- a real daemon --------------------------------------------------------------------------


def test_a_real_member_shows_its_earlier_lifes_decision_after_a_restart(workdir: Path) -> None:
    """uav2 takes a HOLD, its daemon restarts (state file kept), and ``swarmctl outcomes``
    on uav2 lists the HOLD, as the earlier life decided it, with its kind, the wall-clock
    time it was received and its life. A temporary file left beside the state file is
    removed at the restart, counted in a log line, and so is one beside the boot epoch's
    file."""
    files = write_bundle(workdir, 2, domain_id=run_domain(), lease_s=20.0)
    swarm = Swarm(workdir, files)
    sock = str(workdir / "uav2.sock")

    async def main() -> tuple[int, float, Any, Any]:
        await start_pair(swarm)
        try:
            app = swarm.commander.app
            assert app is not None
            await until(lambda: bool(swarm.table()["uav2"]["ready"]), swarm.table)
            issued_at = time.time()
            sent = app.request_command({"kind": "hold", "only": ["uav2"], "valid_for_s": 60.0})
            cid = int(sent["command_id"])
            await until(
                lambda: (
                    app.request_outcomes({"command_id": cid})["nodes"]["uav2"]["state"]
                    == "completed"
                ),
                lambda: app.request_outcomes({"command_id": cid}),
            )
            await swarm.daemons[1].stop("test")
            # as a kill -9 inside the atomic write leaves it (tests/test_cmd_state_kill.py)
            path = statefile.state_path(workdir / "state", "uav2")
            path.with_name(f".{path.name}.tmp-{'ab' * 8}").write_bytes(b'{"boot"')
            epoch = epoch_path(swarm.daemons[1].config.bundle.node_state_dir, "uav2")
            epoch.with_name(f".{epoch.name}.tmp-{'cd' * 8}").write_bytes(b"17")
            reborn = swarm.daemon(1)
            await reborn.start()
            swarm.daemons[1] = reborn
            as_json = await asyncio.to_thread(_swarmctl, "outcomes", "--json", "--socket", sock)
            human = await asyncio.to_thread(_swarmctl, "outcomes", "--socket", sock)
            return cid, issued_at, as_json, human
        finally:
            await swarm.stop()

    with capture_logs() as logs:
        cid, issued_at, as_json, human = run_on_raw_clock(main())
    removed = [e for e in logs if e["event"] == "state_temp_files_removed"]
    # one line for the data plane's state file, one for the epoch's folder
    assert [(e["node"], e["count"]) for e in removed] == [("uav2", 1), ("uav2", 1)]
    assert list(workdir.rglob(".*.tmp-*")) == []
    body = json.loads(as_json.stdout)
    (ran,) = body["ran"]
    assert (ran["command_id"], ran["kind"], ran["state"], ran["commander"]) == (
        cid,
        "hold",
        "completed",
        "uav1",
    )
    assert ran["life"] == body["life"] - 1 and ran["saved"]
    # received when it was issued, on the wall clock (a loose bound: a clock check, not a
    # speed one)
    received = calendar.timegm(time.strptime(ran["received_at"], "%Y-%m-%dT%H:%M:%SZ"))
    assert abs(received - issued_at) < 60, (ran, issued_at)
    row = next(ln for ln in human.stdout.splitlines() if ln.split()[:1] == [f"{cid:#x}"])
    assert row.split()[1:4] == ["HOLD", "uav1", "COMPLETED"], human.stdout
    assert row.rstrip().endswith("(earlier)"), human.stdout
