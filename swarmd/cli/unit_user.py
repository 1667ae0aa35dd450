"""Whose view ``swarmd check-config`` judges the written folders from: the unit's.

Before session 15's fix, ``check-config`` judged ``dataplane.state_dir`` and node.key's
folder for ``--user``, else (as root) for ``swarmd``, the name systemd/swarmd.service
ships in ``User=``, whatever the unit the daemon really runs under said. A drop-in with
``User=drone`` (or ``SupplementaryGroups=`` reset, or ``DynamicUser=yes``) made the
check say ``ok`` for folders the daemon then could not write (exit 73). Now the identity
is read from the same unit the sandbox is (``swarmd.unitsandbox.UnitIdentity``) and
resolved here against this host's user and group database, as systemd resolves it at
start (systemd.exec(5), "Credentials"; src/core/execute.c, ``get_supplementary_groups``):

- ``User=`` unset: root. Else the user (a name or a numeric uid: either must have a
  passwd entry); ``Group=`` unset: the user's own group.
- groups: ``Group=``'s, every group that lists the user as a member (``initgroups``), and
  ``SupplementaryGroups=``.
- ``DynamicUser=yes``: a static user of the name (``User=``, else the unit's name)
  is used if it exists; else a uid allocated at each start, unknown here: only the folders
  systemd gives it (``StateDirectory=`` and its kin) count as its own, the rest is judged
  as another user's with the supplementary groups.
- a user or group the host lacks: systemd would not start the service (status
  217/USER, 216/GROUP), so the check refuses it in ``run``'s one-line style (78).

``--user NAME`` overrides the unit; with no unit found, the earlier default stays (as
root, ``swarmd`` when it exists; else this process's user).
"""

from __future__ import annotations

import grp
import os
import pwd
from dataclasses import replace
from pathlib import PurePath

from swarmd.bundle.statedir import UNKNOWN_UID, DaemonUser
from swarmd.cli.sandbox_check import UNIT_NAME, Unit, assignments
from swarmd.exitcodes import EX_CONFIG, EX_USAGE, StartupError
from swarmd.unitsandbox import Setting, UnitIdentity


def _refuse(unit: Unit, setting: Setting, field: str, what: str, fix: str) -> StartupError:
    status = "217/USER" if field == "User=" else "216/GROUP"
    return StartupError(
        f"{unit.where(setting.line)}: field {field}: no {what} {setting.value!r} on this host, "
        f"so systemd would not start swarmd (status {status}); fix: {fix}",
        EX_CONFIG,
    )


def _user(unit: Unit, setting: Setting) -> pwd.struct_passwd:
    try:
        return pwd.getpwnam(setting.value)
    except KeyError:
        pass
    if setting.value.isdigit():
        try:
            return pwd.getpwuid(int(setting.value))
        except KeyError:
            pass
    fix = (
        f"create it (useradd --system --home-dir /var/lib/swarmd --shell /usr/sbin/nologin "
        f"{setting.value}: docs/deploy.md, step 3), or name an existing user in User="
    )
    raise _refuse(unit, setting, "User=", "user", fix)


def _gid(unit: Unit, setting: Setting, field: str) -> int:
    try:
        return grp.getgrnam(setting.value).gr_gid
    except KeyError:
        pass
    if setting.value.isdigit():
        try:
            return grp.getgrgid(int(setting.value)).gr_gid
        except KeyError:
            pass
    fix = f"create it (groupadd --system {setting.value}), or name an existing group in {field}"
    raise _refuse(unit, setting, field, "group", fix)


def _file(unit: Unit, setting: Setting) -> str:
    return unit.file_of(setting.line)[0]


def unit_user(unit: Unit) -> DaemonUser:
    """The identity ``unit`` runs the daemon as (see the module docstring); raises
    ``StartupError`` (78, one line) for a user or group this host lacks."""
    identity = UnitIdentity.of(assignments(unit))
    supplementary = {_gid(unit, s, "SupplementaryGroups=") for s in identity.supplementary}
    chowned = identity.chowned
    if identity.dynamic is not None:
        name = identity.user.value if identity.user else PurePath(UNIT_NAME).stem
        try:
            static = pwd.getpwnam(name)
        except KeyError:
            shown = [path for path in chowned if "/private/" not in path]  # and their twins
            # the group of a dynamic user is dynamic too, unless Group= names a static one
            groups = set(supplementary)
            if identity.group is not None:
                try:
                    groups.add(grp.getgrnam(identity.group.value).gr_gid)
                except KeyError:
                    pass
            return DaemonUser(
                name,
                UNKNOWN_UID,
                frozenset(groups),
                current=False,
                source=f"DynamicUser= of {_file(unit, identity.dynamic)}: a uid allocated at "
                f"each start; systemd gives it {' '.join(shown) or 'no folder'}",
                chowned=chowned,
            )
        user = Setting(static.pw_name, identity.user.line if identity.user else 0)
        source = f"DynamicUser= of {_file(unit, identity.dynamic)}, a static user"
    elif identity.user is None:
        user, source = Setting("root", 0), f"no User= in {unit.source}: systemd's root"
    else:
        user, source = identity.user, f"User= of {_file(unit, identity.user)}"
    entry = _user(unit, user)
    gid = _gid(unit, identity.group, "Group=") if identity.group else entry.pw_gid
    # initgroups(user, gid): the group, and every group that lists the user as a member
    members = {g.gr_gid for g in grp.getgrall() if entry.pw_name in g.gr_mem}
    gids = frozenset({gid, *members, *supplementary})
    current = entry.pw_uid == os.geteuid()
    judged = DaemonUser(entry.pw_name, entry.pw_uid, gids, current, source, chowned)
    return judged


def judged_user(name: str | None, unit: Unit | None) -> DaemonUser:
    """``check-config``'s user: ``--user NAME`` (64 if this host lacks it), else the unit's
    (``unit_user``), else the earlier default (``DaemonUser.service_or_this_process``)."""
    if name is not None:
        try:
            return replace(DaemonUser.named(name), source="--user")
        except KeyError:
            raise StartupError(f"check-config: no user {name!r} on this host", EX_USAGE) from None
    if unit is not None:
        return unit_user(unit)
    fallback = DaemonUser.service_or_this_process()
    how = "this process" if fallback.current else "the shipped unit's User="
    return replace(fallback, source=f"{how}; no {UNIT_NAME} found")
