"""``swarmctl takeoff | land | hold | abort``: command the swarm from the commander's drone.

``takeoff`` first waits, with a progress line whenever something changes, for readiness as
asked: by default until every targeted drone has reported (then the ready ones are sent the
command and the others are listed as refused with their reason); with ``--require-all``
until every targeted drone is ready (nothing is sent if that does not happen within
``--timeout``). Then it sends the command and follows each drone's outcome to the end, for
up to ``--timeout`` again (a wait for readiness that used the budget does not leave the
command unfollowed). Ctrl-C says whether the command went out and how to follow it.

Every command has a validity (``--valid-for``; defaults per kind in
``swarmd.swarm.issuer.DEFAULT_VALID_FOR_S``): a drone that has not received it by then refuses
it for good. A drone that did not answer while the command was valid is reported
``unreachable``: the command can no longer start there; if it started, its answer was
lost and comes late (docs/dataplane.md, "Validity"). A
drone whose daemon restarted before its answer arrived tells the commander afterwards what
it did; such a row is marked as told after a restart (``after_restart`` in ``--json``;
docs/dataplane.md, "Outcomes across a restart"); one that accepted it and restarted with
nothing to re-report is said so too (no completion will come). A drone that could not
write its record of the command to its state file says so, and its row is marked
``[not saved on drone]`` (``save_failed``; docs/dataplane.md, "A failed save") until it
says a later write held it.

Exit codes (docs/operations.md): 0 every targeted drone confirmed (airborne, for take-off);
1 some drone refused, failed, was unreachable while the command was valid, or did not
answer in time, or the daemon took the command request and its answer never came (it may
have sent the command: "A command request left unanswered"); 2 the daemon is not
reachable or answered that it is stopping (nothing sent);
3 ``--require-all`` and not every targeted drone became ready (nothing sent); 64 usage
(not the commander, unknown node, bad altitude, a validity out of range, data plane
disabled); 130 interrupted
(a command already sent keeps running on the drones). Each drone's RESULT and REASON:
docs/operations.md, "What swarmctl tells you about a command".
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Callable, Sequence
from typing import Any, Final, TextIO

from swarmd.cli.commands_view import DISARM_MARK, FollowLines, reason_text, reasons, sent_line
from swarmd.cli.status_cmd import socket_argument, table
from swarmd.control import (
    ControlClient,
    DaemonStopping,
    DaemonUnreachable,
    ReplyLost,
    RequestError,
)
from swarmd.dataplane.types import CommandKind
from swarmd.exitcodes import (
    EX_FAILED,
    EX_INTERRUPTED,
    EX_NOT_READY,
    EX_OK,
    EX_UNREACHABLE,
    EX_USAGE,
)
from swarmd.swarm.commander import UNREACHABLE
from swarmd.swarm.issuer import DEFAULT_VALID_FOR_S
from swarmd.terminal import safe_text, safe_tree

COMMAND_KINDS: Final = {k.name.lower(): k for k in CommandKind}

POLL_S: Final = 0.2
UNHEARD: Final = ("no_report", "peer_lost", "report_stale")


def register(sub: Any) -> None:
    what = "take off the swarm's ready drones (run on the commander's drone)"
    takeoff = sub.add_parser(
        "takeoff",
        help=what,
        description=_description(what, takeoff=True),
    )
    takeoff.add_argument(
        "--alt", type=float, default=None, metavar="M",
        help="metres above home (default: the commander's px4.takeoff_alt_m)",
    )  # fmt: skip
    _targets(takeoff)
    _validity(takeoff, "takeoff")
    takeoff.add_argument(
        "--require-all", action="store_true",
        help="wait until every targeted drone is ready; send nothing otherwise",
    )  # fmt: skip
    _common(takeoff, default_timeout=60.0)
    takeoff.set_defaults(func=_takeoff, kind="takeoff")
    for kind, text in (
        ("land", "land the drones where they are (NAV_LAND)"),
        ("hold", "hold position (PX4 Hold mode)"),
        ("abort", "stop what a drone does: disarm on the ground, land in the air (never forced)"),
    ):
        p = sub.add_parser(kind, help=text, description=_description(text))
        _targets(p)
        _validity(p, kind)
        _common(p, default_timeout=20.0)
        p.set_defaults(func=_simple, kind=kind)


def _description(what: str, *, takeoff: bool = False) -> str:
    """``--help``'s text: what the command does, then its exit codes (module docstring)."""
    return (
        f"{what[0].upper()}{what[1:]}, then follow each drone's answer to the end. Each "
        "RESULT and REASON: docs/operations.md, 'What swarmctl tells you about a command'. "
        + (
            "Exit 0 every targeted drone airborne; "
            if takeoff
            else "Exit 0 every targeted drone confirmed; "
        )
        + "1 one refused, failed, was unreachable while the command was valid, or did not "
        "answer within --timeout, or swarmd took the request and its answer never came (it "
        "may have sent it); 2 the daemon is not reachable or is stopping (nothing sent); "
        + ("3 --require-all and not every drone became ready: nothing sent; " if takeoff else "")
        + "64 not the commander, an unknown --only drone, "
        + ("a bad altitude, " if takeoff else "")
        + "a --valid-for outside what the daemon takes, the data plane disabled; "
        "130 interrupted (a command sent keeps running; the last line names it)."
    )


