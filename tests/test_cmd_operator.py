"""What ``swarmctl takeoff | land | hold | abort`` tells the operator (session 17 review,
from the operator's seat): every drone named once, a command sent is always followed and
named, ``--json`` stable, drone names shown as data.

A played commander (``Played``) answers swarmctl's control requests in-process, on a
virtual clock swarmctl's waits advance (``Clock``), so nothing here sleeps or asserts how
fast anything happened. ``tests/test_cmd_operator_loopback.py`` runs the take-off case
against real daemons.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest

from swarmd.cli import outcomes_cmd, swarmctl, takeoff_cmd
from swarmd.control import DaemonUnreachable
from swarmd.exitcodes import EX_FAILED, EX_INTERRUPTED, EX_NOT_READY, EX_OK, EX_UNREACHABLE

COMMAND_ID = 0x6B09A20700000001
HOSTILE = "uav9\x1b[2J\u202e"
DRONES = ("uav1", "uav2", "uav3")


class Clock:
    """swarmctl's ``time``: ``sleep`` moves the virtual clock on, nothing waits."""

    def __init__(self) -> None:
        self.now = 0.0

    def monotonic(self) -> float:
        return self.now

    def sleep(self, seconds: float) -> None:
        self.now += seconds


def _row(state: str, reason: str | None = None) -> dict[str, Any]:
    return {"state": state, "reason": reason, "latency_s": None, "done_s": None,
            "after_restart": False, "save_failed": False}  # fmt: skip


class Played:
    """The commander's answers. ``ready``: each drone's readiness (a drone missing from it
    is ``no_report``, never heard since boot); ``reply``: the answer to the request that
    sends; ``outcome(age)``: the ``nodes`` and ``done`` of the sent command ``age``
    seconds after it went out; ``interrupt``: the request (and its call number) at which
    the operator presses Ctrl-C; ``lost``: the one at which the daemon goes."""

    def __init__(
        self,
        clock: Clock,
        *,
        ready: dict[str, bool],
        reply: dict[str, Any],
        outcome: Callable[[float], tuple[dict[str, Any], bool]],
        interrupt: tuple[str, int] | None = None,
        lost: tuple[str, int] | None = None,
    ) -> None:
        self.clock = clock
        self.ready = ready
        self.reply = reply
        self.outcome = outcome
        self.interrupt = interrupt
        self.lost = lost
        self.calls: dict[str, int] = {}
        self.sent_at: float | None = None

    def client(self, _path: str, **_kw: Any) -> Played:
        return self

    def __enter__(self) -> Played:
        return self

    def __exit__(self, *exc: object) -> None:
        return None

    def request(self, cmd: str, **request: Any) -> Any:
        self.calls[cmd] = self.calls.get(cmd, 0) + 1
        if self.interrupt == (cmd, self.calls[cmd]):
            raise KeyboardInterrupt
        if self.lost == (cmd, self.calls[cmd]):  # the commander's daemon restarted
            raise DaemonUnreachable("lost the connection to swarmd: Connection reset by peer")
        if cmd == "status":
            rows: dict[str, dict[str, Any]] = {n: {} for n in DRONES}
            return {"node": "uav1", "role": "commander", "dataplane": {"enabled": True},
                    "readiness": rows}  # fmt: skip
        if cmd == "readiness":
            return {
                n: {"ready": self.ready[n], "reason": None if self.ready[n] else "no_3d_fix"}
                if n in self.ready
                else {"ready": False, "reason": "no_report"}
                for n in DRONES
            }
        if cmd in ("takeoff", "command"):
            self.sent_at = self.clock.now
            return self.reply
        assert cmd == "outcomes" and request["command_id"] == COMMAND_ID, (cmd, request)
        assert self.sent_at is not None
        nodes, done = self.outcome(self.clock.now - self.sent_at)
        return {"command_id": COMMAND_ID, "kind": "takeoff", "targets": list(nodes),
                "valid_for_s": 3.0, "valid_left_s": 0.0, "done": done, "sent_by": None,
                "nodes": nodes}  # fmt: skip


@pytest.fixture
def clock(monkeypatch: pytest.MonkeyPatch) -> Clock:
    c = Clock()
    monkeypatch.setattr(takeoff_cmd, "time", SimpleNamespace(monotonic=c.monotonic, sleep=c.sleep))
    return c


def _run(monkeypatch: pytest.MonkeyPatch, played: Played, argv: list[str], as_json: bool) -> int:
    monkeypatch.setattr(takeoff_cmd, "ControlClient", played.client)
    return swarmctl.main([*argv, "--socket", "/nonexistent", *(["--json"] if as_json else [])])


