"""``swarmctl outcomes``: what became of each command, after the fact (docs/operations.md,
"What became of each command").

Unit tests drive the parser, the member's ``DecisionLog`` and the rendering on hand-made
answers; one test runs a real ``swarmctl`` against a control socket that answers with
hostile names (issue 10, attack 8); one runs three in-process daemons' worth of the swarm
(two of them started) on loopback, issues a command, and reads its outcomes back with the
real ``swarmctl``. Waiting for a state with a generous cap is not a timing assertion.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import subprocess
import sys
import unicodedata
from pathlib import Path
from typing import Any

import pytest

from swarmd.cli import takeoff_cmd
from swarmd.cli.outcomes_cmd import exit_code, render_kept, select, to_json
from swarmd.cli.swarmctl import build_parser
from swarmd.control import ControlClient, ControlServer
from swarmd.dataplane.types import CommandResult
from swarmd.exitcodes import EX_FAILED, EX_OK, EX_UNREACHABLE
from swarmd.rawclock import run_on_raw_clock
from swarmd.swarm.commander import MAX_DECIDED_COMMANDS, DecisionLog
from swarmd.terminal import UNSAFE_CATEGORIES
from tests.daemon_support import (
    loopback_daemon,
    run_domain,
    swarm_sections,
    write_bundle,
)
from tests.test_cmd_validity import _Outcomes

SWARMCTL = str(Path(sys.executable).parent / "swarmctl")
HOSTILE = "uav9\x1b[2J\x1b]0;owned\x07\x9b31m\u202eydaer"
WALL_NOW = 1_750_000_000.0  # a fixed wall clock: the rendering is a pure function of it


def _unsafe(text: str) -> list[str]:
    return [c for c in text if unicodedata.category(c) in UNSAFE_CATEGORIES and c != "\n"]


def _node(state: str, reason: str = "", latency: float | None = None) -> dict[str, Any]:
    return {
        "state": state,
        "reason": reason,
        "latency_s": latency,
        "done_s": None if latency is None else latency + 0.5,
        "after_restart": False,
    }


def _issued(cid: int, nodes: dict[str, Any], **kw: Any) -> dict[str, Any]:
    return {
        "command_id": cid,
        "kind": kw.get("kind", "land"),
        "altitude_m": None,
        "targets": list(nodes),
        "age_s": kw.get("age_s", 60.0),
        "valid_for_s": 10.0,
        "valid_left_s": 0.0,
        "done": kw.get("done", True),
        "sent_by": kw.get("sent_by", {"uid": 1001, "user": "ops", "pid": 4242}),
        "nodes": nodes,
    }


ALL_DONE = _issued(0x11, {"uav2": _node("completed", "NAV_LAND", 0.01)})
ONE_MISSED = _issued(
    0x12,
    {
        "uav2": _node("completed", "NAV_LAND", 0.01),
        "uav3": _node("unreachable", "not_reached_while_valid"),
        "uav4": _node("rejected", "expired", 0.02),
    },
    kind="takeoff",
)


# ---- the parser ---------------------------------------------------------------------------


def test_parser_takes_an_optional_id_in_hex_or_decimal_and_the_common_options() -> None:
    parser = build_parser()
    args = parser.parse_args(["outcomes"])
    assert args.command_id is None and not args.json
    args = parser.parse_args(["outcomes", "0x6b09757000000002", "--json", "--socket", "/s"])
    assert args.command_id == 0x6B09757000000002 and args.json and args.socket == "/s"
    assert parser.parse_args(["outcomes", "18"]).command_id == 18


@pytest.mark.parametrize("bad", ["zz", "-1", "0xg"])
def test_parser_refuses_what_is_not_a_command_id(bad: str) -> None:
    with pytest.raises(SystemExit) as caught:
        build_parser().parse_args(["outcomes", bad])
    assert caught.value.code == 2


# ---- the member's record ------------------------------------------------------------------


def test_a_members_decision_log_keeps_the_final_answer_newest_first() -> None:
    log = DecisionLog()
    log.decided("uav1", 7, "TAKEOFF", CommandResult.ACCEPTED, "", 10.0)
    log.decided("uav1", 8, "LAND", CommandResult.REJECTED, "expired", 11.0)
    log.decided("uav1", 7, "TAKEOFF", CommandResult.COMPLETED, "IN_AIR", 12.5)
    # a final answer stays as it was reported: a later report for the id changes nothing
    log.decided("uav1", 8, "LAND", CommandResult.COMPLETED, "", 13.0)
    rows = log.recent(20.0)
    assert [(r["command_id"], r["kind"], r["state"], r["reason"]) for r in rows] == [
        (8, "land", "rejected", "expired"),
        (7, "takeoff", "completed", "IN_AIR"),
    ]
    assert rows[1]["age_s"] == 10.0 and rows[1]["done_s"] == 2.5 and rows[1]["commander"] == "uav1"


def test_a_members_decision_log_is_bounded() -> None:
    log = DecisionLog()
    for i in range(MAX_DECIDED_COMMANDS + 5):
        log.decided("uav1", i, "HOLD", CommandResult.REJECTED, "expired", float(i))
    rows = log.recent(1000.0)
    assert len(rows) == MAX_DECIDED_COMMANDS and log.evicted == 5
    assert rows[0]["command_id"] == MAX_DECIDED_COMMANDS + 4


# ---- selection, exit code, rendering --------------------------------------------------------


def test_exit_code_is_1_when_a_shown_command_has_a_drone_that_did_not_execute_it() -> None:
    answer = {"role": "commander", "issued": [ONE_MISSED, ALL_DONE], "ran": []}
    assert exit_code(select(answer, None) or {}) == EX_FAILED
    assert exit_code(select(answer, 0x11) or {}) == EX_OK
    assert exit_code(select(answer, 0x12) or {}) == EX_FAILED
    assert select(answer, 0x99) is None
    ran = {"command_id": 5, "kind": "land", "commander": "uav1", "state": "rejected"}
    assert exit_code({"issued": [], "ran": [ran]}) == EX_FAILED
    assert exit_code({"issued": [], "ran": []}) == EX_OK  # nothing kept: nothing missed


def test_the_view_names_every_drone_that_did_not_execute_and_why() -> None:
    lines = render_kept(select({"issued": [ONE_MISSED], "ran": []}, None) or {}, WALL_NOW)
    text = "\n".join(lines)
    assert lines[0].startswith("TAKEOFF 0x12  issued ") and "(60 s ago)" in lines[0]
    assert "sent by ops (uid 1001, pid 4242)" in text
    assert "UNREACHABLE" in text and "not_reached_while_valid" in text  # the outcome table
    assert lines[-1].strip() == (
        "1/3 executed; not reported executed: uav3 (unreachable: not_reached_while_valid), "
        "uav4 (rejected: expired)"
    )


def test_a_drone_whose_save_failed_is_marked_in_the_commanders_view() -> None:
    """The member flagged its outcome ``OUTCOME_NOT_SAVED`` (docs/dataplane.md, "A failed
    save"): the commander's row says so; ``--json`` keeps ``save_failed``."""
    marked = {**_node("completed", "IN_AIR", 0.01), "save_failed": True}
    cmd = _issued(0x15, {"uav2": marked, "uav3": _node("completed", "IN_AIR", 0.01)})
    lines = render_kept({"issued": [cmd], "ran": []}, WALL_NOW)
    uav2 = next(ln for ln in lines if ln.split()[:1] == ["uav2"])
    uav3 = next(ln for ln in lines if ln.split()[:1] == ["uav3"])
    assert "IN_AIR [not saved on drone]" in uav2 and "not saved" not in uav3
    assert lines[-1].strip() == "2/2 executed"  # it ran: the mark is not a failure
    body = to_json({"issued": [cmd], "ran": []}, WALL_NOW, EX_OK)
    assert body["issued"][0]["nodes"]["uav2"]["save_failed"] is True


def test_swarmctl_following_a_command_says_when_a_drone_could_not_save(
    capsys: pytest.CaptureFixture[str],
) -> None:
    """``swarmctl hold`` (any command it follows) prints one line when a drone's row gets
    the mark, and its closing table shows it; the command still counts as confirmed."""
    marked = {**_node("completed", "", 0.01), "save_failed": True}
    snap = {**_issued(0x16, {"uav2": marked}, kind="hold"), "valid_left_s": 0.0}
    run = takeoff_cmd._Run(argparse.Namespace(json=False, timeout=30.0))
    reply = {"command_id": 0x16, "ready": ["uav2"], "valid_for_s": 10.0}
    code = takeoff_cmd._follow(_Outcomes(snap), run, reply, "hold")  # type: ignore[arg-type]
    out = capsys.readouterr().out
    assert code == EX_OK
    assert out.count("uav2: its daemon could not write its record of this command") == 1
    assert "- [not saved on drone]" in out and "hold: 1/1 confirmed" in out


def test_an_open_command_says_so_and_a_member_shows_what_it_ran() -> None:
    open_cmd = _issued(0x13, {"uav2": _node("pending")}, done=False, sent_by=None)
    open_cmd["valid_left_s"] = 4.5
    ran = {
        "command_id": 0x12,
        "kind": "takeoff",
        "commander": "uav1",
        "state": "completed",
        "reason": "IN_AIR",
        "age_s": 30.0,
        "done_s": 2.0,
    }
    lines = render_kept({"issued": [open_cmd], "ran": [ran]}, WALL_NOW)
    assert "sent by - (no control socket client)" in lines[1]
    assert lines[lines.index("") - 1].strip() == (
        "0/1 executed; not reported executed: uav2 (pending) (still open; valid for 4.5 s more)"
    )
    assert any(ln.split()[:5] == ["0x12", "TAKEOFF", "uav1", "COMPLETED", "IN_AIR"] for ln in lines)
    assert render_kept({"role": "member", "issued": [], "ran": []}, WALL_NOW) == [
        "no commands kept here (role member)"
    ]


def test_peer_strings_in_the_view_are_data_and_json_keeps_them_exact() -> None:
    """Attack 8 (issue 10) on this view: a drone's name and reason, the commander's name a
    member shows and the sender's user name carry ESC, OSC, C1 CSI and RLO. Each is shown
    as a visible escape, once (not escaped twice); ``--json`` keeps the exact value."""
    hostile = _issued(
        0x14,
        {HOSTILE: _node(HOSTILE, HOSTILE)},
        kind=HOSTILE,
        sent_by={"uid": 1001, "user": HOSTILE, "pid": 1},
    )
    ran = {"command_id": 1, "kind": HOSTILE, "commander": HOSTILE, "state": HOSTILE}
    shown = {"role": HOSTILE, "issued": [hostile], "ran": [ran]}
    text = "\n".join(render_kept(shown, WALL_NOW))
    assert _unsafe(text) == []
    assert "uav9\\x1b[2J" in text and "\\u202eydaer" in text and "\\\\x1b" not in text
    as_json = json.dumps(to_json(shown, WALL_NOW, EX_FAILED))
    assert json.loads(as_json)["issued"][0]["nodes"][HOSTILE]["reason"] == HOSTILE


def test_json_adds_the_wall_clock_and_the_exit_code_to_the_daemons_keys() -> None:
    body = to_json({"role": "commander", "issued": [ALL_DONE], "ran": []}, WALL_NOW, EX_OK)
    assert body["exit_code"] == EX_OK and body["role"] == "commander"
    entry = body["issued"][0]
    assert entry["issued_at"] == "2025-06-15T15:05:40Z"  # WALL_NOW less age_s, in UTC
    assert {k: entry[k] for k in ALL_DONE} == ALL_DONE  # the daemon's keys, unchanged


# ---- a real swarmctl ------------------------------------------------------------------------


def _swarmctl(*argv: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [SWARMCTL, *argv], capture_output=True, text=True, timeout=60, check=False
    )


def test_a_real_swarmctl_prints_hostile_outcomes_as_data(workdir: Path) -> None:
    """A control socket whose ``outcomes`` carries escapes in a drone's name and reason, as
    a captured member could choose its reason (real swarmctl process, real socket): the
    terminal sees no control character; exit 1, the drone did not execute."""
    sock = str(workdir / "s.sock")
    answer = {
        "role": "commander",
        "issued": [_issued(0x15, {HOSTILE: _node("rejected", HOSTILE, 0.01)})],
        "ran": [],
    }

    async def main() -> list[subprocess.CompletedProcess[str]]:
        server = ControlServer(sock, {"outcomes": lambda _req: answer})
        await server.start()
        try:
            return [
                await asyncio.to_thread(_swarmctl, "outcomes", *extra, "--socket", sock)
                for extra in ([], ["0x15"], ["--json"])
            ]
        finally:
            await server.close()

    human, one, as_json = asyncio.run(main())
    for proc in (human, one):
        assert proc.returncode == EX_FAILED, proc.stderr
        assert _unsafe(proc.stdout + proc.stderr) == []
        assert "uav9\\x1b[2J" in proc.stdout and "REJECTED" in proc.stdout
    assert json.loads(as_json.stdout)["issued"][0]["nodes"][HOSTILE]["reason"] == HOSTILE


def test_no_daemon_is_exit_2_with_one_line(workdir: Path) -> None:
    proc = _swarmctl("outcomes", "--socket", str(workdir / "none.sock"))
    assert proc.returncode == EX_UNREACHABLE and proc.stdout == ""
    assert len(proc.stderr.strip().splitlines()) == 1


def test_a_real_daemon_shows_what_became_of_a_command(workdir: Path) -> None:
    """Three drones in the bundle, two running (uav1 commands; no vehicles): a LAND to uav2
    and uav3 from the control socket. uav2 answers (REJECTED ``px4_disabled``: it has no
    vehicle), uav3 never runs and is ``unreachable`` once the validity ends. ``swarmctl
    outcomes`` on the commander shows both with the sender, exit 1; ``--json`` has the
    documented keys; an unknown id is exit 2; on uav2 it shows what uav2 decided."""
    files = write_bundle(workdir, 3, domain_id=run_domain() + 17)
    socks = [workdir / f"uav{i}.sock" for i in (1, 2)]
    state = swarm_sections(workdir / "state", None, period_s=0.5)
    daemons = [loopback_daemon(workdir, files, node, extra=state) for node in ("uav1", "uav2")]

    async def until(cond: Any, what: Any) -> None:
        loop = asyncio.get_running_loop()
        deadline = loop.time() + 30.0
        while not cond():
            if loop.time() > deadline:
                raise AssertionError(f"gave up waiting: {what()}")
            await asyncio.sleep(0.05)

    async def main() -> tuple[int, list[subprocess.CompletedProcess[str]]]:
        for d in daemons:
            await d.start()
        try:
            app = daemons[0].app
            assert app is not None and app.is_commander

            def uav2_heard() -> bool:
                row = app.table.rows(asyncio.get_running_loop().time()).get("uav2") or {}
                return bool(row.get("peer_up")) and bool(row.get("count"))

            await until(uav2_heard, lambda: daemons[0].status()["readiness"])

            def issue() -> dict[str, Any]:
                with ControlClient(str(socks[0])) as client:
                    sent: dict[str, Any] = client.request(
                        "command", kind="land", only=["uav2", "uav3"], valid_for_s=1.0
                    )
                    return sent

            cid = int((await asyncio.to_thread(issue))["command_id"])
            await until(
                lambda: app.request_outcomes({"command_id": cid})["done"],
                lambda: app.request_outcomes({"command_id": cid}),
            )
            runs = [
                await asyncio.to_thread(_swarmctl, "outcomes", *argv)
                for argv in (
                    ["--socket", str(socks[0])],
                    [f"{cid:#x}", "--json", "--socket", str(socks[0])],
                    [f"{cid + 1:#x}", "--socket", str(socks[0])],
                    ["--socket", str(socks[1])],
                    [f"{cid}", "--socket", str(socks[1]), "--json"],
                )
            ]
            return cid, runs
        finally:
            for d in daemons:
                await d.stop("test")

    cid, (human, as_json, unknown, member, member_json) = run_on_raw_clock(main())

    assert human.returncode == EX_FAILED, human.stderr
    assert human.stdout.startswith(f"LAND {cid:#x}  issued "), human.stdout
    assert "sent by root (uid 0, pid " in human.stdout
    rows = {ln.split()[0]: ln.split()[1:3] for ln in human.stdout.splitlines() if "uav" in ln}
    assert rows["uav2"] == ["REJECTED", "px4_disabled"], human.stdout
    assert rows["uav3"] == ["UNREACHABLE", "not_reached_while_valid"], human.stdout
    assert (
        "0/2 executed; not reported executed: uav2 (rejected: px4_disabled), uav3 (unreachable"
        in (human.stdout)
    )

    assert as_json.returncode == EX_FAILED, as_json.stderr
    body = json.loads(as_json.stdout)
    assert set(body) == {
        "role", "issued", "issued_evicted", "ran", "ran_evicted", "life", "exit_code",
    }  # fmt: skip
    assert body["role"] == "commander" and body["exit_code"] == EX_FAILED and body["ran"] == []
    (entry,) = body["issued"]
    assert entry["command_id"] == cid and entry["kind"] == "land" and entry["done"]
    assert entry["sent_by"]["uid"] == 0 and entry["issued_at"].endswith("Z")
    assert {n: v["state"] for n, v in entry["nodes"].items()} == {
        "uav2": "rejected",
        "uav3": "unreachable",
    }

    assert unknown.returncode == EX_UNREACHABLE and unknown.stdout == ""
    assert "unknown command id" in unknown.stderr

    assert member.returncode == EX_FAILED, member.stderr
    assert any(
        ln.split()[:5] == [f"{cid:#x}", "LAND", "uav1", "REJECTED", "px4_disabled"]
        for ln in member.stdout.splitlines()
    ), member.stdout
    (ran,) = json.loads(member_json.stdout)["ran"]
    assert (ran["command_id"], ran["commander"], ran["state"]) == (cid, "uav1", "rejected")