def _targets(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--only", nargs="+", action="extend", default=None, metavar="NODE",
        help="command only these drones (default: every drone of the swarm)",
    )  # fmt: skip


def _validity(p: argparse.ArgumentParser, kind: str) -> None:
    default = DEFAULT_VALID_FOR_S[COMMAND_KINDS[kind]]
    p.add_argument(
        "--valid-for", type=float, default=None, metavar="SECONDS",
        help=f"a drone that has not received the command within SECONDS of sending refuses "
        f"it for good (default {default:g})",
    )  # fmt: skip


def _common(p: argparse.ArgumentParser, *, default_timeout: float) -> None:
    socket_argument(p)
    p.add_argument(
        "--timeout", type=float, default=default_timeout, metavar="S",
        help=f"give up waiting after S seconds: for readiness (takeoff), then, once the "
        f"command is sent, for the drones' answers (default {default_timeout:g})",
    )  # fmt: skip
    p.add_argument("--json", action="store_true", help="print one JSON object at the end")


class _Run:
    """One invocation: the connection, the clock and where progress lines go."""

    def __init__(self, args: argparse.Namespace) -> None:
        self.args = args
        self.deadline: float = time.monotonic() + max(0.0, float(args.timeout))
        # with --json, stdout carries only the final object; progress goes to stderr
        self.progress: TextIO = sys.stderr if args.json else sys.stdout
        self._last = ""
        # what Ctrl-C leaves behind (``_interrupted``): the kind whose request is on its
        # way to the daemon, then the command it sent and the last outcome snapshot
        self.sending: str | None = None
        self.sent: int | None = None
        self.snap: dict[str, Any] = {}

    def say(self, line: str) -> None:
        if line != self._last:
            self._last = line
            # names and reasons in it come from the drones: shown, never obeyed (attack 8)
            print(safe_text(line), file=self.progress, flush=True)

    def expired(self) -> bool:
        return time.monotonic() >= self.deadline

    def follow_from_now(self) -> None:
        """A command was sent: following it gets a full ``--timeout`` of its own. A take-off
        whose readiness wait used the budget (a member lost, or never heard since boot)
        was otherwise sent and left at once, every drone ``pending`` (session 17)."""
        self.deadline = time.monotonic() + max(0.0, float(self.args.timeout))


def _session(args: argparse.Namespace, body: Callable[[ControlClient, _Run], int]) -> int:
    """Run ``body`` on one control connection; the exits every command shares."""
    run = _Run(args)
    try:
        with ControlClient(args.socket) as client:
            return body(client, run)
    except DaemonUnreachable as exc:
        print(f"swarmctl: {safe_text(str(exc))}", file=sys.stderr)
        return EX_UNREACHABLE
    except KeyboardInterrupt:  # a command already sent keeps running on the drones
        return _interrupted(run)


