"""The state file under ``kill -9`` at each step of its atomic write (``statefile.py``,
``bundle.safeopen.write_atomic``: temporary file, fsync, rename, fsync of the folder;
session 12 review).

The executed ids are written before the vehicle moves (docs/dataplane.md, "Exactly once"
3). A daemon killed at any step of that write must leave the earlier file or the new
one, whole, and a left-over temporary file must not stop or mislead the next life: a
half file would be "corrupt" and replaced, losing every executed id at once (exactly
once would then rest on the member's clock rule alone, "A life runs only its own
commands"). Each case runs a real process that SIGKILLs itself at one step.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from swarmd import statefile

CHILD = """
import os, signal, sys
from pathlib import Path
import swarmd.bundle.safeopen as safeopen
from swarmd import statefile

step = sys.argv[2]
def die(*args, **kwargs):
    os.kill(os.getpid(), signal.SIGKILL)
if step == "fsync":
    os.fsync = die
elif step == "rename":
    os.rename = die  # safeopen.write_atomic: renameat through the folder's descriptor
elif step == "dir":
    safeopen.sync_folder = die
state = statefile.load(Path(sys.argv[1]))
state.executed.append(("lead", 2))
state.save()
"""


@pytest.mark.parametrize(("step", "new"), [("fsync", False), ("rename", False), ("dir", True)])
def test_a_kill_at_any_step_of_the_write_leaves_a_whole_file(
    tmp_path: Path, step: str, new: bool
) -> None:
    path = statefile.state_path(tmp_path, "m01")
    statefile.NodeState(path, boot=3, executed=[("lead", 1)]).save()
    done = subprocess.run([sys.executable, "-c", CHILD, str(path), step], timeout=60, check=False)
    assert done.returncode == -9  # killed at the step, not finished
    state = statefile.load(path)
    assert state.recovered_from is None  # whole, not "corrupt"
    expected = [("lead", 1), ("lead", 2)] if new else [("lead", 1)]
    assert state.executed == expected
    # the kill left the temporary file (before the rename it is still there) ...
    left = sorted(p.name for p in tmp_path.glob(f".{path.name}.tmp-*"))
    assert len(left) == (0 if new else 1), left
    # ... and the next life boots on the whole file and removes it
    booted = statefile.boot(tmp_path, "m01")
    assert (booted.boot, booted.executed, booted.recovered_from) == (4, expected, None)
    assert booted.temps_removed == len(left)
    assert list(tmp_path.glob(".*.tmp-*")) == []


def test_boot_removes_only_its_own_left_over_temporary_files(tmp_path: Path) -> None:
    """What ``boot`` removes: this node's state file's temp names (``.<file>.tmp-<16
    hex>``), regular files of this daemon's uid. Left alone: a symlink of that name (never
    followed: its target is untouched), a folder, another uid's file, another node's temp
    (a co-hosted daemon may be writing it now), a name not of the pattern."""
    path = statefile.state_path(tmp_path, "m01")
    statefile.NodeState(path, boot=3, executed=[("lead", 1)]).save()
    suffix = "0123456789abcdef"
    ours = tmp_path / f".{path.name}.tmp-{suffix}"
    ours.write_bytes(b'{"boot": 9')  # half a write
    target = tmp_path / "elsewhere"
    target.write_bytes(b"keep me")
    kept = {
        "symlink": tmp_path / f".{path.name}.tmp-{'1' * 16}",
        "folder": tmp_path / f".{path.name}.tmp-{'2' * 16}",
        "other uid": tmp_path / f".{path.name}.tmp-{'3' * 16}",
        "other node": tmp_path / f".{statefile.state_path(tmp_path, 'm02').name}.tmp-{suffix}",
        "not the pattern": tmp_path / f".{path.name}.tmp-{suffix}x",
        "short": tmp_path / f".{path.name}.tmp-{suffix[:15]}",
    }
    kept["symlink"].symlink_to(target)
    kept["folder"].mkdir()
    for name in ("other uid", "other node", "not the pattern", "short"):
        kept[name].write_bytes(b"x")
    os.chown(kept["other uid"], os.geteuid() + 4242, -1)
    booted = statefile.boot(tmp_path, "m01")
    assert booted.temps_removed == 1 and not ours.exists()
    assert {n: os.path.lexists(p) for n, p in kept.items()} == dict.fromkeys(kept, True)
    assert target.read_bytes() == b"keep me"
    assert (booted.boot, booted.executed) == (4, [("lead", 1)])
