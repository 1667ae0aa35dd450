"""The state file under ``kill -9`` at each step of its atomic write (``statefile.py``,
``bundle.keys.write_file_atomic``: temporary file, fsync, rename, fsync of the folder;
session 12 review).

The executed ids are written before the vehicle moves (docs/dataplane.md, "Exactly once"
3). A daemon killed at any step of that write must leave the earlier file or the new
one, whole, and a left-over temporary file must not stop or mislead the next life: a
half file would be "corrupt" and replaced, losing every executed id at once (exactly
once would then rest on the member's clock rule alone, "A life runs only its own
commands"). Each case runs a real process that SIGKILLs itself at one step.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from swarmd.swarm import statefile

CHILD = """
import os, signal, sys
from pathlib import Path
import swarmd.bundle.keys as keys
from swarmd.swarm import statefile

step = sys.argv[2]
def die(*args, **kwargs):
    os.kill(os.getpid(), signal.SIGKILL)
real_fsync, real_replace, real_fsync_dir = os.fsync, os.replace, keys.fsync_dir
if step == "fsync":
    os.fsync = die
elif step == "rename":
    os.replace = die
elif step == "dir":
    keys.fsync_dir = die
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
    # the next life boots on it, whatever temporary file the kill left behind
    booted = statefile.boot(tmp_path, "m01")
    assert (booted.boot, booted.executed, booted.recovered_from) == (4, expected, None)
