"""``swarmd.bundle.statedir``: whether the daemon's user can create and write a state folder,
judged by reading only (``swarmd check-config`` as root for the unit's ``User=``).

The judgement for another user than this process reads the folder's owner, group and mode
bits; these cases set each one (root may chown), and check nothing was created.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from swarmd.bundle.statedir import DaemonUser, refuse_unwritable_dir, unwritable_why

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
