"""Exactly once across a lost state file, with real daemons on the host loopback
(docs/dataplane.md, "A life runs only its own commands").

Two daemons in one process (``tests.test_takeoff_loopback``'s ``Swarm``: real sockets,
real RTPS, each with a vehicle simulator on its own MAVLink port): uav1 commands, uav2
takes a HOLD (not a TAKEOFF: resent to a vehicle already airborne, a TAKEOFF is also
refused by the member's readiness gate, which would hide the defect this test is about;
a HOLD has no such gate and ran a second time before the defence). uav2's daemon stops,
its state file is deleted (a lost or corrupt file is replaced the same way,
``statefile.load``), and it starts again (its vehicle keeps flying); the commander sees
its new boot epoch. The commander's data plane then sends
the same command id again (no ``swarmctl`` path does: this is the plane's
``send_command``, called in the commander's process), with a fresh echo its caller made;
the plane sends it with the first send's dating.

Asserted: uav2's new life refuses it (REJECTED ``memory_lost``, its executor counter
``refused_memory_lost``), never accepts it (its vehicle is not told again), and the
commander's row keeps what the first life said.

The same with a state dir made unwritable (``chattr +i``: root writes through a mode, not
through the immutable flag) once uav2 has booted, so every write of the HOLD's record
fails, and writable again for the restart (docs/dataplane.md, "A failed save"): the HOLD
runs, and the operator is told: ``state_save_failed`` names the command, the status counts
it, ``swarmctl outcomes`` on uav2 marks its decision unsaved, and uav1's row for it says
``save_failed`` (uav2 flagged its outcome ``OUTCOME_NOT_SAVED``; with the file deleted
instead, the row is not marked). While the dir stays
unwritable uav2 does not start again (exit 73); once writable, the restart boots on a file
without the HOLD, and the resend is refused as above.
Waits have caps; nothing asserts how fast anything happened.
"""

from __future__ import annotations

import contextlib
import shutil
import subprocess
from collections.abc import Iterator, MutableMapping
from pathlib import Path
from typing import Any

import pytest
from structlog.testing import capture_logs
from swarmd_lab.px4.vehicle_sim import start_sim

from swarmd import statefile
from swarmd.dataplane.types import Command, CommandKind
from swarmd.exitcodes import EX_CANTCREAT, StartupError
from swarmd.px4.transport import parse_connection
from swarmd.rawclock import run_on_raw_clock
from swarmd.statefile import state_path
from tests.daemon_support import run_domain, write_bundle
from tests.test_takeoff_loopback import Swarm, _mavlink_port, _sim, until


async def start_pair(swarm: Swarm) -> None:
    """uav1 (the commander) and uav2, each with its vehicle simulator."""
    for i in range(2):
        d = swarm.daemon(i)
        await d.start()
        swarm.daemons.append(d)
    for i in range(2):
        endpoint = parse_connection(f"udpout:127.0.0.1:{_mavlink_port(i)}")
        swarm.sims.append(await start_sim(_sim(i + 1), endpoint, seed=i))


def _executor(swarm: Swarm, i: int) -> dict[str, int]:
    app = swarm.daemons[i].app
    assert app is not None
    counters: dict[str, int] = app.status()["executor"]["counters"]
    return counters


def _chattr(flag: str, path: Path) -> bool:
    done = subprocess.run(["chattr", flag, str(path)], capture_output=True, check=False)
    return done.returncode == 0


@contextlib.contextmanager
def _immutable(directory: Path) -> Iterator[None]:
    """``directory`` refuses every new file and rename while inside, for root too."""
    assert _chattr("+i", directory)
    try:
        yield
    finally:
        _chattr("-i", directory)


def _can_make_immutable(workdir: Path) -> bool:
    probe = workdir / "probe"
    probe.mkdir()
    try:
        return shutil.which("chattr") is not None and _chattr("+i", probe)
    finally:
        _chattr("-i", probe)
        probe.rmdir()