SENT = {"sent": True, "command_id": COMMAND_ID, "ready": ["uav1", "uav2"],
        "refused": {"uav3": "no_report"}, "valid_for_s": 3.0}  # fmt: skip


def _airborne_after_one_second(age: float) -> tuple[dict[str, Any], bool]:
    state = "completed" if age >= 1.0 else "pending"
    nodes = {"uav1": _row(state, "TAKEOFF"), "uav2": _row(state, "TAKEOFF"),
             "uav3": _row("refused", "no_report")}  # fmt: skip
    return nodes, state == "completed"


@pytest.mark.parametrize("as_json", [False, True])
def test_a_takeoff_sent_after_a_long_readiness_wait_is_still_followed(
    clock: Clock, monkeypatch: pytest.MonkeyPatch, as_json: bool, capsys: pytest.CaptureFixture[str]
) -> None:
    """uav3 is in the bundle and never heard since boot: the readiness wait lasts the
    whole ``--timeout``, then the ready drones are sent the take-off. [fails on main: the
    follow shared that spent budget, so swarmctl left at its first poll, uav1 and uav2
    ``pending``, "timed out waiting for the rest", while they took off]"""
    played = Played(clock, ready={"uav1": True, "uav2": True}, reply=SENT,
                    outcome=_airborne_after_one_second)  # fmt: skip
    code = _run(monkeypatch, played, ["takeoff", "--timeout", "5"], as_json)
    out, err = capsys.readouterr()
    assert code == EX_FAILED  # uav3 was refused (no_report): not every drone airborne
    if as_json:
        nodes = json.loads(out)["nodes"]
        assert {n: v["state"] for n, v in nodes.items()} == {
            "uav1": "completed", "uav2": "completed", "uav3": "refused"}  # fmt: skip
    else:
        assert "takeoff: 2/3 confirmed airborne" in out, out
        assert "timed out" not in out + err


@pytest.mark.parametrize("as_json", [False, True])
@pytest.mark.parametrize("kind", ["takeoff", "land"])
def test_ctrl_c_while_following_names_the_running_command(
    clock: Clock,
    monkeypatch: pytest.MonkeyPatch,
    kind: str,
    as_json: bool,
    capsys: pytest.CaptureFixture[str],
) -> None:
    """Ctrl-C after the command went out: it keeps running on the drones, and the
    operator is told which one and how to follow it; ``--json`` still gets its object.
    [fails on main: one line "swarmctl: interrupted", no command id, nothing on stdout]"""
    played = Played(clock, ready={n: True for n in DRONES}, reply=SENT,
                    outcome=_airborne_after_one_second, interrupt=("outcomes", 2))  # fmt: skip
    code = _run(monkeypatch, played, [kind], as_json)
    out, err = capsys.readouterr()
    assert code == EX_INTERRUPTED
    assert f"swarmctl outcomes {COMMAND_ID:#x}" in err, err
    if as_json:
        final = json.loads(out)
        assert final["command_id"] == COMMAND_ID and final["sent"] is True
        assert final["exit_code"] == EX_INTERRUPTED and set(final["nodes"]) == set(DRONES)


@pytest.mark.parametrize("as_json", [False, True])
@pytest.mark.parametrize(
    ("argv", "at", "sent"),
    [
        (["land"], ("command", 1), None),  # the request is on its way: not known
        (["takeoff"], ("takeoff", 1), None),
        (["takeoff", "--require-all"], ("readiness", 2), False),  # still waiting
    ],
)
def test_ctrl_c_before_the_answer_says_whether_anything_went_out(
    clock: Clock,
    monkeypatch: pytest.MonkeyPatch,
    argv: list[str],
    at: tuple[str, int],
    sent: bool | None,
    as_json: bool,
    capsys: pytest.CaptureFixture[str],
) -> None:
    """[fails on main: "swarmctl: interrupted" alone, whether or not the daemon had the
    request; nothing on stdout with --json]"""
    ready = {"uav1": True, "uav2": True} if sent is False else {n: True for n in DRONES}
    played = Played(clock, ready=ready, reply=SENT, outcome=_airborne_after_one_second,
                    interrupt=at)  # fmt: skip
    code = _run(monkeypatch, played, argv, as_json)
    out, err = capsys.readouterr()
    assert code == EX_INTERRUPTED
    if sent is None:
        assert "may have sent" in err and "swarmctl outcomes" in err, err
    else:
        assert "not sent" in err, err
    if as_json:
        final = json.loads(out)
        assert final["sent"] is sent and final["command_id"] is None
        assert final["exit_code"] == EX_INTERRUPTED


