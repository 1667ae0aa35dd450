"""Can the daemon's user write a state folder? Judged by reading only, never by writing.

The daemon writes its state (the boot epoch, the bundle floor, the data plane's state file,
an XRCE agent's key) into folders named by the config (``bundle.node_key``'s folder,
``dataplane.state_dir``). ``swarmd run`` creates them (with their parents) and writes files
there; ``swarmd check-config`` must tell, without writing, whether that will work, and
both must say it in the same line (docs/operations.md, "Exit codes": 73). So both call
``refuse_unwritable_dir`` before anything is written.

Whose writing counts: the daemon's user. ``swarmd run`` judges for itself; ``swarmd
check-config`` judges for the identity the unit gives the daemon (``User=``, ``Group=``,
``SupplementaryGroups=``, ``DynamicUser=``: ``swarmd.cli.sandbox_check.judged_user``), or
``--user``, or with no unit found, as root, ``User=swarmd`` of systemd/swarmd.service
(``SERVICE_USER``) when that user exists. Both judge the folder's owner, group and mode
bits, its POSIX ACL (acl(5), read with ``os.getxattr``) and a read-only mount; the daemon
then asks the kernel too (``os.access`` with its effective ids: capabilities, mount
options), which a check made for another user cannot. The folders systemd creates and
gives the unit's user at each start (``StateDirectory=`` and its kin: ``chowned``) are
judged as that user's.
"""

from __future__ import annotations

import grp
import os
import pwd
import stat
import struct
from dataclasses import dataclass
from pathlib import Path
from typing import Final

from swarmd.bundle.safeopen import SERVICE_USER

UNKNOWN_UID: Final = -1  # a DynamicUser= uid: allocated by systemd at each start

# linux/posix_acl_xattr.h: the access ACL as an extended attribute: a little-endian u32
# version (2), then one (u16 tag, u16 permissions, u32 uid or gid) per entry (acl(5))
ACL_XATTR: Final = "system.posix_acl_access"
ACL_VERSION: Final = 2
ACL_USER_OBJ, ACL_USER, ACL_GROUP_OBJ, ACL_GROUP, ACL_MASK, ACL_OTHER = 1, 2, 4, 8, 16, 32
WRITE_SEARCH: Final = 0o3  # an ACL entry's w and x: create and rename files in a folder


@dataclass(frozen=True, slots=True)
class DaemonUser:
    """The user whose writes are judged: its name, uid (``UNKNOWN_UID`` for a
    ``DynamicUser=``) and groups; ``current``: this process (``os.access`` answers for it);
    ``source``: where the identity came from, for the operator; ``chowned``: the folders
    systemd creates and gives this user at each start (systemd.exec(5), ``StateDirectory=``
    and its kin)."""

    name: str
    uid: int
    gids: frozenset[int]
    current: bool
    source: str = "this process"
    chowned: tuple[str, ...] = ()

    @property
    def dynamic(self) -> bool:
        return self.uid == UNKNOWN_UID

    @property
    def own_uid(self) -> frozenset[int]:
        """Its uid, for the owner checks that trust the daemon's own files (none: dynamic)."""
        return frozenset() if self.dynamic else frozenset({self.uid})

    def given_at_start(self, folder: Path) -> bool:
        """Whether systemd gives the existing ``folder`` to this user at each start: it is
        one of ``chowned``, or below one with that one's owner ("if the specified
        directories already exist and their owning user or group do not match the
        configured ones, all files and directories below ... will have their file
        ownership recursively changed": a folder of another owner below one the user
        already owns keeps its owner, so it is judged as it is)."""
        real = Path(os.path.realpath(folder))
        for tree in self.chowned:
            top = Path(tree)
            if real == top:
                return True
            if top in real.parents:
                try:
                    return os.stat(real).st_uid == os.stat(top).st_uid
                except OSError:
                    return False
        return False

    def created_at_start(self, directory: Path) -> bool:
        """Whether ``directory`` is one of ``chowned`` or below one that does not exist yet:
        systemd creates it for this user at start."""
        real = Path(os.path.realpath(directory))
        for tree in map(Path, self.chowned):
            if (real == tree or tree in real.parents) and not os.path.lexists(tree):
                return True
        return False

    def trusted_owners(self, folder: Path) -> frozenset[int]:
        """The owners of ``folder`` this user's daemon trusts beside root and swarmd: its own
        uid, and the folder's owner now when systemd gives it to the user at start."""
        owners = set(self.own_uid)
        if self.given_at_start(folder):
            try:
                owners.add(os.stat(folder).st_uid)
            except OSError:
                pass
        return frozenset(owners)

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
        """``check-config``'s default when no unit is found (``swarmd.cli.unit_user``): as
        root, the shipped unit's ``User=`` (``SERVICE_USER``) when this host has that user;
        else this process's user (a lab, a bench: the daemon runs as whoever runs
        ``check-config``)."""
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