def _interrupted(run: _Run) -> int:
    """Ctrl-C: say whether a command went out and how to follow it; with ``--json`` the
    final object too (``sent``: true, null for not known, false), as for every other end
    after the daemon answered. Before, one line "interrupted" left a running command
    unnamed (session 17)."""
    kind = str(getattr(run.args, "kind", "takeoff")).upper()
    if run.sent is not None:
        print(
            f"swarmctl: interrupted; {kind} command {run.sent:#x} was sent and keeps running "
            f"on the drones: 'swarmctl outcomes {run.sent:#x}' tells what became of it",
            file=sys.stderr,
        )
        _final(run.args, run.sent, {**run.snap, "sent": True}, EX_INTERRUPTED)
    elif run.sending is not None:
        print(
            f"swarmctl: interrupted while swarmd took the {kind} request; it may have sent "
            "it to the drones: 'swarmctl outcomes' lists the commands it sent",
            file=sys.stderr,
        )
        _final(run.args, None, {"sent": None}, EX_INTERRUPTED)
    else:
        print(f"swarmctl: interrupted; the {kind} command was not sent", file=sys.stderr)
        _final(run.args, None, {"sent": False}, EX_INTERRUPTED)
    return EX_INTERRUPTED


def _takeoff(args: argparse.Namespace) -> int:
    def body(client: ControlClient, run: _Run) -> int:
        targets = _check_commander(client, args.only)
        if isinstance(targets, int):
            return targets
        ready = _wait_for_readiness(client, run, targets, args.require_all)
        if ready is None:
            return EX_NOT_READY
        request: dict[str, Any] = {"only": targets, "require_all": args.require_all}
        if args.alt is not None:
            request["alt_m"] = args.alt
        if args.valid_for is not None:
            request["valid_for_s"] = args.valid_for
        run.sending = "takeoff"
        try:
            reply = client.request("takeoff", **request)
        except RequestError as exc:
            return _usage(str(exc))
        except DaemonStopping as exc:
            return _stopping("takeoff", exc)
        except ReplyLost as exc:
            return _reply_lost(run, "takeoff", exc)
        if not reply["sent"]:  # nobody ready, or one fell back between wait and send
            run.sending = None
            refused = reply.get("refused") or {}
            # --require-all: the others were ready, and are named too (session 17)
            ready = [n for n in reply.get("ready") or [] if n not in refused]
            code = EX_NOT_READY if args.require_all else EX_FAILED
            if ready:
                run.say(
                    f"not sent (--require-all): not ready: {reasons(refused)}; ready, "
                    f"not sent: {', '.join(ready)}"
                )
            else:
                run.say("not sent, no drone is ready: " + reasons(refused))
            _final(args, None, {"sent": False, "ready": ready, "refused": refused}, code)
            return code
        return _follow(client, run, reply, "takeoff")

    return _session(args, body)


def _simple(args: argparse.Namespace) -> int:
    def body(client: ControlClient, run: _Run) -> int:
        targets = _check_commander(client, args.only)
        if isinstance(targets, int):
            return targets
        request: dict[str, Any] = {"kind": args.kind, "only": targets}
        if args.valid_for is not None:
            request["valid_for_s"] = args.valid_for
        run.sending = args.kind
        try:
            reply = client.request("command", **request)
        except RequestError as exc:
            return _usage(str(exc))
        except DaemonStopping as exc:
            return _stopping(args.kind, exc)
        except ReplyLost as exc:
            return _reply_lost(run, args.kind, exc)
        return _follow(client, run, reply, args.kind)

    return _session(args, body)


def _stopping(kind: str, exc: DaemonStopping) -> int:
    """The daemon answered the command request that it is stopping: it ran nothing of it
    (``Driver.call``), so "not reachable, nothing sent" (exit 2), as when it is not running;
    with ``--json`` nothing on stdout, as every exit 2 (session 16)."""
    print(
        f"swarmctl: {safe_text(str(exc))}: the {kind.upper()} command was not sent; run it "
        "again once swarmd is back ('systemctl status swarmd')",
        file=sys.stderr,
    )
    return EX_UNREACHABLE


def _reply_lost(run: _Run, kind: str, exc: ReplyLost) -> int:
    """The command request reached the daemon and its answer did not come back: it may
    have gone to the drones, so not "not reachable" (exit 2, which says nothing was sent)
    but not confirmed (exit 1), and where to look (session 16 command review)."""
    print(
        f"swarmctl: {safe_text(str(exc))}; the {kind.upper()} request reached swarmd, which "
        "may have sent it to the drones: 'swarmctl outcomes' lists the commands it sent "
        "(unless it restarted since), 'swarmctl status' shows the drones",
        file=sys.stderr,
    )
    _final(run.args, None, {"sent": None, "error": str(exc)}, EX_FAILED)
    return EX_FAILED


