"""``swarmd.bundle.statedir``: whether the daemon's user can create and write a state folder,
judged by reading only (``swarmd check-config`` as root for the unit's ``User=``).

The judgement for another user than this process reads the folder's owner, group and mode
bits; these cases set each one (root may chown), and check nothing was created.
"""

from __future__ import annotations

import os
import stat
import struct
from dataclasses import replace
from pathlib import Path

import pytest

from swarmd.bundle.statedir import (
    UNKNOWN_UID,
    DaemonUser,
    refuse_unwritable_dir,
    unwritable_why,
)

pytestmark = pytest.mark.skipif(os.geteuid() != 0, reason="chown to another uid needs root")

# a user and a group no test process runs as
OTHER = DaemonUser("drone", uid=64_001, gids=frozenset({64_002}), current=False)


def _folder(path: Path, uid: int, gid: int, mode: int) -> Path:
    path.mkdir()
    os.chown(path, uid, gid)
    path.chmod(mode)
    return path


@pytest.mark.parametrize(
    ("uid", "gid", "mode", "writable"),
    [
        (64_001, 0, 0o700, True),  # its own folder
        (64_001, 0, 0o500, False),  # its own, but read-only for it
        (0, 64_002, 0o770, True),  # its group may write
        (0, 64_002, 0o750, False),  # its group may only read
        (0, 0, 0o755, False),  # root's: what a root-run install leaves behind
        (0, 0, 0o777, True),  # everyone's (refused elsewhere: refuse_shared_dir)
    ],
)
def test_owner_group_and_mode_decide_for_another_user(
    tmp_path: Path, uid: int, gid: int, mode: int, writable: bool
) -> None:
    folder = _folder(tmp_path / "state", uid, gid, mode)
    assert (unwritable_why(folder, OTHER) is None) == writable


def test_a_missing_folder_is_judged_by_its_nearest_parent(tmp_path: Path) -> None:
    parent = _folder(tmp_path / "lib", 0, 0, 0o755)
    why = unwritable_why(parent / "swarmd" / "state", OTHER)
    assert why is not None and str(parent) in why and "create" in why
    assert not (parent / "swarmd").exists()
    os.chown(parent, OTHER.uid, 0)
    assert unwritable_why(parent / "swarmd" / "state", OTHER) is None


def test_a_file_in_the_way_is_refused_for_any_user(tmp_path: Path) -> None:
    blocker = tmp_path / "blocker"
    blocker.write_text("")
    for user in (OTHER, DaemonUser.this_process()):
        with pytest.raises(OSError, match="dataplane.state_dir") as caught:
            refuse_unwritable_dir(blocker / "state", "dataplane.state_dir", OSError, user)
        assert str(blocker) in str(caught.value)


# ---- ACLs (acl(5)) and the folders systemd gives the unit's user ------------------------------

ANY = 0xFFFFFFFF  # an entry without a qualifier (linux/posix_acl_xattr.h: ACL_UNDEFINED_ID)


def _set_acl(folder: Path, entries: list[tuple[int, int, int]]) -> None:
    """Write ``folder``'s access ACL as the kernel stores it (what ``setfacl`` does)."""
    raw = struct.pack("<I", 2) + b"".join(struct.pack("<HHI", *entry) for entry in entries)
    try:
        os.setxattr(folder, "system.posix_acl_access", raw)
    except OSError as exc:  # a file system without ACLs
        pytest.skip(f"no POSIX ACLs on {folder}: {exc.strerror}")


def test_an_acl_that_denies_the_owning_group_is_judged_though_the_mode_bits_allow(
    tmp_path: Path,
) -> None:
    """The owning group's entry is r-x while a named group's rwx sets the mask (the mode's
    group bits) to rwx: the mode bits say the group may write, the kernel says no. On main
    the mode bits alone were judged: "writable"."""
    folder = _folder(tmp_path / "state", 0, 64_002, 0o770)
    _set_acl(folder, [(1, 7, ANY), (4, 5, ANY), (8, 7, 64_099), (16, 7, ANY), (32, 0, ANY)])
    assert stat.S_IMODE(os.stat(folder).st_mode) == 0o770
    why = unwritable_why(folder, OTHER)
    assert why is not None and "ACL" in why
    in_named_group = DaemonUser("drone", 64_001, frozenset({64_002, 64_099}), current=False)
    assert unwritable_why(folder, in_named_group) is None  # any matching entry may grant


def test_an_acl_naming_the_user_lets_it_create_its_folder(tmp_path: Path) -> None:
    parent = _folder(tmp_path / "lib", 0, 0, 0o750)
    assert unwritable_why(parent / "state", OTHER) is not None
    _set_acl(parent, [(1, 7, ANY), (2, 7, OTHER.uid), (4, 5, ANY), (16, 7, ANY), (32, 0, ANY)])
    assert unwritable_why(parent / "state", OTHER) is None
    masked = [(1, 7, ANY), (2, 7, OTHER.uid), (4, 5, ANY), (16, 5, ANY), (32, 0, ANY)]
    _set_acl(parent, masked)  # the mask takes w away from every named entry
    assert unwritable_why(parent / "state", OTHER) is not None


def test_a_folder_systemd_gives_the_user_at_start_is_judged_as_its_own(tmp_path: Path) -> None:
    """systemd.exec(5), StateDirectory=: created if missing, chowned to the unit's user
    (recursively when its owner differs) at each start."""
    given = _folder(tmp_path / "swarmd", 0, 0, 0o700)
    below = _folder(given / "state", 0, 0, 0o700)  # the top's owner: chowned with it
    foreign = _folder(given / "other", 65_000, 0, 0o700)  # another owner: left alone
    user = replace(OTHER, chowned=(str(given),))
    assert unwritable_why(given, OTHER) is not None
    assert unwritable_why(given, user) is None
    assert unwritable_why(below, user) is None
    assert unwritable_why(foreign, user) is not None
    assert user.trusted_owners(given) == frozenset({OTHER.uid, 0})
    missing = replace(OTHER, chowned=(str(tmp_path / "later"),))
    _folder(tmp_path / "ro", 0, 0, 0o755)
    assert unwritable_why(tmp_path / "later" / "state", missing) is None  # created at start
    dynamic = DaemonUser("dyn", UNKNOWN_UID, frozenset(), current=False, chowned=(str(given),))
    assert unwritable_why(given, dynamic) is None
    assert unwritable_why(tmp_path / "ro", dynamic) is not None
    with pytest.raises(OSError, match="systemd gives the dynamic user") as caught:
        refuse_unwritable_dir(tmp_path / "ro", "dataplane.state_dir", OSError, dynamic)
    assert "chown" not in str(caught.value)
