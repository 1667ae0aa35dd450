"""``swarmctl outcomes [ID]``: what became of each command, after the fact.

``takeoff``/``land``/``hold``/``abort`` follow one command while it runs; this reads what
the daemon kept afterwards (the control request ``outcomes`` without a command id), so an
operator can answer after a flight: did every drone do what I said, and which did not.

- On the commander: the commands it issued (the last ``MAX_TRACKED_COMMANDS``, newest
  first), each with its kind, when it was issued (this host's clock, from the daemon's
  ``age_s``), who sent it (``sent_by``), its validity, and per drone its outcome and reason
  (``render_outcomes``, the table ``takeoff`` ends with), drones never reached while the
  command was valid included (``unreachable``).
- On any drone that ran commands: what it decided for each one it received, in this life of
  its daemon and, as its state file kept them, in earlier ones (``ran``, each with its
  ``life``, the state file's boot counter; the answer's ``life`` is the current one); a
  decision whose record the daemon failed to write is marked ``[not saved]``
  (``saved: false``), a failed take-off whose DISARM was never confirmed
  ``[disarm not confirmed]`` (``disarm_unconfirmed: true``): this drone may still be armed.

A member runs a command id at most once (docs/dataplane.md, "Exactly once"), so one row per
drone is the whole answer: ``completed`` is "it did it, once"; any other state is "it did
not" (or not yet: ``pending``, ``accepted``).

Exit codes (docs/operations.md, "What became of each command"): 0 every shown command was
executed by every drone it targeted; 1 a shown command has a drone that did not execute it
(refused, rejected, failed, unreachable, or not finished yet); 2 the daemon is not reachable,
cannot answer (no swarm layer), or ``ID`` is not among the commands it keeps.

Strings from other hosts (drone names, reasons) and the sender's user name are shown through
``terminal.safe_tree`` (issue 10, attack 8); ``--json`` keeps the exact values.
"""

from __future__ import annotations

import argparse
import json
import time
from collections.abc import Callable
from typing import Any, Final

from swarmd.cli.commands_view import DISARM_MARK, reason_text
from swarmd.cli.status_cmd import fail_unreachable, socket_argument, table
from swarmd.cli.takeoff_cmd import render_outcomes, sent_by_text
from swarmd.control import DaemonUnreachable, RequestError, request
from swarmd.exitcodes import EX_FAILED, EX_OK
from swarmd.swarm.commander import MAX_TRACKED_COMMANDS
from swarmd.terminal import safe_text, safe_tree

EXECUTED: Final = "completed"  # the one state that means "it did what it was told"
# A commander keeps the commands it issued in memory, for this life of its daemon only
# (``CommandTracker``); its drones keep their decisions across lives (session 17: an
# empty or unknown answer after a commander restart named nowhere else to look).
EARLIER_LIFE: Final = (
    "the commander keeps only the commands this life of its daemon issued (the last "
    f"{MAX_TRACKED_COMMANDS}); for one from before a restart, 'swarmctl outcomes' on each "
    "drone says what that drone decided"
)


def register(sub: Any) -> None:
    p = sub.add_parser(
        "outcomes",
        help="what became of each command: per drone executed, refused or unreachable",
        description="Show the commands this daemon issued (on the commander) or ran (on a "
        "drone), newest first, with each drone's outcome. Exit 0 if every drone executed "
        "every shown command, 1 if one did not, 2 if the daemon is not reachable or ID is "
        "unknown.",
    )
    p.add_argument(
        "command_id",
        nargs="?",
        type=_command_id,
        metavar="ID",
        help="one command, as swarmctl printed it (0x6b09757000000002) or in decimal",
    )
    socket_argument(p)
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=_outcomes)


def _command_id(text: str) -> int:
    try:
        value = int(text, 0)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a command id: {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"not a command id: {text!r}")
    return value


def _outcomes(args: argparse.Namespace) -> int:
    try:
        answer = request(args.socket, "outcomes")
    except (DaemonUnreachable, RequestError) as exc:
        return fail_unreachable(str(exc))
    if not isinstance(answer, dict):
        return fail_unreachable("the daemon's answer to 'outcomes' is not an object")
    shown = select(answer, args.command_id)
    if shown is None:
        return fail_unreachable(
            f"unknown command id {args.command_id:#x}: not among the commands kept here"
            + (f"; {EARLIER_LIFE}" if answer.get("role") == "commander" else "")
        )
    wall_now = time.time()
    code = exit_code(shown)
    if args.json:
        print(json.dumps(to_json(shown, wall_now, code), indent=2))
    else:
        print("\n".join(render_kept(shown, wall_now)))
    return code


def select(answer: dict[str, Any], command_id: int | None) -> dict[str, Any] | None:
    """``answer`` cut to ``command_id`` (every command when None); None when it holds no
    command of that id."""
    issued = [c for c in answer.get("issued") or [] if isinstance(c, dict)]
    ran = [c for c in answer.get("ran") or [] if isinstance(c, dict)]
    if command_id is not None:
        issued = [c for c in issued if c.get("command_id") == command_id]
        ran = [c for c in ran if c.get("command_id") == command_id]
        if not issued and not ran:
            return None
    return {**answer, "issued": issued, "ran": ran}


def not_executed(snap: dict[str, Any]) -> dict[str, Any]:
    """The drones of one issued command that did not execute it (yet), by name."""
    nodes = snap.get("nodes") or {}
    return {n: v for n, v in nodes.items() if not isinstance(v, dict) or v.get("state") != EXECUTED}


