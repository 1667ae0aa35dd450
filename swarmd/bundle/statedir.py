"""Can the daemon's user write a state folder? Judged by reading only, never by writing.

The daemon writes its state (the boot epoch, the bundle floor, the data plane's state file,
an XRCE agent's key) into folders named by the config (``bundle.node_key``'s folder,
``dataplane.state_dir``). ``swarmd run`` creates them (with their parents) and writes files
there; ``swarmd check-config`` must tell, without writing, whether that will work, and
both must say it in the same line (docs/operations.md, "Exit codes": 73). So both call
``refuse_unwritable_dir`` before anything is written.

Whose writing counts: the daemon's user. ``swarmd run`` judges for itself; ``swarmd
check-config`` run as root on a drone judges, by default, for the user the unit runs the
daemon as (``User=swarmd`` in systemd/swarmd.service, ``SERVICE_USER``) when that user
exists. Both judge the folder's owner, group and mode bits and a read-only mount; the daemon
then asks the kernel too (``os.access`` with its effective ids: ACLs, capabilities), which
a check made for another user cannot.
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


def _bits_allow(info: os.stat_result, user: DaemonUser) -> bool:
    """Whether the folder's owner, group and mode bits let ``user`` create and rename files
    in it (w and x): root always."""
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
    in it, or None. Reads only: it stats the folder, or its nearest existing parent.

    The owner, group and mode bits are judged first, alike for every user, so the daemon
    and a check made for it by root say the same line; then the mount, and for this
    process the kernel's own answer (``os.access``: ACLs, capabilities)."""
    existing = directory
    while not os.path.lexists(existing) and existing.parent != existing:
        existing = existing.parent
    try:
        info = os.stat(existing)
    except OSError as exc:
        return f"{existing}: {exc.strerror}"
    if not stat.S_ISDIR(info.st_mode):
        return f"{existing} is not a folder"
    if not _bits_allow(info, user):
        what = "write in" if existing == directory else "create folders in"
        mode = stat.S_IMODE(info.st_mode)
        return f"user {user.name} cannot {what} {existing} (uid {info.st_uid}, mode {mode:04o})"
    if _read_only_mount(existing):
        # for the daemon under systemd: ProtectSystem=strict leaves it only /var/lib/swarmd
        # and /run/swarmd to write (systemd/swarmd.service)
        return f"{existing} is on a read-only mount for user {user.name}"
    if user.current:
        effective = os.access in os.supports_effective_ids
        if not os.access(existing, os.W_OK | os.X_OK, effective_ids=effective):
            return f"user {user.name} may not write in {existing} (an ACL or a mount option)"
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