@pytest.mark.parametrize("as_json", [False, True])
def test_a_require_all_takeoff_refused_at_the_send_names_every_drone(
    clock: Clock, monkeypatch: pytest.MonkeyPatch, as_json: bool, capsys: pytest.CaptureFixture[str]
) -> None:
    """Every drone was ready in the wait; uav3 lost its fix before the daemon checked
    again, so ``--require-all`` sent nothing. [fails on main: "not sent, no drone is
    ready: uav3 (no_3d_fix)", false, and uav1, uav2 named nowhere, nor in --json]"""
    reply = {"sent": False, "command_id": None, "ready": ["uav1", "uav2"],
             "refused": {"uav3": "no_3d_fix"}}  # fmt: skip
    played = Played(clock, ready={n: True for n in DRONES}, reply=reply,
                    outcome=_airborne_after_one_second)  # fmt: skip
    code = _run(monkeypatch, played, ["takeoff", "--require-all"], as_json)
    out, err = capsys.readouterr()
    assert code == EX_NOT_READY
    last = (err if as_json else out).strip().splitlines()[-1]
    assert "no drone is ready" not in last
    assert all(n in last for n in DRONES), last
    if as_json:
        final = json.loads(out)
        assert final["sent"] is False and final["ready"] == ["uav1", "uav2"]
        assert final["refused"] == {"uav3": "no_3d_fix"}


def _never_ready(_age: float) -> tuple[dict[str, Any], bool]:
    raise AssertionError("nothing was sent")


@pytest.mark.parametrize(
    ("argv", "ready", "reply", "outcome", "code", "sent"),
    [
        (["takeoff"], {n: True for n in DRONES}, SENT, _airborne_after_one_second,
         EX_FAILED, True),
        (["land"], {}, SENT, _airborne_after_one_second, EX_FAILED, True),
        (["takeoff", "--require-all", "--timeout", "1"], {"uav1": True}, SENT, _never_ready,
         EX_NOT_READY, False),
        (["takeoff"], {"uav1": False, "uav2": False, "uav3": False},
         {"sent": False, "command_id": None, "ready": [], "refused": {"uav1": "no_3d_fix"}},
         _never_ready, EX_FAILED, False),
    ],
)  # fmt: skip
def test_every_json_end_says_whether_the_command_was_sent(
    clock: Clock,
    monkeypatch: pytest.MonkeyPatch,
    argv: list[str],
    ready: dict[str, bool],
    reply: dict[str, Any],
    outcome: Callable[[float], tuple[dict[str, Any], bool]],
    code: int,
    sent: bool,
    capsys: pytest.CaptureFixture[str],
) -> None:
    """``sent`` is in every final object (true, false, or null when not known), so a
    script reads one key. [fails on main: only the ends after a lost answer had it]"""
    played = Played(clock, ready=ready, reply=reply, outcome=outcome)
    assert _run(monkeypatch, played, argv, True) == code
    final = json.loads(capsys.readouterr().out)
    assert final["sent"] is sent and final["exit_code"] == code
    if sent:
        assert final["command_id"] == COMMAND_ID and final["nodes"]


