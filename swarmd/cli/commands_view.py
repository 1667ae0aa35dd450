"""Commands in the operator's views: what ``swarmctl takeoff`` follows, ``swarmctl watch``
prints, and ``swarmctl status`` lists (docs/operations.md, "Commands in status and watch").

Pure: a status object or an outcome snapshot in, lines out. One set of event lines
(``FollowLines``) serves the take-off follow and ``watch``, so the operator reads the same
words for the same drone wherever they look. Lines built here carry peer strings (drone
names, reasons) as they came: ``takeoff`` and ``watch`` pass each line through
``terminal.safe_text``, and ``render_commands`` is given a status already made safe
(``status_cmd.render_status``), as every remote string is data (issue 10, attack 8).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any, Final

from swarmd.dataplane.validity import MEMORY_LOST
from swarmd.px4.actions import SUPERSEDED
from swarmd.swarm.commander import RESTARTED, RESTARTED_RUNNING, UNREACHABLE

# ``swarmctl status``: at most this many commands (newest first) and names per group; the
# rest is counted ("+N more") and ``swarmctl outcomes`` shows every one. A swarm of tens of
# drones with one lost would otherwise push the discovery part off the screen.
COMMANDS_SHOWN: Final = 3
NAMES_SHOWN: Final = 4
# The order the per-state counts are listed in: settled and good first, then the rest.
STATE_ORDER: Final = (
    "completed", "accepted", "pending", "unreachable", "refused", "rejected", "failed"
)  # fmt: skip
# The groups a status names, drone by drone: the ones an operator has to act on or wait
# for (docs/operations.md, "What swarmctl tells you about a command").
NAMED: Final = (
    ("pending", "no answer yet"),
    ("unreachable", "unreachable"),
    ("refused", "refused"),
    ("rejected", "rejected"),
    ("failed", "failed"),
)

# the mark of a row whose failed take-off's DISARM was never confirmed (``disarm_unconfirmed``
# in --json; docs/operations.md, "What swarmctl tells you about a command")
DISARM_MARK: Final = "disarm not confirmed"


def superseded_by(reason: object) -> str | None:
    """``LAND`` for the reason ``superseded: land``: a later LAND, HOLD or ABORT took the
    vehicle over from this command's task (docs/px4.md, "Two requests, one vehicle")."""
    if not isinstance(reason, str):
        return None
    code, sep, later = reason.partition(":")
    if code != SUPERSEDED or not sep or not later.strip():
        return None
    return later.strip().upper()


def reason_text(reason: object) -> str:
    """A drone's reason code as a table cell: the code itself, but ``superseded by LAND``
    for ``superseded: land``; JSON keeps the exact code."""
    later = superseded_by(reason)
    return str(reason or "-") if later is None else f"{SUPERSEDED} by {later}"


def _cid(value: object) -> str:
    return f"{value:#x}" if isinstance(value, int) and not isinstance(value, bool) else "?"


def _number(value: object) -> float | None:
    return float(value) if isinstance(value, int | float) and not isinstance(value, bool) else None


def _seconds(value: object) -> str:
    number = _number(value)
    return "its validity" if number is None else f"{number:g} s"


def sent_line(
    kind: str, command_id: object, sent_to: Sequence[str], valid_for: object,
    refused: Mapping[str, object],
) -> str:  # fmt: skip
    """``TAKEOFF command 0x... sent to 2 drone(s): uav1, uav2; valid for 3 s; refused:
    uav3 (no_report)``: the take-off's line at the send, and ``watch``'s for a new one."""
    valid = _number(valid_for)
    return (
        f"{kind.upper()} command {_cid(command_id)} sent to {len(sent_to)} drone(s): "
        + ", ".join(sent_to)
        + (f"; valid for {valid:g} s" if valid is not None else "")
        + (f"; refused: {reasons(refused)}" if refused else "")
    )


def reasons(by_name: Mapping[str, object]) -> str:
    """``uav3 (no_report), uav4 (no_3d_fix)``, or ``-`` for none."""
    return ", ".join(f"{n} ({r})" for n, r in by_name.items()) or "-"


