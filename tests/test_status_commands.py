"""Commands in ``swarmctl status`` and ``swarmctl watch`` (session 17, from the operator's
seat): a take-off in progress, the drones that have not answered, ``[not saved on
drone]``, and on a member the command it runs now.

The daemons are played: real swarm cores on the in-memory network and virtual time
(``tests/test_swarm_core.Swarm``), answering swarmctl's ``status`` request in-process as
``SwarmApp.status`` builds it (``_status``); swarmctl's ``watch`` sleeps move the network's
clock on, so nothing here waits or asserts how fast anything happened.
"""

from __future__ import annotations

import json
import sys
import time
from collections.abc import Callable
from types import SimpleNamespace
from typing import Any

import pytest

from swarmd.cli import status_cmd, swarmctl
from swarmd.cli.commands_view import COMMANDS_SHOWN, NAMES_SHOWN, CommandWatch, render_commands
from swarmd.cli.status_cmd import render_status
from swarmd.exitcodes import EX_OK
from swarmd.px4.vehicle import TaskFinished
from tests.test_swarm_core import Swarm

HOSTILE = "x\x1b[2J\u202eevil"
VALID_S = 3.0
WALL = 1_800_000_000.0  # this host's wall clock in the played runs


def _status(swarm: Swarm, name: str) -> dict[str, Any]:
    """What the daemon of ``name`` answers to ``status``: the swarm fragment as
    ``SwarmApp.status`` builds it, on the network's clock."""
    core, now = swarm.cores[name], swarm.net.now
    return {
        "node": name,
        "role": core.roles.role,
        "readiness": core.table.rows(now),
        "commands": core.tracker.recent(now) if core.roles.is_commander else [],
        "executor": core.executor_status(now),
    }


class PlayedDaemon:
    """swarmctl's ``ControlClient`` and ``time`` for one played daemon: ``status`` is
    answered from the swarm, ``sleep`` runs the swarm on."""

    def __init__(self, swarm: Swarm, name: str) -> None:
        self.swarm, self.name = swarm, name

    def client(self, _path: str, **_kw: Any) -> PlayedDaemon:
        return self

    def __enter__(self) -> PlayedDaemon:
        return self

    def __exit__(self, *exc: object) -> None:
        return None

    def close(self) -> None:
        return None

    def request(self, cmd: str, **_request: Any) -> Any:
        assert cmd == "status", cmd
        return _status(self.swarm, self.name)

    def sleep(self, seconds: float) -> None:
        self.swarm.run(seconds)


def _swarmctl(monkeypatch: pytest.MonkeyPatch, daemon: PlayedDaemon, argv: list[str]) -> int:
    monkeypatch.setattr(status_cmd, "ControlClient", daemon.client)
    played_time = SimpleNamespace(
        time=lambda: WALL, sleep=daemon.sleep, strftime=time.strftime, localtime=time.localtime
    )
    monkeypatch.setattr(status_cmd, "time", played_time)
    return swarmctl.main([*argv, "--socket", "/nonexistent"])


