"""What a node keeps across restarts: its boot counter and the commands it executed.

One small JSON file per node in the state directory (``dataplane.state_dir``, systemd's
``StateDirectory=swarmd`` = ``/var/lib/swarmd``), named after the node so co-hosted daemons
(tests, a ground station running several participants) never share one::

    {"boot": 7, "executed": [["lead", 30064771073], ...],
     "outcomes": [["lead", 30064771073, 1, "IN_AIR"], ...],
     "decisions": [[6, "lead", 30064771073, "takeoff", "completed", "IN_AIR",
                    1795797000.25, 4.1], ...],
     "told_unsaved": [["lead", 30064771073]],
     "disarm_unconfirmed": [["lead", 30064771074]]}

Why: the data plane's exactly-once argument (docs/dataplane.md, "Exactly once") needs an
``incarnation`` that grows with every restart (sequence numbers and command ids of a
restarted commander stay above its earlier lives), and a member that restarts must not
execute again a command the commander still holds in its history. The executed ids are
written *before* the command reaches the autopilot (write-ahead): a crash between the two
loses a command, never repeats one — for a take-off, the safe side. Each outcome decided
for an executed id (commander, id, ``CommandResult`` value, reason) is written after the
decision, in ``outcomes`` (a second write; the write-ahead of the id is unchanged), so a
restarted member can re-report it (docs/dataplane.md, "Outcomes across a restart"). A file
without ``outcomes`` (written before they were kept) loads with none; a daemon that does
not know the key ignores it. An unreadable ``outcomes`` list is dropped alone: the ids,
which exactly-once depends on, are kept. ``decisions`` is the member's ``DecisionLog``
(``swarm.commander.KeptDecision``: life, commander, id, kind, state, reason, when received
in Unix seconds, how long the final answer took), so ``swarmctl outcomes`` in a later life
lists what the earlier ones decided, with kind and time; at most ``MAX_DECIDED_COMMANDS``
(64) entries over all lives, the newest. ``told_unsaved`` ([commander, id] pairs, one per
kept decision at most) names the decisions whose commander was told their record was not
saved, so a later life that holds their final answer says it is (docs/dataplane.md, "A
clear lost to a restart"); at load an entry naming no kept decision, or of another
shape, is left out alone. Same compatibility: a file without it loads with
none, an unreadable list is dropped alone. ``disarm_unconfirmed`` ([commander, id] pairs,
at most ``MAX_DISARM_MARKS``, the newest) names the failed take-offs whose DISARM was never
confirmed, so a later life's re-report of that FAILED still says the vehicle may be armed
(docs/dataplane.md, "Outcomes across a restart"); at load an entry naming no kept FAILED
outcome, or of another shape, is left out alone (a mark can only ride on a re-report of
one), the same compatibility as ``told_unsaved``. A decision whose time cannot be right (NaN,
infinite, negative, or later than the wall clock at load by more than
``DECISION_CLOCK_SLACK_S``; its answer likewise) is dropped alone and counted
(``decisions_dropped``), the rest kept; its (commander, id), when well formed, stays in
``executed`` (added if missing, ``decision_ids_kept``): the time is wrong, the id is right,
and exactly once rests on the id (docs/dataplane.md, "Exactly once" 3).

Writes are atomic (temporary file, fsync, rename), so a power cut leaves the old or the new
file, never half of one. ``boot``'s write is made at start-up, before anything is sent; the
running daemon's run on its writer thread (``encode`` on the loop, ``write`` on the thread:
``swarmd.filewriter``), so a slow SD card's fsync never stalls the loop. A crash mid-write
leaves the temporary file (``.<file>.tmp-<16 hex>``); ``boot`` removes this node's before
it loads (``remove_left_temps``: regular files of this daemon's uid, symlinks never
followed), counted in ``temps_removed``.

The directory must be writable by this daemon's user alone (or root): start-up refuses one
others can write, whose files another user could have planted (docs/security-history.md,
"Local boundaries (session 10 review)"). An unreadable or corrupt file is reported and
replaced (refusing to start would ground the drone): the dedup set is lost, and exactly once
then rests on the member's own rule that a life runs only commands issued after it began
(docs/dataplane.md, "A life runs only its own commands"), which holds with or without this
file.
"""

from __future__ import annotations

import json
import math
import os
import stat
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Final, TypeGuard