def _acl(folder: Path) -> list[tuple[int, int, int]] | None:
    """The folder's access ACL entries (tag, permissions, id), or None when it has none
    beyond its mode bits (the kernel keeps no attribute then), or when it cannot be read
    or is in an unknown format: then the mode bits alone are judged (their group part is
    the ACL's mask; a named user's entry is not seen: docs/security.md)."""
    try:
        raw = os.getxattr(folder, ACL_XATTR)
    except OSError:
        # ENODATA: none; ENOTSUP: a file system without ACLs; anything else: not judged
        return None
    if len(raw) < 4 or (len(raw) - 4) % 8 or struct.unpack_from("<I", raw)[0] != ACL_VERSION:
        return None
    return [struct.unpack_from("<HHI", raw, offset) for offset in range(4, len(raw), 8)]


def _acl_allows(
    entries: list[tuple[int, int, int]], info: os.stat_result, user: DaemonUser, owner: bool
) -> bool:
    """acl(5), "Access check algorithm", for w and x: the owner's entry; else a named
    user's; else every matching group entry (the owning group's, named groups'), any of
    which may grant (each masked by ACL_MASK); else the others' entry."""
    mask = next((perm for tag, perm, _ in entries if tag == ACL_MASK), 0o7)
    if owner:
        return any(t == ACL_USER_OBJ and p & WRITE_SEARCH == WRITE_SEARCH for t, p, _ in entries)
    for tag, perm, qualifier in entries:
        if tag == ACL_USER and qualifier == user.uid:
            return perm & mask & WRITE_SEARCH == WRITE_SEARCH
    groups = [
        perm
        for tag, perm, qualifier in entries
        if (tag == ACL_GROUP_OBJ and info.st_gid in user.gids)
        or (tag == ACL_GROUP and qualifier in user.gids)
    ]
    if groups:
        return any(perm & mask & WRITE_SEARCH == WRITE_SEARCH for perm in groups)
    return any(t == ACL_OTHER and p & WRITE_SEARCH == WRITE_SEARCH for t, p, _ in entries)


def _bits_allow(info: os.stat_result, user: DaemonUser, owner: bool) -> bool:
    """Whether the folder's owner, group and mode bits let ``user`` create and rename files
    in it (w and x): root always. ``owner``: ``user`` owns it (now, or from the start on)."""
    if user.uid == 0:
        return True
    if owner:
        bits = stat.S_IWUSR | stat.S_IXUSR
    elif info.st_gid in user.gids:
        bits = stat.S_IWGRP | stat.S_IXGRP
    else:
        bits = stat.S_IWOTH | stat.S_IXOTH
    return info.st_mode & bits == bits


def _allows(folder: Path, info: os.stat_result, user: DaemonUser) -> bool:
    """The owner, group, mode bits and ACL's answer for ``user`` on the existing ``folder``."""
    if user.uid == 0:
        return True  # CAP_DAC_OVERRIDE (capabilities are not read: docs/security.md)
    owner = info.st_uid == user.uid or user.given_at_start(folder)
    entries = _acl(folder)
    if entries is not None:
        return _acl_allows(entries, info, user, owner)
    return _bits_allow(info, user, owner)


def unwritable_why(directory: Path, user: DaemonUser) -> str | None:
    """Why ``user`` could not create ``directory`` (with its missing parents) or write files
    in it, or None. Reads only: it stats the folder, or its nearest existing parent.

    The owner, group, mode bits and ACL are judged first, alike for every user, so the
    daemon and a check made for it by root say the same line; then the mount, and for this
    process the kernel's own answer (``os.access``: capabilities, mount options)."""
    existing = directory
    while not os.path.lexists(existing) and existing.parent != existing:
        existing = existing.parent
    try:
        info = os.stat(existing)
    except OSError as exc:
        return f"{existing}: {exc.strerror}"
    if not stat.S_ISDIR(info.st_mode):
        return f"{existing} is not a folder"
    if user.created_at_start(directory):
        pass  # systemd creates it for the user (systemd.exec(5), StateDirectory=)
    elif not _allows(existing, info, user):
        what = "write in" if existing == directory else "create folders in"
        mode = stat.S_IMODE(info.st_mode)
        acl = ", an ACL" if _acl(existing) is not None else ""
        return (
            f"user {user.name} cannot {what} {existing} "
            f"(uid {info.st_uid}, gid {info.st_gid}, mode {mode:04o}{acl})"
        )
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
    if why is None:
        return
    if user.dynamic:
        # its uid changes; only the folders systemd gives it at each start are its own
        given = " ".join(user.chowned) or "none: add StateDirectory= to the unit"
        fix = f"point {field} below a folder systemd gives the dynamic user ({given})"
    else:
        fix = (
            f"make it a folder {user.name} owns (chown {user.name} {directory}; chmod 700 "
            f"{directory}), or point {field} at one"
        )
    raise error(f"{directory} cannot be written: {why}; fix: {fix}")