@pytest.fixture
def show(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> Callable[..., str]:
    """``show(swarm, name, *argv)``: ``swarmctl status ARGV`` on ``name``'s played daemon,
    its exit 0, then its stdout."""

    def run(swarm: Swarm, name: str, *argv: str) -> str:
        assert _swarmctl(monkeypatch, PlayedDaemon(swarm, name), ["status", *argv]) == EX_OK
        return capsys.readouterr().out

    return run


def _takeoff_in_progress() -> tuple[Swarm, int]:
    """A take-off to m01..m04 half a second in: m01 and m02 accepted (their vehicles
    climb for 1 s), m03 cut off (no answer), m04 refused at the send (not ready)."""
    swarm = Swarm(4)
    swarm.vehicles["m04"].verdict.ready = False
    swarm.vehicles["m04"].verdict.reason = "no_3d_fix"
    swarm.run(2.0)
    swarm.net.isolate(swarm.ids["m03"])
    sent = swarm.call("lead", lambda now: swarm.lead.request_takeoff({"valid_for_s": VALID_S}, now))
    swarm.run(0.5)
    return swarm, int(sent["command_id"])


def test_status_on_the_commander_shows_a_takeoff_in_progress_and_who_has_not_answered(
    show: Callable[..., str],
) -> None:
    """[fails on main: the human status had no commands part; only --json had them]"""
    swarm, cid = _takeoff_in_progress()
    out = show(swarm, "lead")
    assert f"TAKEOFF {cid:#x}" in out, out
    assert "accepted 2, pending 1, refused 1" in out, out
    assert "no answer yet: m03" in out and "refused: m04 (no_3d_fix)" in out, out
    assert "open: may still start for" in out, out

    swarm.run(VALID_S + 3.0)  # the validity and its grace are over
    out = show(swarm, "lead")
    assert "completed 2, unreachable 1, refused 1" in out, out
    assert "unreachable: m03 (not_reached_while_valid)" in out and ", done" in out, out


def test_status_on_a_member_names_the_command_it_runs_now(show: Callable[..., str]) -> None:
    """[fails on main: a member's status said nothing of the take-off its vehicle flew]"""
    swarm, cid = _takeoff_in_progress()
    out = show(swarm, "m01")
    assert f"running now: TAKEOFF {cid:#x} from lead" in out, out
    swarm.run(2.0)  # the vehicle reached the air: the task ended
    assert "running now: no command" in show(swarm, "m01")


def test_status_json_keeps_its_keys_and_adds_the_running_command(
    show: Callable[..., str],
) -> None:
    """``--json`` is the daemon's object unchanged: ``commands`` as before, ``executor``
    with ``running`` and ``counters`` as before and ``commands`` added."""
    swarm, cid = _takeoff_in_progress()
    lead = json.loads(show(swarm, "lead", "--json"))
    (command,) = lead["commands"]
    assert command["command_id"] == cid and set(command["nodes"]) == {"m01", "m02", "m03", "m04"}
    executor = json.loads(show(swarm, "m01", "--json"))["executor"]
    assert executor["running"] == 1 and executor["counters"]["received_takeoff"] == 1
    (task,) = executor["commands"]
    assert (task["command_id"], task["kind"], task["commander"], task["saved"]) == (
        cid, "takeoff", "lead", True)  # fmt: skip
    assert task["age_s"] == pytest.approx(0.5, abs=0.1)


def test_watch_prints_the_send_and_each_drones_verdict_once(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """``swarmctl watch`` piped, on the commander, while a take-off goes out: one line for
    the send and one per drone verdict, as the take-off follow says them, each once.
    [fails on main: watch printed peer changes only]"""
    swarm = Swarm(3)
    swarm.vehicles["m03"].answer = lambda r: TaskFinished(r.token, False, HOSTILE, None)
    swarm.run(2.0)
    daemon = PlayedDaemon(swarm, "lead")
    sent: dict[str, Any] = {}

    def sleep(seconds: float) -> None:
        if not sent:  # the operator takes off from another shell after the first frame
            sent.update(swarm.call("lead", lambda now: swarm.lead.request_takeoff({}, now)))
        swarm.run(seconds)

    daemon.sleep = sleep  # type: ignore[method-assign]
    assert _swarmctl(monkeypatch, daemon, ["watch", "--count", "6"]) == EX_OK
    lines = [ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("command: ")]
    cid = f"{sent['command_id']:#x}"
    events = [ln.split("  ", 1)[1] for ln in lines]
    assert events[0] == f"TAKEOFF command {cid} sent to 3 drone(s): m01, m02, m03; valid for " + (
        f"{sent['valid_for_s']:g} s"
    ), events
    said = [e.split(" after ")[0] for e in events[1:]]
    assert sorted(said) == sorted(
        [f"TAKEOFF {cid}: m0{i}: accepted" for i in (1, 2, 3)]
        + [f"TAKEOFF {cid}: m0{i}: completed (IN_AIR)" for i in (1, 2)]
        + [f"TAKEOFF {cid}: m03: failed (x\\x1b[2J\\u202eevil)"]
    ), events
    assert not any("\x1b" in ln or "\u202e" in ln for ln in lines)  # shown, never obeyed


def test_watch_on_a_terminal_keeps_the_command_lines_under_the_screen(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    swarm = Swarm(1)
    swarm.run(2.0)
    daemon = PlayedDaemon(swarm, "lead")
    sent: dict[str, Any] = {}

    def sleep(seconds: float) -> None:
        if not sent:
            sent.update(swarm.call("lead", lambda now: swarm.lead.request_command(
                {"kind": "land"}, now)))  # fmt: skip
        swarm.run(seconds)

    daemon.sleep = sleep  # type: ignore[method-assign]
    monkeypatch.setattr(sys.stdout, "isatty", lambda: True)
    assert _swarmctl(monkeypatch, daemon, ["watch", "--count", "4"]) == EX_OK
    last_frame = capsys.readouterr().out.split(status_cmd.CLEAR_SCREEN)[-1]
    under = last_frame.split("changes while watching:\n", 1)[1]
    assert f"LAND command {sent['command_id']:#x} sent to 1 drone(s): m01" in under, under
    assert "m01: completed" in under, under


def test_a_watch_started_mid_command_prints_only_what_changes_after(
) -> None:  # fmt: skip
    """The first frame primes: the screen already shows the command; its later verdicts
    are news."""
    swarm, cid = _takeoff_in_progress()
    watch = CommandWatch()
    assert watch.update(_status(swarm, "lead")) == []
    swarm.run(2.0)
    news = watch.update(_status(swarm, "lead"))
    assert sorted(e.split(" after ")[0] for e in news) == [
        f"TAKEOFF {cid:#x}: m01: completed (IN_AIR)", f"TAKEOFF {cid:#x}: m02: completed (IN_AIR)"
    ]  # fmt: skip
    assert watch.update(_status(swarm, "lead")) == []  # said once


def _played_command(i: int, names: list[str], state: str, **row: Any) -> dict[str, Any]:
    node = {"state": state, "reason": None, "latency_s": None, "done_s": None,
            "after_restart": False, "save_failed": False, **row}  # fmt: skip
    return {"command_id": 0x6B09A20700000000 + i, "kind": "land", "age_s": 10.0 - i,
            "valid_for_s": 5.0, "valid_left_s": 0.0, "done": False,
            "nodes": {n: dict(node) for n in names}}  # fmt: skip


def test_status_bounds_the_commands_and_names_it_shows() -> None:
    """Eight commands, the newest to thirty drones none of which answered, each marked
    ``[not saved on drone]``: a few commands and a few names, then "+N more" and where to
    find the rest (``swarmctl outcomes``)."""
    names = [f"uav{i:02d}" for i in range(30)]
    commands = [_played_command(i, names, "pending", save_failed=True) for i in range(8)]
    lines = render_commands({"role": "commander", "commands": commands})
    newest = f"{commands[-1]['command_id']:#x}"
    assert lines[1].strip().startswith(f"LAND {newest}"), lines
    assert sum(ln.strip().startswith("LAND 0x") for ln in lines) == COMMANDS_SHOWN
    assert f"  +{8 - COMMANDS_SHOWN} earlier: swarmctl outcomes" in lines
    more = f", +{30 - NAMES_SHOWN} more (swarmctl outcomes {newest})"
    assert f"    no answer yet: {', '.join(names[:NAMES_SHOWN])}{more}" in lines, lines
    assert f"    [not saved on drone]: {', '.join(names[:NAMES_SHOWN])}{more}" in lines, lines
    assert len(lines) < 20
    (none,) = render_commands({"role": "commander", "commands": []})
    assert none.startswith("commands sent: none since this daemon started"), none


def test_peer_strings_in_the_commands_part_are_shown_never_obeyed() -> None:
    """A drone name and a reason carrying ESC and U+202E (a captured member's words):
    visible escapes on the terminal. [fails on main: the part did not exist]"""
    command = _played_command(1, [HOSTILE], "rejected", reason=HOSTILE)
    status = {"role": "commander", "commands": [command],
              "executor": {"running": 1, "commands": [
                  {"command_id": 1, "kind": "land", "commander": HOSTILE, "age_s": 1.0,
                   "saved": False}]}}  # fmt: skip
    lines = render_status(status, WALL)
    shown = "x\\x1b[2J\\u202eevil"
    assert f"    rejected: {shown} ({shown})" in lines, lines
    assert f"running now: LAND 0x1 from {shown}, received 1.0 s ago [not saved]" in lines, lines
    assert not any("\x1b" in ln or "\u202e" in ln for ln in lines)


def test_watch_on_a_drone_prints_when_its_running_command_changes(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """``swarmctl watch`` piped, on a member, while the commander's LAND runs there (the
    played vehicle takes 1 s): a line when it starts running and one when it ends, each
    once; the redrawn ``running now:`` line alone said it before. [fails on main: no
    line]"""
    swarm = Swarm(1)
    swarm.run(2.0)
    daemon = PlayedDaemon(swarm, "m01")
    sent: dict[str, Any] = {}

    def sleep(seconds: float) -> None:
        if not sent:  # the operator lands from the commander after the first frame
            sent.update(swarm.call("lead", lambda now: swarm.lead.request_command(
                {"kind": "land"}, now)))  # fmt: skip
        swarm.run(seconds / 2)

    daemon.sleep = sleep  # type: ignore[method-assign]
    assert _swarmctl(monkeypatch, daemon, ["watch", "--count", "8"]) == EX_OK
    lines = [ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("command: ")]
    events = [ln.split("  ", 1)[1] for ln in lines]
    cid = f"{sent['command_id']:#x}"
    assert events == [
        f"running now: LAND {cid} from lead",
        f"no longer running: LAND {cid} from lead",
    ], events