from swarmd.bundle.keys import (
    node_state_path,
    open_state_dir,
    refuse_shared_dir,
    remove_left_temps,
    write_file_atomic,
)
from swarmd.bundle.safeopen import (
    STATE_FILE_CAP,
    Folder,
    held,
    open_folder,
    read_file,
    unreadable_why,
    write_atomic,
)
from swarmd.bundle.statedir import DaemonUser, refuse_unwritable_dir
from swarmd.dataplane.ledger import KeptOutcome
from swarmd.dataplane.types import MAX_NAME_CHARS, MAX_REASON_CHARS, CommandResult
from swarmd.dataplane.writer import MAX_INCARNATION
from swarmd.swarm.commander import MAX_DECIDED_COMMANDS, MAX_DISARM_MARKS, KeptDecision

FILE_PATTERN: Final = "dataplane-{node}.json"
# How far past this life's wall clock a kept decision's time (or its answer's) may lie and
# still be believed. An earlier life wrote it by time.time(); a board without a real-time
# clock boots with its clock behind (systemd-timesyncd restores the last saved time, and
# NTP steps it forward again), by minutes to hours. A day covers that; beyond it the time
# is not a clock's (a hand edit, a bad disk, 1e300) and the entry is dropped at load.
DECISION_CLOCK_SLACK_S: Final = 86_400.0
STATE_FILE_MODE: Final = 0o640  # what UMask=0027 made of open(..., "w"): the group reads


class StateDirError(OSError):
    """The state directory cannot be created or written; ``str()`` is one line."""


@dataclass(slots=True)
class NodeState:
    """The persisted state of one node, and where it lives."""

    path: Path
    boot: int = 0
    executed: list[tuple[str, int]] = field(default_factory=list)
    outcomes: list[KeptOutcome] = field(default_factory=list)
    # received_at in Unix seconds (wall clock: the only one two lives share)
    decisions: list[KeptDecision] = field(default_factory=list)
    # (commander, id) of kept decisions whose commander was told they were not saved: the
    # next life says they are (``swarm.commander.DecisionLog.told_unsaved``)
    told_unsaved: list[tuple[str, int]] = field(default_factory=list)
    # (commander, id) of the kept FAILED take-offs whose DISARM was never confirmed: the
    # next life re-reports them flagged so (``swarm.member.Member.rereport``)
    disarm_unconfirmed: list[tuple[str, int]] = field(default_factory=list)
    recovered_from: str | None = None  # why an unreadable file was replaced, for the log
    temps_removed: int = 0  # left-over temporary files removed at boot, for the log
    # no file was there: a first boot, or a deleted file (the caller knows which: the boot
    # epoch says whether this node started before, swarmapp_saves.StateSaves._boot_dataplane)
    missing: bool = False
    # kept decisions dropped at load for a time that cannot be right (``load``), the first
    # one's problem, and how many of their ids were missing from ``executed`` and added
    decisions_dropped: int = 0
    decisions_problem: str | None = None
    decision_ids_kept: int = 0
    # the state folder as ``boot`` opened and judged it: every save goes through it
    folder: Folder | None = field(default=None, compare=False, repr=False)

    def save(self) -> None:
        """Write atomically, here and now; raises ``StateDirError`` (one line) on failure.
        ``boot`` calls it before anything is sent; the running daemon instead encodes on
        its loop (``encode``) and writes on its writer thread (``write``,
        ``swarmd.filewriter``)."""
        self.write(self.encode())

    def encode(self) -> bytes:
        """The file's bytes for the state held now (a snapshot: later changes are not in it)."""
        body: dict[str, object] = {
            "boot": self.boot,
            "executed": [[c, i] for c, i in self.executed],
        }
        if self.outcomes:  # without any, the file stays as it was before they were kept
            body["outcomes"] = [list(kept) for kept in self.outcomes]
        if self.decisions:  # the same: without any, as before they were kept
            body["decisions"] = [list(kept) for kept in self.decisions[-MAX_DECIDED_COMMANDS:]]
        if self.told_unsaved:  # the same
            body["told_unsaved"] = [[c, i] for c, i in self.told_unsaved[-MAX_DECIDED_COMMANDS:]]
        if self.disarm_unconfirmed:  # the same
            marks = self.disarm_unconfirmed[-MAX_DISARM_MARKS:]
            body["disarm_unconfirmed"] = [[c, i] for c, i in marks]
        return json.dumps(body, separators=(",", ":")).encode("utf-8")

    def write(self, data: bytes) -> None:
        """Replace the file with ``data`` (``encode``'s) atomically; blocking (two fsyncs),
        safe on another thread (it reads only ``path`` and ``folder``, fixed at ``boot``).
        Raises ``StateDirError`` (one line) on failure."""
        try:
            # a random O_EXCL|O_NOFOLLOW temp name: a symlink planted at the old fixed
            # "<file>.tmp" made this write go through to its target (session 10 review);
            # through the folder ``boot`` judged, whatever its path names now (safeopen)
            if self.folder is not None:
                write_atomic(self.folder, self.path.name, data, STATE_FILE_MODE)
            else:
                write_file_atomic(self.path, data, STATE_FILE_MODE)
        except OSError as exc:
            raise StateDirError(f"cannot write {self.path}: {exc.strerror}") from None