def _connection_lost(
    run: _Run, kind: str, cid: int, snap: dict[str, Any], exc: DaemonUnreachable | RequestError
) -> int:
    """The daemon stopped answering about a command it had sent while we followed it: the
    command is out there, so exit 1 (not confirmed), never 2 ("not reachable": nothing
    sent), nor a traceback."""
    if not run.args.json:
        # every drone once, with the last answer heard from it (session 17: before, a
        # drone that had not answered yet was named only in the "sent to" line)
        print("last known, before swarmd stopped answering:")
        print("\n".join(render_outcomes(snap)))
    print(
        f"swarmctl: {safe_text(str(exc))}; {kind.upper()} command {cid:#x} was sent: "
        f"'swarmctl outcomes {cid:#x}' tells what became of it (a restarted swarmd no "
        "longer knows it: then 'swarmctl outcomes' on each drone says what that drone "
        "decided), 'swarmctl status' shows the drones",
        file=sys.stderr,
    )
    _final(run.args, cid, {**snap, "sent": True, "error": str(exc)}, EX_FAILED)
    return EX_FAILED


def _as_sent(reply: dict[str, Any]) -> dict[str, Any]:
    """The command as the daemon's answer to the send describes it, in the shape of its
    outcome entry: what swarmctl knows before its first look (every row ``pending`` but
    the refused ones), so an end before that look names every drone too."""
    row = {"reason": None, "latency_s": None, "done_s": None, "after_restart": False,
           "save_failed": False, "disarm_unconfirmed": False}  # fmt: skip
    nodes = {str(n): {"state": "pending", **row} for n in reply.get("ready") or []}
    for name, reason in (reply.get("refused") or {}).items():
        nodes[str(name)] = {**row, "state": "refused", "reason": reason}
    return {"command_id": reply.get("command_id"), "valid_for_s": reply.get("valid_for_s"),
            "done": False, "nodes": nodes}  # fmt: skip


def _usage(message: str) -> int:
    print(f"swarmctl: {safe_text(message)}", file=sys.stderr)
    return EX_USAGE


def _check_commander(client: ControlClient, only: list[str] | None) -> list[str] | int:
    """The targeted drones, or an exit code after a one-line message."""
    try:
        status = client.request("status")
    except RequestError as exc:
        return _usage(str(exc))
    if status.get("role") != "commander":
        return _usage(
            f"{status.get('node', 'this node')} is not the swarm's commander; "
            "run this on the commander's drone"
        )
    if not (status.get("dataplane") or {}).get("enabled"):
        return _usage("the data plane is disabled here (dataplane.enabled: false in swarmd.yaml)")
    known = list(status.get("readiness") or {})
    if not only:
        if not known:
            return _usage("the bundle names no drone that reports readiness to this commander")
        return known
    unknown = [n for n in only if n not in known]
    if unknown:
        return _usage(f"unknown drone {', '.join(unknown)}; known: {', '.join(known)}")
    return list(dict.fromkeys(only))


def _wait_for_readiness(
    client: ControlClient, run: _Run, targets: Sequence[str], require_all: bool
) -> list[str] | None:
    """Wait as asked; the ready drones, or None when --require-all was not met."""
    while True:
        rows = client.request("readiness")
        ready = [t for t in targets if (rows.get(t) or {}).get("ready")]
        waiting = {
            t: str((rows.get(t) or {}).get("reason") or "not_ready")
            for t in targets
            if t not in ready
        }
        unheard = {t: r for t, r in waiting.items() if r in UNHEARD}
        # how long the wait may last and what comes after: a drone lost, or never heard
        # since boot, holds it for the whole --timeout, with no line in between (session 17)
        line = f"readiness: {len(ready)}/{len(targets)} ready"
        if waiting and (require_all or unheard):
            then = "sent only if all become ready" if require_all else "then sent to the ready ones"
            line += f"; waiting up to {run.args.timeout:g} s for {reasons(waiting)}; {then}"
        elif waiting:
            line += f"; not ready: {reasons(waiting)}"
        run.say(line)
        done = not waiting if require_all else not unheard
        if done:
            return ready
        if run.expired():
            if require_all:
                run.say(f"gave up: not every drone became ready ({reasons(waiting)}); not sent")
                body = {"sent": False, "ready": ready, "not_ready": waiting}
                _final(run.args, None, body, EX_NOT_READY)
                return None
            return ready
        time.sleep(POLL_S)


