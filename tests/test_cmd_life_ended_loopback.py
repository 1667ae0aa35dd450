"""The commander's view of a member's decision across a restart and a failed save, with
real daemons on the host loopback (session 15; docs/dataplane.md, "A failed save" and
"Outcomes across a restart").

Two daemons in one process (``tests.test_takeoff_loopback``'s ``Swarm``: real sockets,
real RTPS, each with a vehicle simulator on its own MAVLink port); uav1 commands.

- *An accepted row whose member restarted with nothing to re-report*: uav2 accepts a
  TAKEOFF (its simulator spools up for 6 s, so the task is still running), its daemon
  stops, its state file is deleted, and it starts again (the vehicle keeps flying). uav1
  sees the new boot epoch: the row says ``accepted``, ``restarted_before_finishing`` and
  is settled (``done``), where it stayed ``accepted`` and unsettled before.
- *A failed save, then a write that holds it*: uav2's state dir is immutable (``chattr
  +i``) while it takes a HOLD, so uav1's row says ``save_failed``; the dir is writable
  again and uav1 sends another HOLD, whose write holds the whole record: uav2 tells uav1
  (``OUTCOME_NOW_SAVED``) and the first row's mark goes.
- *The same clear, lost to a restart* (session 16): as above, but uav2's daemon never
  sends the clear (its plane drops it, as a daemon that dies between the write and the
  send) and restarts: the new life, whose file holds the HOLD's final answer and that
  uav1 was told it was unsaved, re-reports it flagged saved and the mark goes.

Waits have caps; nothing asserts how fast anything happened.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
from structlog.testing import capture_logs
from swarmd_lab.px4.vehicle_sim import start_sim

from swarmd.dataplane.types import OUTCOME_NOW_SAVED
from swarmd.px4.transport import parse_connection
from swarmd.rawclock import run_on_raw_clock
from swarmd.statefile import state_path
from swarmd.swarm.commander import RESTARTED_RUNNING
from tests.daemon_support import run_domain, write_bundle
from tests.test_cmd_memory_loopback import _can_make_immutable, _executor, _immutable
from tests.test_takeoff_loopback import Swarm, _mavlink_port, _sim, until


async def _start(swarm: Swarm, spool_up_s: float = 1.0) -> None:
    """uav1 (the commander) and uav2, each with its vehicle simulator; uav2's motors take
    ``spool_up_s`` to spin up before it climbs (its take-off task runs that long)."""
    for i in range(2):
        d = swarm.daemon(i)
        await d.start()
        swarm.daemons.append(d)
    for i, sim in enumerate((_sim(1), _sim(2, spool_up_s=spool_up_s))):
        endpoint = parse_connection(f"udpout:127.0.0.1:{_mavlink_port(i)}")
        swarm.sims.append(await start_sim(sim, endpoint, seed=i))


def _snap(app: Any, cid: int) -> dict[str, Any]:
    snap: dict[str, Any] = app.request_outcomes({"command_id": cid})
    return snap


def test_an_accepted_row_ends_when_its_member_restarts_without_its_record(
    workdir: Path,
) -> None:
    files = write_bundle(workdir, 2, domain_id=run_domain(), lease_s=20.0)
    swarm = Swarm(workdir, files)

    async def main() -> None:
        await _start(swarm, spool_up_s=6.0)
        try:
            app = swarm.commander.app
            assert app is not None
            await until(lambda: bool(swarm.table()["uav2"]["ready"]), swarm.table)
            sent = app.request_takeoff({"only": ["uav2"], "alt_m": 5.0, "valid_for_s": 30.0})
            cid = int(sent["command_id"])
            await until(
                lambda: _snap(app, cid)["nodes"]["uav2"]["state"] != "pending",
                lambda: _snap(app, cid),
            )
            row = _snap(app, cid)["nodes"]["uav2"]
            assert (row["state"], _snap(app, cid)["done"]) == ("accepted", False), row
            plane = app.plane
            assert plane is not None
            epoch_before = plane.peer_epoch("uav2") or 0

            await swarm.daemons[1].stop("test")  # mid-task: the vehicle keeps spooling
            state_path(workdir / "state", "uav2").unlink()
            reborn = swarm.daemon(1)
            await reborn.start()
            swarm.daemons[1] = reborn
            await until(
                lambda: (plane.peer_epoch("uav2") or 0) > epoch_before,
                lambda: (plane.peer_epoch("uav2"), swarm.table()["uav2"]),
            )
            await until(lambda: bool(_snap(app, cid)["done"]), lambda: _snap(app, cid))
            row = _snap(app, cid)["nodes"]["uav2"]
            assert (row["state"], row["reason"], row["after_restart"]) == (
                "accepted",
                RESTARTED_RUNNING,
                False,
            ), row
            counters = _executor(swarm, 1)
            assert "outcome_accepted" not in counters, counters  # the new life ran nothing
        finally:
            await swarm.stop()

    with capture_logs() as logs:
        run_on_raw_clock(main())
    ended = [e for e in logs if e["event"] == "command_member_restarted"]
    assert [(e["member"], e["reason"]) for e in ended] == [("uav2", RESTARTED_RUNNING)], ended


async def _marked_hold(swarm: Swarm, workdir: Path, *, done: bool) -> tuple[Any, int]:
    """uav1 sends uav2 a HOLD while uav2's state dir is immutable, and waits until its row
    says ``save_failed`` (and, ``done``, ``completed``): uav1's app and the HOLD's id."""
    app = swarm.commander.app
    assert app is not None
    await until(lambda: bool(swarm.table()["uav2"]["ready"]), swarm.table)
    with _immutable(workdir / "state"):
        sent = app.request_command({"kind": "hold", "only": ["uav2"]})
        cid = int(sent["command_id"])

        def marked() -> bool:
            row = _snap(app, cid)["nodes"]["uav2"]
            return bool(row["save_failed"]) and (not done or row["state"] == "completed")

        await until(marked, lambda: _snap(app, cid))
    return app, cid


def test_a_failed_save_then_a_write_that_holds_it_clears_the_commanders_mark(
    workdir: Path,
) -> None:
    if not _can_make_immutable(workdir):
        pytest.skip("needs chattr +i (root, a file system with the immutable flag)")
    files = write_bundle(workdir, 2, domain_id=run_domain(), lease_s=20.0)
    swarm = Swarm(workdir, files)
    ids: dict[str, int] = {}

    async def main() -> None:
        await _start(swarm)
        try:
            app, cid = await _marked_hold(swarm, workdir, done=False)
            ids["first"] = cid
            again = app.request_command({"kind": "hold", "only": ["uav2"]})
            second = int(again["command_id"])
            await until(
                lambda: not _snap(app, cid)["nodes"]["uav2"]["save_failed"],
                lambda: (_snap(app, cid), _executor(swarm, 1)),
            )
            assert _snap(app, second)["nodes"]["uav2"]["save_failed"] is False
            assert _executor(swarm, 1).get("told_saved") == 1
            member = swarm.daemons[1].app
            assert member is not None
            ran = {r["command_id"]: r["saved"] for r in member.request_outcomes({})["ran"]}
            assert ran[cid] is True
        finally:
            await swarm.stop()

    with capture_logs() as logs:
        run_on_raw_clock(main())
    heard = [
        e["saved"]
        for e in logs
        if e["event"] == "command_outcome_received" and e.get("command_id") == ids["first"]
    ]
    assert False in heard and heard[-1] is True, heard


def test_a_clear_lost_to_a_restart_is_sent_by_the_next_life(
    workdir: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    if not _can_make_immutable(workdir):
        pytest.skip("needs chattr +i (root, a file system with the immutable flag)")
    files = write_bundle(workdir, 2, domain_id=run_domain(), lease_s=20.0)
    swarm = Swarm(workdir, files)

    async def main() -> None:
        await _start(swarm)
        try:
            app, cid = await _marked_hold(swarm, workdir, done=True)
            member = swarm.daemons[1].app
            assert member is not None and member.plane is not None
            plane = member.plane
            sends = plane.report_outcome
            dropped: list[int] = []

            def without_clears(command_id: int, *args: Any, **kwargs: Any) -> int:
                if kwargs.get("flags", 0) & OUTCOME_NOW_SAVED:
                    dropped.append(command_id)  # the daemon died before it went out
                    return 0
                return sends(command_id, *args, **kwargs)

            monkeypatch.setattr(plane, "report_outcome", without_clears)
            app.request_command({"kind": "hold", "only": ["uav2"]})  # its write holds cid
            await until(lambda: dropped == [cid], lambda: (dropped, _executor(swarm, 1)))
            assert _snap(app, cid)["nodes"]["uav2"]["save_failed"] is True
            await swarm.daemons[1].stop("test")
            reborn = swarm.daemon(1)
            await reborn.start()
            swarm.daemons[1] = reborn
            await until(
                lambda: not _snap(app, cid)["nodes"]["uav2"]["save_failed"],
                lambda: (_snap(app, cid), _executor(swarm, 1)),
            )
            assert _executor(swarm, 1).get("told_saved") == 1
            assert _snap(app, cid)["nodes"]["uav2"]["state"] == "completed"
        finally:
            await swarm.stop()

    run_on_raw_clock(main())