def state_path(state_dir: str | Path, node: str) -> Path:
    return node_state_path(state_dir, FILE_PATTERN, node)


def check_dir(state_dir: str | Path, user: DaemonUser) -> Path:
    """The state directory, refused (``StateDirError``, one line) when another user could
    write it or ``user`` (the daemon's) could not create or write it. Reads only."""
    directory = Path(state_dir)
    with held(_judged_dir(directory, user)):
        return directory


def _judged_dir(directory: Path, user: DaemonUser) -> Folder | None:
    """``directory`` opened and judged on its descriptor (``safeopen``: what is judged is
    what is read and written); None when it does not exist yet. The caller closes it."""
    folder = open_state_dir(directory, "dataplane.state_dir", StateDirError)
    try:
        refuse_shared_dir(
            folder, "dataplane.state_dir", StateDirError, user.trusted_owners(directory)
        )
        refuse_unwritable_dir(directory, "dataplane.state_dir", StateDirError, user)
    except BaseException:
        if folder is not None:
            folder.close()
        raise
    return folder


def preview(
    state_dir: str | Path, node: str, user: DaemonUser, *, wall_now: float | None = None
) -> NodeState:
    """What ``boot`` would load and count, by reading only: the folder checked
    (``check_dir``), the file loaded as ``boot`` loads it, the boot counted in memory. It
    never creates the folder, removes a temporary file or writes the state file
    (``swarmd check-config``, docs/operations.md). ``wall_now``: the wall clock decision
    times are judged against (None: ``time.time()``). Raises ``StateDirError``."""
    directory = Path(state_dir)
    with held(_judged_dir(directory, user)) as folder:
        owners = user.trusted_owners(directory)
        return _counted(folder, state_path(directory, node), wall_now, owners)


def _counted(
    folder: Folder | None, path: Path, wall_now: float | None, also: frozenset[int]
) -> NodeState:
    """The state in ``folder`` (None: not there yet) with this boot counted, in memory;
    ``also``: the file's owners trusted beside root and swarmd (the daemon's)."""
    if folder is None:
        state = NodeState(path, missing=True)
    else:
        try:
            info = os.stat(path.name, dir_fd=folder.fd, follow_symlinks=False)
        except FileNotFoundError:
            info = None
        if info is not None and stat.S_ISDIR(info.st_mode):
            # the atomic write renames over it, and a rename cannot replace a folder
            raise StateDirError(f"cannot write {path}: it is a folder; fix: remove it")
        state = load(path, wall_now, folder, also)
    state.boot = _next_boot(state.boot)
    return state


def _next_boot(count: int) -> int:
    # wraps long after any drone's life (2^31 boots); 0 stays "never persisted"
    return count + 1 if count < MAX_INCARNATION else 1


def boot(
    state_dir: str | Path,
    node: str,
    user: DaemonUser | None = None,
    *,
    wall_now: float | None = None,
) -> NodeState:
    """Load the node's state, count this boot and save it before anything is sent;
    ``user``: whose writes are judged (None: this process's); ``wall_now``: as ``preview``.
    The folder is judged, the file read and every later save written through one
    descriptor of it (``safeopen``), kept in ``NodeState.folder``.

    Raises ``StateDirError`` when the directory cannot be created or written.
    """
    wall_now = time.time() if wall_now is None else wall_now
    who = user if user is not None else DaemonUser.this_process()
    planned = preview(state_dir, node, who, wall_now=wall_now)  # refusals before any write
    directory = planned.path.parent
    try:
        directory.mkdir(parents=True, exist_ok=True, mode=0o750)
    except OSError as exc:
        raise StateDirError(f"cannot create state directory {directory}: {exc.strerror}") from None
    folder = _judged_dir(Path(state_dir), who)  # judged again: new, or swapped since
    if folder is None:
        raise StateDirError(f"cannot create state directory {directory}: it vanished")
    try:
        # a crash inside write_atomic leaves its temporary file (tests/test_cmd_state_kill.py)
        removed = remove_left_temps(planned.path, folder)
        state = _counted(folder, planned.path, wall_now, who.trusted_owners(directory))
        state.temps_removed = removed
        state.folder = folder
        state.save()
    except BaseException:
        folder.close()
        raise
    return state