def _follow(client: ControlClient, run: _Run, reply: dict[str, Any], kind: str) -> int:
    cid = int(reply["command_id"])
    run.sent = cid
    run.follow_from_now()
    refused = reply.get("refused") or {}
    sent_to = reply.get("ready") or []
    valid_for = reply.get("valid_for_s")
    run.say(sent_line(kind, cid, sent_to, valid_for, refused))
    follow = FollowLines()
    snap = run.snap = _as_sent(reply)
    while True:
        try:
            snap = client.request("outcomes", command_id=cid)
            run.snap = snap
        except (DaemonUnreachable, RequestError) as exc:
            # gone, or a daemon that no longer knows the command (a new life of it, or
            # the command pushed out of the ones it keeps): it was sent all the same
            return _connection_lost(run, kind, cid, snap, exc)
        # the same lines swarmctl watch prints for this command (commands_view)
        for line in follow.lines(snap, kind, expired=run.expired()):
            run.say("  " + line)
        if snap["done"] or run.expired():
            break
        time.sleep(POLL_S)
    nodes = snap["nodes"]
    ok = all(n["state"] == "completed" for n in nodes.values())
    code = EX_OK if ok else EX_FAILED
    if run.args.json:
        _final(run.args, cid, {**snap, "sent": True}, code)
    else:
        print("\n".join(render_outcomes(snap)))
        sender = sent_by_text(snap)
        if sender is not None:
            print(sender)
        unreachable = [n for n, v in nodes.items() if v["state"] == UNREACHABLE]
        print(
            f"{kind}: {sum(n['state'] == 'completed' for n in nodes.values())}/{len(nodes)} "
            + ("confirmed airborne" if kind == "takeoff" else "confirmed")
            + (
                "; no answer while valid, can no longer start there: "
                + safe_text(", ".join(unreachable))
                if unreachable
                else ""
            )
            + ("" if snap["done"] else _still_valid(snap))
        )
    return code


def _still_valid(snap: dict[str, Any]) -> str:
    """What a timed-out wait leaves open: drones that may still start the command."""
    silent = [n for n, v in snap["nodes"].items() if v["state"] == "pending"]
    left = snap.get("valid_left_s")
    if silent and isinstance(left, int | float) and left > 0:
        return (
            f" (timed out waiting for the rest; still valid for {left:g} s: "
            f"it may yet run on {safe_text(', '.join(silent))})"
        )
    return " (timed out waiting for the rest)"


def _final(args: argparse.Namespace, cid: int | None, body: dict[str, Any], code: int) -> None:
    if args.json:
        print(json.dumps({"command_id": cid, **body, "exit_code": code}, indent=2))


def sent_by_text(snap: dict[str, Any]) -> str | None:
    """``sent by USER (uid N, pid P)``: the control socket client the commander recorded
    for this command (SO_PEERCRED, docs/operations.md); None when it recorded none."""
    who = safe_tree(snap).get("sent_by")
    if not isinstance(who, dict):
        return None
    name = who.get("user") or "uid without a name"
    return f"sent by {name} (uid {who.get('uid')}, pid {who.get('pid')})"


def render_outcomes(snap: dict[str, Any]) -> list[str]:
    """The per-drone outcome table; the drones' reasons are made safe for a terminal."""
    snap = safe_tree(snap)
    rows = []
    for name, n in snap["nodes"].items():
        latency = n.get("latency_s")
        done = n.get("done_s")
        reason = reason_text(n.get("reason"))
        if n.get("after_restart"):
            reason += " [after restart]"
        if n.get("save_failed"):
            reason += " [not saved on drone]"
        if n.get("disarm_unconfirmed"):
            reason += f" [{DISARM_MARK}]"
        rows.append(
            [
                name,
                str(n["state"]).upper(),
                reason,
                "-" if latency is None else f"{latency * 1000:.0f} ms",
                "-" if done is None else f"{done:.2f} s",
            ]
        )
    return table(["DRONE", "RESULT", "REASON", "LATENCY", "DONE AFTER"], rows)