class FollowLines:
    """What has been said about one command's drones, so each change is said once: a
    verdict (``pending`` is not one), a ``[not saved on drone]`` mark and its clearing, a
    task whose drone restarted with nothing to re-report. ``lines`` takes each new outcome
    snapshot (``outcomes`` with a ``command_id``, or one entry of status ``commands``)."""

    def __init__(self) -> None:
        self.seen: dict[str, str] = {}
        self.told_not_saved: set[str] = set()
        self.ended: set[str] = set()  # accepted, then its life ended with nothing re-reported
        self.told_armed: set[str] = set()  # a failed take-off's DISARM not confirmed (once)

    def lines(self, snap: Mapping[str, Any], kind: str, *, expired: bool = False) -> list[str]:
        """The lines ``snap`` adds (``uav1: accepted after 0.012 s``); ``expired``: the
        follow gave up waiting, so an unsettled row is as settled as it will get."""
        out: list[str] = []
        cid = _cid(snap.get("command_id"))
        nodes = snap.get("nodes")
        for name, node in (nodes if isinstance(nodes, dict) else {}).items():
            if isinstance(node, dict):
                out += self._node(str(name), node, snap, kind, cid, expired)
        return out

    def _node(
        self, name: str, node: Mapping[str, Any], snap: Mapping[str, Any], kind: str, cid: str,
        expired: bool,
    ) -> list[str]:  # fmt: skip
        out: list[str] = []
        if node.get("save_failed") and name not in self.told_not_saved:
            self.told_not_saved.add(name)  # docs/operations.md, "state_save_failed"
            out.append(
                f"{name}: its daemon could not write its record of this command to its state "
                "file (the command still runs there; after a restart it will not re-report "
                "this answer)"
            )
        elif not node.get("save_failed") and name in self.told_not_saved:
            self.told_not_saved.discard(name)  # a later write held it (session 15)
            out.append(f"{name}: its daemon wrote its record of this command after all")
        state = str(node.get("state"))
        if (
            state == "accepted"
            and node.get("reason") == RESTARTED_RUNNING
            and not node.get("after_restart")
            and name not in self.ended
            # only once the row is settled: until its grace is over the new life's
            # re-report of what the earlier one decided (a COMPLETED among them) may still
            # be under repair, and "no completion will come" would be false
            # (docs/dataplane.md, "Outcomes across a restart"; review 15)
            and (snap.get("done") or expired)
        ):
            self.ended.add(name)  # docs/dataplane.md, "Outcomes across a restart"
            out.append(
                f"{name}: its daemon restarted before the task ended, with no record of it "
                "to re-report: no completion will come (its readiness shows what the "
                "vehicle did)"
            )
        if self.seen.get(name) != state and state != "pending":
            self.seen[name] = state
            out.append(self._verdict(name, state, node, snap, kind, cid))
        if node.get("disarm_unconfirmed") and name not in self.told_armed:
            # after its failure line: the amendment comes up to 2 s later (docs/px4.md,
            # "A failed take-off's DISARM")
            self.told_armed.add(name)
            out.append(
                f"{name}: {DISARM_MARK}: the failed take-off's DISARM was never confirmed; "
                f"the vehicle may still be armed (on the ground, props maybe spinning, or in "
                f"the air): check it (swarmctl status) and send 'swarmctl abort --only {name}'"
            )
        return out

    @staticmethod
    def _verdict(
        name: str, state: str, node: Mapping[str, Any], snap: Mapping[str, Any], kind: str,
        cid: str,
    ) -> str:  # fmt: skip
        reason = node.get("reason")
        if state == UNREACHABLE and reason == RESTARTED:
            return (
                f"{name}: unreachable: it restarted before it acknowledged the command, which "
                "is not sent to its new life and can no longer run there (its readiness "
                "shows what the vehicle did)"
            )
        if state == "rejected" and reason == MEMORY_LOST:
            # docs/operations.md, "memory_lost"
            return (
                f"{name}: refused (memory_lost): its daemon restarted without its record of "
                "the commands it ran, and this one was issued before; it may have run it "
                "then (its readiness shows what the vehicle did). Issue a new command to "
                "run it now"
            )
        if state == UNREACHABLE:
            # no answer is all the commander knows: the drone may have run it and its
            # answers been lost since (session 16 command review)
            return (
                f"{name}: unreachable: no answer while the command was valid "
                f"({_seconds(snap.get('valid_for_s'))}); it can no longer start there, and "
                f"if it did start, its answer is late (swarmctl outcomes {cid})"
            )
        extra = f" ({reason_text(reason)})" if reason else ""
        at = _number(node.get("done_s"))
        at = _number(node.get("latency_s")) if at is None else at
        when = f" after {at:.3f} s" if at is not None else ""
        if node.get("after_restart"):
            # docs/dataplane.md, "Outcomes across a restart"
            when += ", told by the drone after its daemon restarted"
        later = superseded_by(reason)
        if later is not None:
            # docs/px4.md, "Two requests, one vehicle"
            return (
                f"{name}: {state}: superseded on the drone by a later {later}; this "
                f"{kind.upper()} stopped there and sent nothing more{when}"
            )
        return f"{name}: {state}{extra}{when}"