def load(
    path: Path,
    wall_now: float | None = None,
    folder: Folder | None = None,
    also: frozenset[int] = frozenset(),
) -> NodeState:
    """The state at ``path``; a missing file starts afresh (``missing``), a corrupt one is
    replaced. ``wall_now``: the wall clock (Unix seconds) the kept decisions' times are
    judged against (``DECISION_CLOCK_SLACK_S``; None: ``time.time()``). ``folder``:
    ``path``'s folder as judged, read through (``safeopen``; None: opened here). A symlink,
    a FIFO, a file of another owner (than root, swarmd, ``also``) or one over
    ``STATE_FILE_CAP`` is unreadable."""
    wall_now = time.time() if wall_now is None else wall_now
    opened = folder if folder is not None else open_folder(path.parent)
    if opened is None:
        return NodeState(path, missing=True)
    try:
        raw = read_file(opened, path.name, STATE_FILE_CAP, also=also).decode("utf-8")
    except FileNotFoundError:
        return NodeState(path, missing=True)
    except OSError as exc:
        return NodeState(path, recovered_from=f"unreadable ({unreadable_why(exc)})")
    except UnicodeDecodeError as exc:
        return NodeState(path, recovered_from=f"unreadable ({exc})")
    finally:
        if folder is None:
            opened.close()
    try:
        body = json.loads(raw)
        boot_count = body["boot"]
        executed = [(str(c), int(i)) for c, i in body["executed"]]
        if not isinstance(boot_count, int) or not 0 <= boot_count <= MAX_INCARNATION:
            raise ValueError(f"boot {boot_count!r} out of range")
    except (ValueError, KeyError, TypeError) as exc:
        return NodeState(path, recovered_from=f"corrupt ({type(exc).__name__}: {exc})")
    try:
        outcomes = [_outcome(kept) for kept in body.get("outcomes", [])]
    except (ValueError, TypeError) as exc:  # the ids stand; only the answers are lost
        why = f"outcomes dropped ({type(exc).__name__}: {exc})"
        return NodeState(path, boot_count, executed, recovered_from=why)
    try:
        raw_decisions = body.get("decisions", [])
        if not isinstance(raw_decisions, list):
            raise TypeError("decisions is not a list")
        read = [_decision(kept) for kept in raw_decisions[-MAX_DECIDED_COMMANDS:]]
    except (ValueError, TypeError) as exc:  # the ids and answers stand; only the view is lost
        why = f"decisions dropped ({type(exc).__name__}: {exc})"
        return NodeState(path, boot_count, executed, outcomes, recovered_from=why)
    state = NodeState(path, boot_count, executed, outcomes)
    known = set(executed)
    for decision in read:
        problem = _time_problem(decision, wall_now)
        if problem is None:
            state.decisions.append(decision)
            continue
        state.decisions_dropped += 1
        if state.decisions_problem is None:
            state.decisions_problem = problem
        key = (decision.commander, decision.command_id)
        if key not in known:
            # the entry's time is wrong, its id is not: a command this node decided (the
            # id was written ahead of it) must never run again (docs/dataplane.md,
            # "Exactly once" 3), so the id is kept where the plane's dedup reads it
            known.add(key)
            state.executed.append(key)
            state.decision_ids_kept += 1
    kept = {(d.commander, d.command_id) for d in state.decisions}
    state.told_unsaved = _pairs(body.get("told_unsaved"), kept, MAX_DECIDED_COMMANDS)
    failed = {(c, i) for c, i, result, _ in outcomes if result == CommandResult.FAILED.value}
    state.disarm_unconfirmed = _pairs(body.get("disarm_unconfirmed"), failed, MAX_DISARM_MARKS)
    return state


def _pairs(raw: object, known: set[tuple[str, int]], cap: int) -> list[tuple[str, int]]:
    """A list of [commander, id] pairs from the file (``told_unsaved``,
    ``disarm_unconfirmed``): the last ``cap`` entries read, each kept once if it names one
    of ``known`` (a kept decision; a kept FAILED outcome); anything else (not a list, an
    entry of another shape, a pair not known or dropped at load) is left out. Nothing here
    refuses the file: leaving out a ``told_unsaved`` entry keeps a commander's mark
    standing (the alarm side); a ``disarm_unconfirmed`` entry left out names no outcome a
    re-report could carry."""
    if not isinstance(raw, list):
        return []
    pairs: list[tuple[str, int]] = []
    for entry in raw[-cap:]:
        if not isinstance(entry, list) or len(entry) != 2:
            continue
        commander, command_id = entry
        if not isinstance(commander, str) or type(command_id) is not int:  # not a bool
            continue
        key = (commander, command_id)
        if key in known and key not in pairs:
            pairs.append(key)
    return pairs


