"""How long a save stalls the daemon's event loop, with its state folder on a slow disk.

    sudo .venv/bin/python bench/save_stall.py --slow-disk 4 [--saves 10]
    .venv/bin/python bench/save_stall.py --dir DIR [--saves 10]     # DIR as it is

One real daemon in this process (``tests.daemon_support.loopback_daemon``: host loopback,
no vehicle, the data plane on), its node.key folder (boot epoch, replay windows) and its
``dataplane.state_dir`` under the measured folder. After start, ``--saves`` saves of each
kind, 0.3 s apart, through the daemon's own paths: the state file (``SwarmApp._on_event``
with a ``PersistExecuted``, as the swarm core emits it for a command) and the replay
windows (``Daemon._save_windows`` with a window moved). A loop timer every 5 ms records how
late it fires; per save the bench prints how long the loop thread was inside the save
call, the loop's worst lateness from the call until the file is written (the stall every
datagram, timer and take-off retransmission of the daemon sees), and how long the write
took. On a tree without ``swarmd.filewriter`` (main before session 17) the save is the
call itself.

``--slow-disk WIOPS`` (root): builds the slow disk, runs the measurement on it in a child
process, and removes it on every exit path. No device-mapper on this kernel (no
``dm-delay``), so the disk is an ext4 file system on a loop device over a file in /tmp,
with a cgroup-v1 ``blkio.throttle.write_iops_device`` of WIOPS writes per second on that
loop device for the child alone: an fsync waits for its data blocks at that rate, as on a
busy SD card (4: about 0.3 s per fsync here). Nothing else on the machine is throttled.
A reading, not a test: nothing asserted.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import logging
import os
import shutil
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import structlog  # noqa: E402

from swarmd.auth.freshness import Freshness  # noqa: E402
from swarmd.rawclock import run_on_raw_clock  # noqa: E402
from swarmd.swarm.events import PersistExecuted  # noqa: E402
from tests.daemon_support import (  # noqa: E402
    loopback_daemon,
    run_domain,
    swarm_sections,
    write_bundle,
)

TICK_S = 0.005  # the loop timer's period
GAP_S = 0.3  # between saves
WRITE_CAP_S = 60.0  # a bound on one save
CGROUP = Path("/sys/fs/cgroup/blkio/swarmd-save-stall")
IMAGE_MB = 256


class Lateness:
    """A loop timer every ``TICK_S``: the worst lateness since ``reset``."""

    def __init__(self, loop: asyncio.AbstractEventLoop) -> None:
        self.loop = loop
        self.worst = 0.0
        self._due = loop.time() + TICK_S
        self._handle = loop.call_at(self._due, self._tick)

    def _tick(self) -> None:
        now = self.loop.time()
        self.worst = max(self.worst, now - self._due)
        self._due = now + TICK_S
        self._handle = self.loop.call_at(self._due, self._tick)

    def reset(self) -> None:
        self.worst = 0.0

    def cancel(self) -> None:
        self._handle.cancel()


async def measure(directory: Path, saves: int) -> dict[str, list[tuple[float, float, float]]]:
    """Per kind, per save: (seconds inside the call, worst loop lateness, write seconds)."""
    files = write_bundle(directory, 2, domain_id=run_domain(), lease_s=20.0)
    extra = swarm_sections(directory / "state", None, period_s=0.5)
    daemon = loopback_daemon(directory, files, "uav1", extra=extra)
    await daemon.start()
    loop = asyncio.get_running_loop()
    late = Lateness(loop)
    rows: dict[str, list[tuple[float, float, float]]] = {"state": [], "windows": []}
    writer: Any = getattr(daemon, "writer", None)  # None: main before session 17
    try:
        app, auth = daemon.app, daemon._spdp_auth
        assert app is not None  # noqa: S101 - started with the data plane
        assert auth is not None  # noqa: S101 - every daemon authenticates SPDP
        peer = files.bundle.participants[-1].guid_prefix.value  # uav2
        for i in range(saves):
            for kind in rows:
                await asyncio.sleep(GAP_S)
                late.reset()
                start = loop.time()
                if kind == "state":
                    executed = tuple(("uav0", n) for n in range(1, i + 2))
                    app._on_event(PersistExecuted(executed, command=executed[-1]))
                else:  # the peer's window moved: a line of data to write, as in flight
                    auth.verifier.restore({peer: Freshness(1, 100 * (i + 1))})
                    auth.verifier.windows_changed = True
                    daemon._save_windows()
                inside = loop.time() - start
                if writer is not None:
                    await asyncio.wait_for(writer.flush(), WRITE_CAP_S)
                await asyncio.sleep(TICK_S * 2)  # the timer's next tick sees the stall
                written = loop.time() - start - TICK_S * 2
                rows[kind].append((inside, late.worst, written))
    finally:
        late.cancel()
        await daemon.stop("bench")
    return rows


def report(rows: dict[str, list[tuple[float, float, float]]]) -> None:
    print(
        f"{'save':8} {'n':>3} {'in call ms (med/max)':>22} {'loop stall ms (med/max)':>24} "
        f"{'written after ms (med/max)':>27}"
    )
    for kind, values in rows.items():
        cols = []
        for j in range(3):
            ms = [v[j] * 1000 for v in values]
            cols.append(f"{statistics.median(ms):9.1f} / {max(ms):7.1f}")
        print(f"{kind:8} {len(values):3} {cols[0]:>22} {cols[1]:>24} {cols[2]:>27}")


def run(cmd: list[str]) -> str:
    return subprocess.run(cmd, check=True, capture_output=True, text=True).stdout.strip()


def slow_disk(wiops: int, saves: int) -> int:
    """Build the throttled disk, measure in a child inside the cgroup, remove it all."""
    if os.geteuid() != 0:
        print("--slow-disk needs root (losetup, mount, a blkio cgroup)", file=sys.stderr)
        return 2
    work = Path(tempfile.mkdtemp(prefix="save-stall-"))
    image, mount = work / "disk.img", work / "m"
    loop_dev: str | None = None
    mounted = False
    child: subprocess.Popen[bytes] | None = None
    # SIGTERM ends us through the finally below, like Ctrl-C
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))
    try:
        with image.open("wb") as f:
            f.truncate(IMAGE_MB << 20)
        loop_dev = run(["losetup", "-f", "--show", str(image)])
        run(["mkfs.ext4", "-q", "-F", loop_dev])
        mount.mkdir()
        run(["mount", loop_dev, str(mount)])
        mounted = True
        (mount / "w").mkdir(mode=0o755)
        devno = Path(f"/sys/block/{Path(loop_dev).name}/dev").read_text().strip()
        CGROUP.mkdir(exist_ok=True)
        (CGROUP / "blkio.throttle.write_iops_device").write_text(f"{devno} {wiops}\n")
        print(f"slow disk: ext4 on {loop_dev} ({devno}), {wiops} write IOPS for the bench")
        cgroup_procs = str(CGROUP / "cgroup.procs")

        def enter_cgroup() -> None:
            with open(cgroup_procs, "w") as procs:
                procs.write(str(os.getpid()))

        argv = [sys.executable, __file__, "--dir", str(mount / "w"), "--saves", str(saves)]
        child = subprocess.Popen(argv, preexec_fn=enter_cgroup)  # noqa: S603 - our own argv
        return child.wait(timeout=WRITE_CAP_S * saves * 2 + 120)
    finally:
        if child is not None and child.poll() is None:
            child.kill()
            child.wait()
        if mounted:
            subprocess.run(["umount", str(mount)], check=False)
        if loop_dev is not None:
            subprocess.run(["losetup", "-d", loop_dev], check=False)
        with contextlib.suppress(OSError):
            CGROUP.rmdir()
        with contextlib.suppress(OSError):
            image.unlink()
        with contextlib.suppress(OSError):
            mount.rmdir()
        with contextlib.suppress(OSError):
            work.rmdir()


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--slow-disk", type=int, metavar="WIOPS", help="build one (root)")
    parser.add_argument("--dir", type=Path, help="measure in this folder as it is")
    parser.add_argument("--saves", type=int, default=10)
    args = parser.parse_args()
    if args.slow_disk is not None:
        return slow_disk(args.slow_disk, args.saves)
    # the daemon's info lines would bury the table
    structlog.configure(wrapper_class=structlog.make_filtering_bound_logger(logging.ERROR))
    own = args.dir is None
    directory = Path(tempfile.mkdtemp(prefix="save-stall-")) if own else args.dir
    code = "filewriter" if (ROOT / "swarmd" / "filewriter.py").exists() else "on the loop"
    print(f"tree {ROOT} (saves: {code}), folder {directory}")
    t0 = time.monotonic()
    try:
        report(run_on_raw_clock(measure(directory, args.saves)))
    finally:
        if own:
            shutil.rmtree(directory, ignore_errors=True)
    print(f"{time.monotonic() - t0:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
