"""A local user against swarmd's state files (session 10 review of the local boundaries).

In production the state directory is systemd's ``StateDirectory=swarmd`` (``/var/lib/swarmd``,
0700 swarmd), which no other user can enter (``tests/test_production_layout.py``). These are
the attacks when ``dataplane.state_dir`` or ``bundle.node_key``'s folder points somewhere
another user can write (a shared folder, a lab box, a hand-made directory): swarmd wrote
each file through a predictable temporary name with a plain ``open``, so a symlink planted
there made the daemon truncate and overwrite whatever it pointed at (its own ``node.key``),
and a state file planted there was taken as the node's memory of executed commands.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

from swarmd.auth.epoch import EpochError, next_epoch
from swarmd.bundle.keys import write_file_atomic
from swarmd.statefile import NodeState, StateDirError, boot, state_path

VICTIM_BYTES = b"-----BEGIN PRIVATE KEY-----\nnot to be touched\n"


def _victim(tmp_path: Path) -> Path:
    victim = tmp_path / "private" / "node.key"
    victim.parent.mkdir(mode=0o700)
    victim.write_bytes(VICTIM_BYTES)
    return victim


def _shared_dir(tmp_path: Path) -> Path:
    shared = tmp_path / "shared"
    shared.mkdir()
    os.chmod(shared, 0o777)  # noqa: S103 - the attack: a folder every local user writes
    return shared


def test_a_symlink_at_the_state_files_temp_name_is_not_written_through(tmp_path: Path) -> None:
    """The attacker plants ``dataplane-<node>.json.tmp`` -> the daemon's node.key; the
    next write-ahead save must not truncate or overwrite the key."""
    victim = _victim(tmp_path)
    state_dir = _shared_dir(tmp_path)
    path = state_path(state_dir, "uav1")
    for planted in (path.with_name(path.name + ".tmp"), path.with_name(f".{path.name}.tmp")):
        planted.symlink_to(victim)
    NodeState(path, boot=3, executed=[("lead", 7)]).save()
    assert victim.read_bytes() == VICTIM_BYTES
    assert json.loads(path.read_text())["executed"] == [["lead", 7]]


def test_a_symlink_at_the_atomic_writers_temp_name_is_not_written_through(
    tmp_path: Path,
) -> None:
    """The epoch, the replay windows and the XRCE key go through ``write_file_atomic``,
    whose temp name was ``.<name>.tmp-<pid>``: predictable from ``ps``."""
    victim = _victim(tmp_path)
    shared = _shared_dir(tmp_path)
    target = shared / "auth-epoch-uav1"
    (shared / f".{target.name}.tmp-{os.getpid()}").symlink_to(victim)
    write_file_atomic(target, b"42\n", 0o644)
    assert victim.read_bytes() == VICTIM_BYTES
    assert target.read_bytes() == b"42\n"


@pytest.mark.parametrize("mode", [0o777, 0o1777, 0o770, 0o730])
def test_start_up_refuses_a_state_dir_others_can_write(tmp_path: Path, mode: int) -> None:
    """A state file planted by another user would be taken as the node's record of executed
    commands (its boot counter, its dedup set): start-up refuses the directory in one line
    naming it and the fix, before reading anything in it."""
    state_dir = tmp_path / "state"
    state_dir.mkdir()
    os.chmod(state_dir, mode)
    planted = state_path(state_dir, "uav1")
    planted.write_text('{"boot": 0, "executed": []}')
    with pytest.raises(StateDirError) as caught:
        boot(state_dir, "uav1")
    line = str(caught.value)
    assert "\n" not in line
    assert str(state_dir) in line
    assert "chmod" in line
    assert json.loads(planted.read_text())["boot"] == 0  # not read, not rewritten
    with pytest.raises(EpochError) as caught_epoch:
        next_epoch(state_dir, "uav1", 1_800_000_000.0)
    assert str(state_dir) in str(caught_epoch.value)
    assert not (state_dir / "auth-epoch-uav1").exists()


def test_a_private_state_dir_is_used(tmp_path: Path) -> None:
    """The production shape (0700, or 0750 with the group reading) passes: the refusal is
    about writers, and this shows the check does not refuse everything."""
    for mode in (0o700, 0o750, 0o755):
        state_dir = tmp_path / f"state-{mode:o}"
        state_dir.mkdir()
        os.chmod(state_dir, mode)
        assert boot(state_dir, "uav1").boot == 1
        assert next_epoch(state_dir, "uav1", 1_800_000_000.0).epoch == 1_800_000_000