def _time_problem(decision: KeptDecision, wall_now: float) -> str | None:
    """Why ``decision``'s time (or its answer's) cannot be right, or None: not finite,
    before 1970, or later than ``wall_now`` by more than ``DECISION_CLOCK_SLACK_S``."""
    received_at, done_s = decision.received_at, decision.done_s
    latest = wall_now + DECISION_CLOCK_SLACK_S
    what = f"decision {decision.commander!r} {decision.command_id:#x}"
    if not math.isfinite(received_at) or received_at < 0:
        return f"{what}: received_at {received_at!r} is not a time"
    if received_at > latest:
        return f"{what}: received_at {received_at!r} is {received_at - wall_now:.3g} s ahead"
    if done_s is None:
        return None
    if not math.isfinite(done_s) or done_s < 0:
        return f"{what}: done_s {done_s!r} is not a duration"
    if received_at + done_s > latest:
        return f"{what}: its answer (done_s {done_s!r}) is ahead of the clock"
    return None


def _outcome(kept: object) -> KeptOutcome:
    """One persisted outcome, checked as the wire would check it (it is sent again)."""
    if not isinstance(kept, list) or len(kept) != 4:
        raise ValueError(f"outcome {kept!r} is not [commander, id, result, reason]")
    commander, command_id, result, reason = kept
    if not (isinstance(commander, str) and isinstance(reason, str)):
        raise TypeError(f"outcome {kept!r}: commander and reason must be strings")
    if isinstance(command_id, bool) or not isinstance(command_id, int) or command_id < 0:
        raise ValueError(f"outcome {kept!r}: bad command id")
    CommandResult(result)  # raises ValueError for a result the wire does not have
    if "\x00" in reason or len(reason.encode("utf-8")) > MAX_REASON_CHARS:
        raise ValueError(f"outcome {kept!r}: reason too long or holding NUL")
    return (commander, command_id, int(result), reason)


DECIDED_STATES: Final = frozenset(r.name.lower() for r in CommandResult)


def _decision(kept: object) -> KeptDecision:
    """One persisted decision, checked: it is shown to an operator (``swarmctl outcomes``,
    which also escapes its strings) and its strings are as bounded as the wire's."""
    if not isinstance(kept, list) or len(kept) != len(KeptDecision._fields):
        raise ValueError(f"decision {kept!r} is not [{', '.join(KeptDecision._fields)}]")
    life, commander, command_id, kind, state, reason, received_at, done_s = kept
    for value in (life, command_id):
        if isinstance(value, bool) or not isinstance(value, int) or value < 0:
            raise ValueError(f"decision {kept!r}: bad life or command id")
    if life > MAX_INCARNATION:
        raise ValueError(f"decision {kept!r}: life out of range")
    if not all(isinstance(v, str) for v in (commander, kind, state, reason)):
        raise TypeError(f"decision {kept!r}: commander, kind, state, reason must be strings")
    if state not in DECIDED_STATES:
        raise ValueError(f"decision {kept!r}: unknown state")
    if len(commander) > MAX_NAME_CHARS or len(kind) > MAX_NAME_CHARS:
        raise ValueError(f"decision {kept!r}: commander or kind too long")
    if len(reason.encode("utf-8")) > MAX_REASON_CHARS:
        raise ValueError(f"decision {kept!r}: reason too long")
    if not _number(received_at) or not (done_s is None or _number(done_s)):
        raise TypeError(f"decision {kept!r}: a time is not a number")
    # the times' values are judged apart (``_time_problem``): a wrong one drops its entry
    # alone, and keeps its id
    done = None if done_s is None else _as_float(done_s)
    return KeptDecision(
        life, commander, command_id, kind, state, reason, _as_float(received_at), done
    )


def _as_float(value: int | float) -> float:
    """A JSON number as a float; an integer past a double's range is infinite (and then
    judged by ``_time_problem``), not an ``OverflowError``."""
    try:
        return float(value)
    except OverflowError:
        return math.inf


def _number(value: object) -> TypeGuard[int | float]:
    return isinstance(value, int | float) and not isinstance(value, bool)
