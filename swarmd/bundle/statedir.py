"""Can the daemon's user write a state folder? Judged by reading only, never by writing.

The daemon writes its state (the boot epoch, the bundle floor, the data plane's state file,
an XRCE agent's key) into folders named by the config (``bundle.node_key``'s folder,
``dataplane.state_dir``). ``swarmd run`` creates them (with their parents) and writes files
there; ``swarmd check-config`` must tell, without writing, whether that will work, and
both must say it in the same line (docs/operations.md, "Exit codes": 73). So both call
``refuse_unwritable_dir`` before anything is written.

Whose writing counts: the daemon's user. ``swarmd run`` judges for itself (``os.access`` with
its effective ids, so ACLs and capabilities count as the kernel counts them).
``swarmd check-config`` run as root on a drone judges, by default, for the user the unit
runs the daemon as (``User=swarmd`` in systemd/swarmd.service, ``SERVICE_USER``) when that
user exists: from the folder's owner, group and mode bits (ACLs are not read) and a
read-only mount.
"""

from __future__ import annotations

import grp
import os
import pwd
import stat
from dataclasses import dataclass
from pathlib import Path

from swarmd.bundle.keys import SERVICE_USER


@dataclass(frozen=True, slots=True)
class DaemonUser:
    """The user whose writes are judged: its name, uid and groups; ``current``: this process
    (``os.access`` answers for it)."""

    name: str
    uid: int
    gids: frozenset[int]
    current: bool

    @classmethod
    def this_process(cls) -> DaemonUser:
        uid = os.geteuid()
        try:
            name = pwd.getpwuid(uid).pw_name
        except KeyError:
            name = f"uid {uid}"
        return cls(name, uid, frozenset({os.getegid(), *os.getgroups()}), current=True)

    @classmethod
    def named(cls, name: str) -> DaemonUser:
        """The user ``name`` (its primary and supplementary groups); ``KeyError`` if unknown."""
        entry = pwd.getpwnam(name)
        if entry.pw_uid == os.geteuid():
            return cls.this_process()
        groups = {g.gr_gid for g in grp.getgrall() if name in g.gr_mem}
        return cls(name, entry.pw_uid, frozenset({entry.pw_gid, *groups}), current=False)

    @classmethod
    def service_or_this_process(cls) -> DaemonUser:
        """``check-config``'s default: as root, the unit's ``User=`` (``SERVICE_USER``) when
        this host has that user (a drone installed as docs/deploy.md says); else this
        process's user (a lab, a bench: the daemon runs as whoever runs ``check-config``)."""
        if os.geteuid() == 0:
            try:
                return cls.named(SERVICE_USER)
            except KeyError:
                pass
        return cls.this_process()


def _read_only_mount(path: Path) -> bool:
    try:
        return bool(os.statvfs(path).f_flag & os.ST_RDONLY)
    except OSError:
        return False


def _may_write_in(folder: Path, info: os.stat_result, user: DaemonUser) -> bool:
    """Whether ``user`` may create and rename files in the folder ``folder`` (w and x)."""
    if user.current:
        effective = os.access in os.supports_effective_ids
        return os.access(folder, os.W_OK | os.X_OK, effective_ids=effective)
    if _read_only_mount(folder):
        return False
    if user.uid == 0:
        return True
    if info.st_uid == user.uid:
        bits = stat.S_IWUSR | stat.S_IXUSR
    elif info.st_gid in user.gids:
        bits = stat.S_IWGRP | stat.S_IXGRP
    else:
        bits = stat.S_IWOTH | stat.S_IXOTH
    return info.st_mode & bits == bits


def unwritable_why(directory: Path, user: DaemonUser) -> str | None:
    """Why ``user`` could not create ``directory`` (with its missing parents) or write files
    in it, or None. Reads only: it stats the folder, or its nearest existing parent."""
    existing = directory
    while not os.path.lexists(existing) and existing.parent != existing:
        existing = existing.parent
    try:
        info = os.stat(existing)
    except OSError as exc:
        return f"{existing}: {exc.strerror}"
    if not stat.S_ISDIR(info.st_mode):
        return f"{existing} is not a folder"
    if not _may_write_in(existing, info, user):
        what = "write in" if existing == directory else "create folders in"
        mode = stat.S_IMODE(info.st_mode)
        return f"user {user.name} cannot {what} {existing} (uid {info.st_uid}, mode {mode:04o})"
    return None


def refuse_unwritable_dir(
    directory: Path, field: str, error: type[OSError], user: DaemonUser
) -> None:
    """Raise ``error`` (one line: the folder, why, the config field and the fix) when
    ``user`` could not create or write ``directory`` (``unwritable_why``)."""
    why = unwritable_why(directory, user)
    if why is not None:
        raise error(
            f"{directory} cannot be written: {why}; fix: make it a folder {user.name} owns "
            f"(chown {user.name} {directory}; chmod 700 {directory}), or point {field} at one"
        )
