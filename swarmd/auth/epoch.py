"""The boot epoch: the first half of every freshness value this node sends.

One small file per node in the state directory (``/var/lib/swarmd`` on a drone, where
node.key lives), ``auth-epoch-<node>``, holding one decimal number. At start-up, before the
first datagram, the daemon calls ``next_epoch``, which writes the new value durably (temp
file, fsync, rename, directory fsync) and only then returns it.

The new epoch is ``max(stored + 1, wall-clock seconds)``:

- the file alone keeps epochs growing across restarts even with no clock at all;
- the clock alone keeps them growing when the file is lost (a re-imaged SD card, a state
  directory wiped by hand): a restarted node must not reuse an epoch, or captured datagrams
  of its earlier life would be fresh again (issue 10, attack 5), and its new datagrams
  would be refused by every peer that remembers the old, higher epoch.

With neither (file lost *and* the clock at 1970, a Jetson without RTC battery, NTP or GPS
time), peers that remember the node's earlier epoch refuse it until they restart: the
daemon logs this case (``EpochResult.recovered_from``) and docs/security.md lists it under
residual risks. u32 seconds last until 2106.

Only the daemon calls this (it is the one file touched in ``swarmd.auth``); the wall clock
is passed in, so the module imports no clock.
"""

from __future__ import annotations

import errno
from dataclasses import dataclass
from pathlib import Path
from typing import Final

from swarmd.auth.freshness import U32_MAX
from swarmd.bundle.keys import node_state_path, open_state_dir, refuse_shared_dir
from swarmd.bundle.safeopen import (
    EPOCH_CAP,
    Folder,
    held,
    open_folder,
    read_file,
    unreadable_why,
    write_atomic,
)
from swarmd.bundle.statedir import DaemonUser, refuse_unwritable_dir

FILE_PATTERN: Final = "auth-epoch-{node}"


class EpochError(OSError):
    """The epoch cannot be made durable (unwritable directory, exhausted); one line."""


@dataclass(frozen=True, slots=True)
class EpochResult:
    epoch: int
    path: Path
    stored: int | None  # what the file held; None when missing or unreadable
    recovered_from: str | None  # why the file was not used, for the log


def epoch_path(state_dir: str | Path, node: str) -> Path:
    return node_state_path(state_dir, FILE_PATTERN, node)


def read_epoch(
    path: Path, folder: Folder | None = None, also: frozenset[int] = frozenset()
) -> tuple[int | None, str | None]:
    """(stored value, problem): (None, None) for a missing file. ``folder``: ``path``'s
    folder as judged (``safeopen``: the file is read through it, never by path; None:
    opened here); ``also``: its owners trusted beside root and swarmd. A symlink, a FIFO,
    a file of another owner or one over ``EPOCH_CAP`` is unreadable: the epoch then comes
    from the clock, and the next write replaces it."""
    opened = folder if folder is not None else open_folder(path.parent)
    if opened is None:
        return None, None
    try:
        raw = read_file(opened, path.name, EPOCH_CAP, also=also)
        text = raw.decode("ascii")
    except FileNotFoundError:
        return None, None
    except OSError as exc:
        return None, f"unreadable ({unreadable_why(exc)})"
    except UnicodeDecodeError as exc:
        return None, f"unreadable ({exc})"
    finally:
        if folder is None:
            opened.close()
    try:
        value = int(text.strip())
    except ValueError:
        return None, f"corrupt ({text[:20]!r})"
    if not 0 <= value <= U32_MAX:
        return None, f"out of range ({value})"
    return value, None


def plan_epoch(
    state_dir: str | Path, node: str, wallclock_s: float, user: DaemonUser
) -> EpochResult:
    """The epoch ``next_epoch`` would make durable, found by reading only: the folder is
    safe (``refuse_shared_dir``) and ``user`` (the daemon's) can create and write it, the
    stored epoch is not exhausted. ``swarmd check-config`` calls it alone; ``next_epoch``
    calls it first, so both refuse with the same line (docs/operations.md, "Exit codes").

    Raises ``EpochError``; writes nothing."""
    directory = Path(state_dir)
    with held(open_state_dir(directory, "bundle.node_key", EpochError)) as folder:
        return _plan(folder, directory, node, wallclock_s, user)


def _plan(
    folder: Folder | None, directory: Path, node: str, wallclock_s: float, user: DaemonUser
) -> EpochResult:
    """``plan_epoch`` in the opened ``folder`` (None: not there yet): judged on its
    descriptor, the stored epoch read through it (``safeopen``)."""
    # the epoch lives beside node.key: a folder others can write could hold a planted one
    owners = user.trusted_owners(directory)
    refuse_shared_dir(folder, "bundle.node_key", EpochError, owners)
    refuse_unwritable_dir(directory, "bundle.node_key", EpochError, user)
    path = epoch_path(directory, node)
    stored, problem = read_epoch(path, folder, owners) if folder is not None else (None, None)
    if stored is not None and stored >= U32_MAX:
        raise EpochError(
            f"{path}: boot epoch exhausted (2^32 - 1); fix: rotate this node's keys "
            "('swarmctl bundle keygen --force', rebuild, re-flash) and delete the file"
        )
    clock = int(wallclock_s) if 0 <= wallclock_s <= U32_MAX else 0
    epoch = max((stored or 0) + 1, clock, 1)
    if stored is None and problem is None and clock == 0:
        problem = "missing and no wall clock"
    return EpochResult(epoch, path, stored, problem)


def next_epoch(
    state_dir: str | Path, node: str, wallclock_s: float, user: DaemonUser | None = None
) -> EpochResult:
    """Raise this node's epoch and make it durable before returning it; ``user``: whose
    writes are judged (None: this process's). The folder is judged, the stored epoch read
    and the new one written through one descriptor (``safeopen``).

    Raises ``EpochError`` when the directory cannot be written or the epoch is exhausted."""
    judged = user if user is not None else DaemonUser.this_process()
    planned = plan_epoch(state_dir, node, wallclock_s, judged)  # refusals before any write
    directory = Path(state_dir)
    try:
        directory.mkdir(parents=True, exist_ok=True, mode=0o750)
    except OSError as exc:
        raise EpochError(
            f"cannot persist the boot epoch in {planned.path}: {exc.strerror}"
        ) from None
    with held(open_state_dir(directory, "bundle.node_key", EpochError)) as folder:
        # judged again on the descriptor written through: the folder may be new, or swapped
        planned = _plan(folder, directory, node, wallclock_s, judged)
        try:
            if folder is None:
                raise FileNotFoundError(errno.ENOENT, "No such file or directory")
            # fsync file and folder
            write_atomic(folder, planned.path.name, f"{planned.epoch}\n".encode("ascii"), 0o644)
        except OSError as exc:
            raise EpochError(
                f"cannot persist the boot epoch in {planned.path}: {exc.strerror}"
            ) from None
    return planned