def exit_code(shown: dict[str, Any]) -> int:
    """0 when every drone executed every shown command, else 1 (``EX_FAILED``)."""
    failed = any(not_executed(c) for c in shown["issued"]) or any(
        c.get("state") != EXECUTED for c in shown["ran"]
    )
    return EX_FAILED if failed else EX_OK


def _issued_at(age_s: Any, wall_now: float) -> float | None:
    if isinstance(age_s, bool) or not isinstance(age_s, int | float):
        return None
    return wall_now - age_s


def _wall(
    at: float | None, convert: Callable[[float], time.struct_time]
) -> time.struct_time | None:
    """``at`` as a calendar time, or None when it is none: a hand-edited state file's
    decision time is any finite number (``statefile._decision``), and one past the C
    library's range made ``gmtime``/``localtime`` raise, ending the view (review 14)."""
    if at is None:
        return None
    try:
        return convert(at)
    except (OverflowError, OSError, ValueError):
        return None


def _iso(at: float | None) -> str | None:
    wall = _wall(at, time.gmtime)
    return None if wall is None else time.strftime("%Y-%m-%dT%H:%M:%SZ", wall)


def to_json(shown: dict[str, Any], wall_now: float, code: int) -> dict[str, Any]:
    """``--json``: the daemon's answer with exact values, plus ``issued_at``/``received_at``
    (UTC, this host's clock less the daemon's ``age_s``) and the ``exit_code``."""
    issued = [
        {**c, "issued_at": _iso(_issued_at(c.get("age_s"), wall_now))} for c in shown["issued"]
    ]
    ran = [{**c, "received_at": _iso(_issued_at(c.get("age_s"), wall_now))} for c in shown["ran"]]
    return {**shown, "issued": issued, "ran": ran, "exit_code": code}


def _clock(age_s: Any, wall_now: float) -> str:
    wall = _wall(_issued_at(age_s, wall_now), time.localtime)
    if wall is None:
        return "--:--:--"
    return time.strftime("%H:%M:%S", wall) + f" ({float(age_s):.0f} s ago)"


def _cid(value: Any) -> str:
    return f"{value:#x}" if isinstance(value, int) and not isinstance(value, bool) else "?"


def render_kept(shown: dict[str, Any], wall_now: float) -> list[str]:
    """The human view. Our own lines are built from a safe copy; ``render_outcomes`` and
    ``sent_by_text`` get the raw command, as they make it safe themselves (made safe twice,
    a backslash would show doubled twice)."""
    lines: list[str] = []
    for raw in shown["issued"]:
        if lines:
            lines.append("")  # one block per command
        c = safe_tree(raw)
        valid = c.get("valid_for_s")
        header = f"{str(c.get('kind', '?')).upper()} {_cid(c.get('command_id'))}  issued "
        header += _clock(c.get("age_s"), wall_now)
        if isinstance(valid, int | float) and not isinstance(valid, bool):
            header += f"  valid for {valid:g} s"
        if c.get("altitude_m") is not None:
            header += f"  altitude {c['altitude_m']:g} m"
        lines.append(header)
        lines.append("  " + (sent_by_text(raw) or "sent by - (no control socket client)"))
        lines += render_outcomes(raw)
        lines.append("  " + _summary(c))
    if shown["issued"] and shown["ran"]:
        lines.append("")
    ran = [safe_tree(r) for r in shown["ran"]]
    if ran:
        life = shown.get("life")
        lines.append(f"commands this drone received ({len(ran)}, this life and earlier ones):")
        rows = [
            [
                _cid(r.get("command_id")),
                str(r.get("kind", "?")).upper(),
                str(r.get("commander", "?")),
                str(r.get("state", "?")).upper(),
                reason_text(r.get("reason"))
                + ("" if r.get("saved", True) else " [not saved]")
                + (f" [{DISARM_MARK}]" if r.get("disarm_unconfirmed") else ""),
                _clock(r.get("age_s"), wall_now),
                _life(r.get("life"), life),
            ]
            for r in ran
        ]
        lines += table(["ID", "KIND", "FROM", "RESULT", "REASON", "RECEIVED", "LIFE"], rows)
    role = str(shown.get("role", "?"))
    if not lines:
        lines.append(f"no commands kept here (role {safe_text(role)})")
    if role == "commander" and not shown["issued"]:
        lines.append(EARLIER_LIFE[0].upper() + EARLIER_LIFE[1:])
    return lines


def _life(life: Any, current: Any) -> str:
    """Which life of the drone's daemon decided it: the state file's boot counter."""
    if isinstance(life, bool) or not isinstance(life, int):
        return "?"
    return f"{life} (this)" if life == current else f"{life} (earlier)"


def _summary(c: dict[str, Any]) -> str:
    """``3/4 executed; not reported executed: uav3 (unreachable: not_reached_while_valid)``:
    a drone with no answer (unreachable, pending) may still have run it (docs/operations.md)."""
    nodes = c.get("nodes") or {}
    missing = not_executed(c)
    line = f"{len(nodes) - len(missing)}/{len(nodes)} executed"
    if missing:
        why = [
            f"{name} ({v.get('state', '?')}"
            + (f": {reason_text(v['reason'])}" if v.get("reason") else "")
            + ")"
            if isinstance(v, dict)
            else name
            for name, v in missing.items()
        ]
        line += "; not reported executed: " + ", ".join(why)
    if not c.get("done", True):
        left = c.get("valid_left_s")
        line += " (still open" + (
            f"; valid for {left:g} s more)" if isinstance(left, int | float) and left else ")"
        )
    return line