class CommandWatch:
    """``swarmctl watch``'s command events: a line when a command appears in the status
    (sent since the watch began) and each ``FollowLines`` line for it, and on a drone a
    line when the command its vehicle runs changes (session 18). The first status
    primes it: what the screen already shows is not news. Bounded: a command that leaves
    the status's list (the commander keeps the last 8 there) is forgotten."""

    def __init__(self) -> None:
        self._follow: dict[object, FollowLines] | None = None
        # the drone's running commands (executor), each "KIND 0x... from NODE", as last seen
        self._running: list[str] | None = None

    def update(self, status: Mapping[str, Any]) -> list[str]:
        return self._commands(status) + self._runs(status)

    def _runs(self, status: Mapping[str, Any]) -> list[str]:
        """A line when the command this drone's vehicle runs changes (the ``running now:``
        line of ``status``): one starts, one ends. The first frame primes it."""
        executor = status.get("executor")
        if not isinstance(executor, dict):
            return []
        tasks = [t for t in executor.get("commands") or [] if isinstance(t, dict)]
        now = [
            f"{str(t.get('kind', '?')).upper()} {_cid(t.get('command_id'))} "
            f"from {t.get('commander', '?')}"
            for t in tasks
        ]
        before, self._running = self._running, now
        if before is None:
            return []
        return [f"running now: {c}" for c in now if c not in before] + [
            f"no longer running: {c}" for c in before if c not in now
        ]

    def _commands(self, status: Mapping[str, Any]) -> list[str]:
        commands = [c for c in status.get("commands") or [] if isinstance(c, dict)]
        first, known = self._follow is None, self._follow or {}
        self._follow = {}
        out: list[str] = []
        for c in commands:
            key, kind = c.get("command_id"), str(c.get("kind", "?"))
            follow = known.get(key)
            lines: list[str] = []
            if follow is None:
                follow = FollowLines()
                if not first:
                    nodes = c.get("nodes")
                    nodes = nodes if isinstance(nodes, dict) else {}
                    refused = {n: v.get("reason") for n, v in nodes.items()
                               if isinstance(v, dict) and v.get("state") == "refused"}  # fmt: skip
                    sent_to = [str(n) for n in nodes if n not in refused]
                    lines.append(sent_line(kind, key, sent_to, c.get("valid_for_s"), refused))
            self._follow[key] = follow
            events = follow.lines(c, kind)
            if not first:
                lines += [f"{kind.upper()} {_cid(key)}: {e}" for e in events]
                out += lines
        return out