def test_drone_names_in_the_last_line_are_shown_as_data(
    clock: Clock, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """The summary line names the unreachable drones and those the command may yet
    start on; a drone's name reaches the terminal escaped, as in the table above it
    (docs/operations.md, "swarmctl on the drone"). [fails on main: raw ESC and U+202E]"""

    def outcome(_age: float) -> tuple[dict[str, Any], bool]:
        nodes = {HOSTILE: _row("unreachable", "not_reached_while_valid"),
                 HOSTILE + "p": _row("pending")}  # fmt: skip
        return nodes, False

    reply = {**SENT, "ready": [HOSTILE, HOSTILE + "p"], "refused": {}}
    played = Played(clock, ready={}, reply=reply, outcome=outcome)
    code = _run(monkeypatch, played, ["land", "--timeout", "1"], False)
    out, err = capsys.readouterr()
    assert code == EX_FAILED
    assert "\x1b" not in out + err and "\u202e" not in out + err
    assert "uav9\\x1b[2J" in out.strip().splitlines()[-1]


def test_a_clean_takeoff_is_still_exit_0(
    clock: Clock, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """Guard: every drone ready and airborne."""

    def outcome(age: float) -> tuple[dict[str, Any], bool]:
        return {n: _row("completed" if age >= 1 else "pending") for n in DRONES}, age >= 1

    reply = {**SENT, "ready": list(DRONES), "refused": {}}
    played = Played(clock, ready={n: True for n in DRONES}, reply=reply, outcome=outcome)
    assert _run(monkeypatch, played, ["takeoff"], False) == EX_OK
    assert "takeoff: 3/3 confirmed airborne" in capsys.readouterr().out


@pytest.mark.parametrize(
    ("argv", "then"),
    [(["takeoff"], "then sent to the ready ones"),
     (["takeoff", "--require-all"], "sent only if all become ready")],
)  # fmt: skip
def test_the_readiness_wait_says_how_long_it_may_last_and_what_comes_after(
    clock: Clock,
    monkeypatch: pytest.MonkeyPatch,
    argv: list[str],
    then: str,
    capsys: pytest.CaptureFixture[str],
) -> None:
    """uav3 never heard: the wait holds for the whole ``--timeout`` with no line in
    between, so its one line says so. [fails on main: "waiting for uav3 (no_report)"]"""
    played = Played(clock, ready={"uav1": True, "uav2": True}, reply=SENT,
                    outcome=_airborne_after_one_second)  # fmt: skip
    _run(monkeypatch, played, [*argv, "--timeout", "5"], False)
    first = capsys.readouterr().out.splitlines()[0]
    assert "up to 5 s" in first and "uav3 (no_report)" in first and then in first, first


@pytest.mark.parametrize("as_json", [False, True])
@pytest.mark.parametrize("at", [1, 7])
def test_a_commander_lost_while_following_leaves_every_drone_named_once(
    clock: Clock,
    monkeypatch: pytest.MonkeyPatch,
    at: int,
    as_json: bool,
    capsys: pytest.CaptureFixture[str],
) -> None:
    """The commander's daemon restarts while swarmctl follows: at its first look (``1``),
    or after uav1 answered (``7``, 1.2 s in). Each drone is named once with the last answer known.
    [fails on main: a drone with no answer yet named only in the "sent to" line; with
    --json no ``nodes`` at all when the first look failed]"""

    def outcome(age: float) -> tuple[dict[str, Any], bool]:
        nodes, _ = _airborne_after_one_second(age)
        nodes["uav2"] = _row("pending")
        return nodes, False

    played = Played(clock, ready={n: True for n in DRONES}, reply=SENT, outcome=outcome,
                    lost=("outcomes", at))  # fmt: skip
    code = _run(monkeypatch, played, ["takeoff"], as_json)
    out, err = capsys.readouterr()
    assert code == EX_FAILED
    assert f"swarmctl outcomes {COMMAND_ID:#x}" in err and "on each drone" in err, err
    uav1 = "completed" if at > 1 else "pending"
    if as_json:
        final = json.loads(out)
        assert final["sent"] is True and final["error"]
        assert {n: v["state"] for n, v in final["nodes"].items()} == {
            "uav1": uav1, "uav2": "pending", "uav3": "refused"}  # fmt: skip
    else:
        table = out[out.index("last known") :].splitlines()
        for name, state in (("uav1", uav1), ("uav2", "pending"), ("uav3", "refused")):
            (row,) = [line for line in table if line.split()[0] == name]
            assert row.split()[1] == state.upper(), table


@pytest.mark.parametrize("argv", [[], [f"{COMMAND_ID:#x}"]])
def test_a_restarted_commanders_outcomes_say_where_its_earlier_commands_are(
    monkeypatch: pytest.MonkeyPatch, argv: list[str], capsys: pytest.CaptureFixture[str]
) -> None:
    """The commander's daemon restarted after the take-off: it keeps no command of its
    earlier life, its drones keep their decisions. [fails on main: "no commands kept
    here" (exit 0) or "unknown command id" (exit 2), and nowhere else to look]"""
    answer = {"role": "commander", "issued": [], "issued_evicted": 0, "ran": [],
              "ran_evicted": 0, "life": 8}  # fmt: skip
    monkeypatch.setattr(outcomes_cmd, "request", lambda _sock, _cmd: answer)
    code = swarmctl.main(["outcomes", *argv, "--socket", "/nonexistent"])
    out, err = capsys.readouterr()
    assert code == (EX_UNREACHABLE if argv else EX_OK)
    assert "this life of its daemon" in out + err and "on each drone" in out + err


def test_swarmctl_help_lists_every_exit_code_operations_md_gives_swarmctl(
    capsys: pytest.CaptureFixture[str],
) -> None:
    """[fails on main: ``swarmctl --help`` named no exit code]"""
    text = (Path(__file__).parents[1] / "docs" / "operations.md").read_text()
    section = text[text.index("\n## Exit codes\n") :]
    section = section[: section.index("\n## ", 1)]
    codes = [
        cells[0]
        for line in section.splitlines()
        if line.startswith("| ")
        and (cells := [c.strip() for c in line.strip("|").split("|")])[0].isdigit()
        and cells[2]
    ]
    assert "130" in codes and "3" in codes
    with pytest.raises(SystemExit):
        swarmctl.main(["--help"])
    epilog = " ".join(capsys.readouterr().out.split("Exit codes", 1)[1].split())
    assert [c for c in codes if f" {c} " not in epilog.replace(";", " ")] == []
