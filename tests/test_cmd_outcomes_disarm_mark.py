"""The drone itself says its failed take-off's DISARM was never confirmed (session 18).

Earlier today the commander learned it (the row ``[disarm not confirmed]`` in ``takeoff``,
``watch``, ``status``; the mark kept across the drone's restart). Two places on the drone
still read as if nothing were wrong:

- ``swarmctl outcomes`` on the drone (its ``ran`` list, ``DecisionLog.recent``) said a
  plain ``failed``: an operator SSH'd into the drone that may be armed was not told. Now
  the row carries ``disarm_unconfirmed`` (``--json``) and ``[disarm not confirmed]``
  (text), this life's mark and one kept from an earlier life alike.
- ``px4_takeoff_disarm`` with ``ended: disarm_unconfirmed`` was an info line, so
  ``journalctl -p warning`` did not show it. Now it is a warning; a confirmed or stopped
  end stays info.

The swarm on ``MemNet`` (virtual time), m01 flying the simulated PX4 whose link loses
every NAV_TAKEOFF and, in the attack, every DISARM (``tests.test_cmd_disarm_unconfirmed``);
the restart through a real state file (``tests.test_cmd_disarm_save``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import structlog
from structlog.testing import capture_logs

from swarmd.cli.outcomes_cmd import render_kept, select, to_json
from swarmd.dataplane.types import CommandResult
from swarmd.px4.bridge import Px4Bridge, Px4Config
from swarmd.px4.takeoff import DisarmRepeatsEnded
from swarmd.swarm.commander import DecisionLog, KeptDecision
from swarmd.swarm.core import SwarmCore
from tests.test_cmd_disarm_save import _amendment_lost, _restarted
from tests.test_cmd_disarm_unconfirmed import _failed_takeoff

WALL_NOW = 1_800_000_000.0  # the host clock the views are rendered on
MARK = "[disarm not confirmed]"  # the mark the commander's rows carry too


def _ran(core: SwarmCore, now: float, cid: int) -> tuple[dict[str, Any], list[str], Any]:
    """What ``swarmctl outcomes`` on the drone gets for ``cid``: the ``ran`` entry, the
    text view's line for it, and the ``--json`` entry."""
    answer = core.request_outcomes({}, now)
    shown = select(answer, cid)
    assert shown is not None and len(shown["ran"]) == 1, answer
    (row,) = shown["ran"]
    lines = [ln for ln in render_kept(shown, WALL_NOW) if f"{cid:#x}" in ln]
    (as_json,) = to_json(shown, WALL_NOW, 1)["ran"]
    return row, lines, as_json


def test_the_drones_own_outcomes_mark_an_unconfirmed_disarm() -> None:
    """Every DISARM lost: m01 sits armed after ``takeoff_no_ack``; its own ``swarmctl
    outcomes`` says so. [main: ``failed`` alone, no ``disarm_unconfirmed`` key]"""
    swarm, cid, _ = _failed_takeoff(disarms_lost=True)
    assert swarm.bench.sim.armed  # honest: the vehicle is armed
    row, lines, as_json = _ran(swarm.cores["m01"], swarm.net.now, cid)
    assert (row["state"], row["reason"], row.get("disarm_unconfirmed")) == (
        "failed",
        "takeoff_no_ack",
        True,
    )
    assert as_json["disarm_unconfirmed"] is True
    assert len(lines) == 1 and MARK in lines[0]


def test_a_confirmed_disarm_leaves_the_drones_row_plain() -> None:
    """The control: the DISARM arrives, the vehicle disarms: the row is ``failed``, no mark."""
    swarm, cid, _ = _failed_takeoff(disarms_lost=False)
    assert not swarm.bench.sim.armed
    row, lines, as_json = _ran(swarm.cores["m01"], swarm.net.now, cid)
    assert (row["state"], row["disarm_unconfirmed"], as_json["disarm_unconfirmed"]) == (
        "failed",
        False,
        False,
    )
    assert len(lines) == 1 and "disarm" not in lines[0]


def test_the_drones_row_keeps_the_mark_after_its_daemon_restarts(tmp_path: Path) -> None:
    """The amendment went into a cut, m01's daemon restarted from its state file: the
    earlier life's row in the new life's ``swarmctl outcomes`` still carries the mark.
    [main: ``failed`` alone]"""
    flight, cid = _amendment_lost(185)
    _restarted(flight, tmp_path, epoch=2)
    swarm = flight.swarm
    row, lines, _ = _ran(swarm.cores["m01"], swarm.net.now, cid)
    assert (row["state"], row["life"], row["disarm_unconfirmed"]) == ("failed", 0, True)
    assert len(lines) == 1 and MARK in lines[0] and "(earlier)" in lines[0]


def test_a_mark_shows_on_the_failure_it_names_alone() -> None:
    """``DecisionLog.recent``: a mark names a failed take-off. The same id decided again
    by a later life (the plane's dedup evicted it; refused ``memory_lost``) is another
    decision, and a row not failed is never marked."""
    earlier = (
        KeptDecision(0, "lead", 5, "takeoff", "failed", "takeoff_no_ack", 1.0, 2.0),
        KeptDecision(0, "lead", 6, "land", "completed", "ON_GROUND", 1.0, 2.0),
    )
    marks = {("lead", 5), ("lead", 6)}  # 6 is not a failure: a hand-edited file's word
    log = DecisionLog(1, earlier)
    assert [(r["command_id"], r["disarm_unconfirmed"]) for r in log.recent(3.0, marks)] == [
        (6, False),
        (5, True),
    ]
    assert [r["disarm_unconfirmed"] for r in log.recent(3.0)] == [False, False]
    log.decided("lead", 5, "TAKEOFF", CommandResult.REJECTED, "memory_lost", 4.0)
    assert [(r["command_id"], r["disarm_unconfirmed"]) for r in log.recent(5.0, marks)] == [
        (5, False),
        (6, False),
    ]


def test_an_unconfirmed_disarm_is_logged_as_a_warning() -> None:
    """``px4_takeoff_disarm``: a warning when the repeats ended unconfirmed (the vehicle may
    be armed: ``journalctl -p warning`` shows it), info when confirmed or stopped.
    [main: info for all three]"""
    bridge = Px4Bridge.from_config(
        Px4Config(connection="udpin:127.0.0.1:0", sysid=1), log=structlog.get_logger()
    )
    ends = (
        DisarmRepeatsEnded(confirmed=False, stopped=False, why="DISARM no ack after 4 sends"),
        DisarmRepeatsEnded(confirmed=True, stopped=False, why="DISARM accepted"),
        DisarmRepeatsEnded(confirmed=False, stopped=True, why="stopped: abort"),
    )
    with capture_logs() as logs:
        for end in ends:
            bridge._on_event(end)  # noqa: SLF001 - the driver's callback, without a loop
    assert [(e["event"], e["log_level"], e["ended"]) for e in logs] == [
        ("px4_takeoff_disarm", "warning", "disarm_unconfirmed"),
        ("px4_takeoff_disarm", "info", "confirmed"),
        ("px4_takeoff_disarm", "info", "stopped"),
    ]