def render_commands(status: Mapping[str, Any]) -> list[str]:
    """``swarmctl status``'s commands part: on the commander the last commands it sent,
    newest first (``COMMANDS_SHOWN``, then "+N more"); on any node with a vehicle task,
    the command it runs now. ``status`` is already made safe for a terminal."""
    lines: list[str] = []
    commands = [c for c in status.get("commands") or [] if isinstance(c, dict)]
    if status.get("role") == "commander":
        if not commands:
            # a commander keeps only this life's commands (outcomes_cmd.EARLIER_LIFE)
            lines.append(
                "commands sent: none since this daemon started (one sent before a restart: "
                "'swarmctl outcomes' on each drone)"
            )
        else:
            lines.append("commands sent, newest first (every drone of one: swarmctl outcomes ID):")
        for c in reversed(commands[-COMMANDS_SHOWN:]):
            lines += ["  " + ln for ln in _command(c)]
        if len(commands) > COMMANDS_SHOWN:
            lines.append(f"  +{len(commands) - COMMANDS_SHOWN} earlier: swarmctl outcomes")
    executor = status.get("executor")
    if isinstance(executor, dict):
        lines += _running(executor, status.get("role") == "commander")
    return lines


def _command(c: Mapping[str, Any]) -> list[str]:
    """``TAKEOFF 0x...  sent 4.0 s ago  valid for 3 s, open: may still start for 0.4 s``, the
    counts per state, then the drones an operator acts on or waits for, by group."""
    cid = _cid(c.get("command_id"))
    head = f"{str(c.get('kind', '?')).upper()} {cid}"
    age, valid, left = (_number(c.get(k)) for k in ("age_s", "valid_for_s", "valid_left_s"))
    if age is not None:
        head += f"  sent {age:.1f} s ago"
    if valid is not None:
        head += f"  valid for {valid:g} s"
    if c.get("done"):
        head += ", done"
    elif left:
        head += f", open: may still start for {left:.1f} s"
    else:
        head += ", open: waiting for answers"
    nodes = {n: v for n, v in (c.get("nodes") or {}).items() if isinstance(v, dict)}
    counts: dict[str, int] = {}
    for v in nodes.values():
        counts[str(v.get("state"))] = counts.get(str(v.get("state")), 0) + 1
    order = [s for s in STATE_ORDER if s in counts] + sorted(set(counts) - set(STATE_ORDER))
    lines = [head, "  " + (", ".join(f"{s} {counts[s]}" for s in order) or "no drones")]
    for state, label in NAMED:
        group = [(n, v) for n, v in nodes.items() if v.get("state") == state]
        if group:
            cells = [n + (f" ({reason_text(v['reason'])})" if v.get("reason") else "")
                     for n, v in group]  # fmt: skip
            lines.append(f"  {label}: {_bounded(cells, cid)}")
    unsaved = [n for n, v in nodes.items() if v.get("save_failed")]
    if unsaved:
        lines.append(f"  [not saved on drone]: {_bounded(unsaved, cid)}")
    armed = [n for n, v in nodes.items() if v.get("disarm_unconfirmed")]
    if armed:
        lines.append(f"  [{DISARM_MARK}], may still be armed: {_bounded(armed, cid)}")
    return lines


def _bounded(cells: Sequence[str], cid: str) -> str:
    shown = ", ".join(cells[:NAMES_SHOWN])
    more = len(cells) - NAMES_SHOWN
    return shown + (f", +{more} more (swarmctl outcomes {cid})" if more > 0 else "")


def _running(executor: Mapping[str, Any], commander: bool) -> list[str]:
    """``running now: LAND 0x... from lead, received 2.0 s ago``; on a member with none,
    ``running now: no command`` (the commander says nothing: it may have no vehicle)."""
    tasks = [t for t in executor.get("commands") or [] if isinstance(t, dict)]
    if not tasks:
        return [] if commander else ["running now: no command"]
    cells = []
    for t in tasks:
        cell = f"{str(t.get('kind', '?')).upper()} {_cid(t.get('command_id'))}"
        cell += f" from {t.get('commander', '?')}"
        age = _number(t.get("age_s"))
        if age is not None:
            cell += f", received {age:.1f} s ago"
        if t.get("saved") is False:
            cell += " [not saved]"
        cells.append(cell)
    return ["running now: " + "; ".join(cells)]