@pytest.mark.parametrize("memory", ["deleted", "save_failed"])
def test_a_member_restarted_without_its_state_file_refuses_a_resent_id(
    workdir: Path, memory: str
) -> None:
    if memory == "save_failed" and not _can_make_immutable(workdir):
        pytest.skip("needs chattr +i (root, a file system with the immutable flag)")
    files = write_bundle(workdir, 2, domain_id=run_domain(), lease_s=20.0)
    swarm = Swarm(workdir, files)
    state_dir = workdir / "state"
    unwritable = _immutable(state_dir) if memory == "save_failed" else contextlib.nullcontext()

    async def main() -> None:
        await start_pair(swarm)
        try:
            app = swarm.commander.app
            assert app is not None
            await until(lambda: bool(swarm.table()["uav2"]["ready"]), swarm.table)
            with unwritable:
                sent = app.request_command({"kind": "hold", "only": ["uav2"], "valid_for_s": 60.0})
                cid = int(sent["command_id"])
                await until(
                    lambda: (
                        app.request_outcomes({"command_id": cid})["nodes"]["uav2"]["state"]
                        in ("accepted", "completed")
                    ),
                    lambda: app.request_outcomes({"command_id": cid}),
                )
                assert _executor(swarm, 1).get("outcome_accepted") == 1
                if memory == "save_failed":
                    # the commander's operator is told too: uav2 flags its outcome
                    await until(lambda: _row(app, cid)["save_failed"], lambda: _row(app, cid))
                    _told_the_save_failed(swarm, cid, logs)
                else:
                    assert _row(app, cid)["save_failed"] is False
                plane = app.plane
                assert plane is not None
                epoch_before = plane.peer_epoch("uav2")

                # uav2's daemon restarts without its record; its vehicle keeps flying
                await swarm.daemons[1].stop("test")
                if memory == "save_failed":  # while it cannot write, it does not start
                    with pytest.raises(StartupError) as refused:
                        await swarm.daemon(1).start()
                    assert refused.value.exit_code == EX_CANTCREAT
            if memory == "deleted":
                state_path(state_dir, "uav2").unlink()
            else:  # what the failed writes would have kept is not there
                assert statefile.load(state_path(state_dir, "uav2")).executed == []
            reborn = swarm.daemon(1)
            await reborn.start()
            swarm.daemons[1] = reborn
            await until(
                lambda: (plane.peer_epoch("uav2") or 0) > (epoch_before or 0),
                lambda: (plane.peer_epoch("uav2"), swarm.table()["uav2"]),
            )

            assert app.driver is not None
            driver = app.driver
            # a report of the new life reached the commander: its caller can date it afresh
            # (without one, it would go undated and be refused ``expired`` before and after)
            await until(
                lambda: bool(driver.call(lambda now: plane.time_echoes(["uav2"], now))),
                lambda: swarm.table()["uav2"],
            )

            def resend(now: float) -> int:
                echoes = plane.time_echoes(["uav2"], now)
                return plane.send_command(
                    Command(cid, CommandKind.HOLD, 0.0, ["uav2"], 60_000, echoes), now
                )

            driver.call(resend)
            await until(
                lambda: _executor(swarm, 1).get("refused_memory_lost", 0) >= 1,
                lambda: _executor(swarm, 1),
            )
            counters = _executor(swarm, 1)
            assert counters.get("refused_memory_lost") == 1
            assert "outcome_accepted" not in counters, counters  # the new life ran nothing
            row: dict[str, Any] = app.request_outcomes({"command_id": cid})["nodes"]["uav2"]
            assert row["state"] in ("accepted", "completed"), row
        finally:
            await swarm.stop()

    with capture_logs() as logs:
        run_on_raw_clock(main())


def _row(app: Any, cid: int) -> dict[str, Any]:
    row: dict[str, Any] = app.request_outcomes({"command_id": cid})["nodes"]["uav2"]
    return row


def _told_the_save_failed(swarm: Swarm, cid: int, logs: list[MutableMapping[str, Any]]) -> None:
    """The operator learns of the failed save: the log line names the command, the status
    counts it, ``swarmctl outcomes`` on the drone marks the decision, and the commander
    logged the flagged outcome (``saved: false``)."""
    flagged = [
        e
        for e in logs
        if e["event"] == "command_outcome_received" and e.get("node") == "uav1"
        if e.get("command_id") == cid and e.get("saved") is False
    ]
    assert flagged, [e for e in logs if e["event"] == "command_outcome_received"]
    failed = [e for e in logs if e["event"] == "state_save_failed" and e.get("node") == "uav2"]
    assert any(e["command_id"] == cid and e["commander"] == "uav1" for e in failed), failed
    app = swarm.daemons[1].app
    assert app is not None
    assert app.status()["dataplane"]["state_save_errors"] >= 1
    (ran,) = app.request_outcomes({})["ran"]
    assert (ran["command_id"], ran["saved"]) == (cid, False), ran
