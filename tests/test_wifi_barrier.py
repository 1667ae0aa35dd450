"""The testbed's fair start (bench/wifi/barrier.py) and swarmd's opt-in hook for it.

``SWARMD_START_BARRIER=PATH`` makes ``swarmd run`` behind the testbed's launcher
(``python -m swarmd_lab.start_barrier``) load its config and bundle, then wait on the
harness's UNIX socket before it opens any socket of its own; unset, nothing changes (the other
daemon tests run plain ``swarmd``).
"""

from __future__ import annotations

import os
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from swarmd_lab.start_barrier import wait_start_barrier as swarmd_wait

from bench.wifi.barrier import BarrierError, StartBarrier, set_priority
from bench.wifi.peers.common import wait_start_barrier as peer_wait
from tests.daemon_support import (
    BundleFiles,
    clean_env,
    loopback_config,
    run_domain,
    write_bundle,
)

SWARMD = [sys.executable, "-m", "swarmd_lab.start_barrier"]  # `swarmd` + the barrier hook
JOIN_S = 20.0  # a safety net for a hung thread or process, never a measured time


def _sleeper() -> subprocess.Popen[bytes]:
    return subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])


def test_nobody_goes_before_release_and_everyone_after(workdir: Path) -> None:
    gone: list[str] = []
    lock = threading.Lock()
    path = workdir / "b.sock"

    def client(name: str) -> None:
        if name == "peer":
            peer_wait(path)  # what cyclone_peer.py and zenoh_peer.py call
        else:
            swarmd_wait(str(path))  # what `swarmd run` calls
        with lock:
            gone.append(name)

    stand_ins = [_sleeper(), _sleeper()]  # wait_all watches processes for early death
    try:
        with StartBarrier(path) as barrier:
            threads = [
                threading.Thread(target=client, args=("peer",)),
                threading.Thread(target=client, args=("swarmd",)),
            ]
            for t in threads:
                t.start()
            barrier.wait_all(stand_ins, timeout_s=JOIN_S)
            assert barrier.waiting == 2
            threads[0].join(0.2)
            assert gone == [], "a client passed the barrier before the release"
            barrier.release()
            for t in threads:
                t.join(JOIN_S)
            assert sorted(gone) == ["peer", "swarmd"]
        assert not path.exists(), "the barrier socket was left behind"
    finally:
        for p in stand_ins:
            p.kill()
            p.wait()


def test_a_contender_dying_before_the_barrier_is_named(workdir: Path) -> None:
    dead = subprocess.Popen([sys.executable, "-c", "raise SystemExit(3)"])
    dead.wait()
    alive = _sleeper()
    try:
        with StartBarrier(workdir / "b.sock") as barrier:
            with pytest.raises(BarrierError, match="contender 1 exited with 3"):
                barrier.wait_all([alive, dead], timeout_s=JOIN_S)
    finally:
        alive.kill()
        alive.wait()


def test_set_priority_reaches_every_thread() -> None:
    proc = subprocess.Popen(
        [
            sys.executable,
            "-c",
            "import threading, time\n"
            "threading.Thread(target=time.sleep, args=(60,), daemon=True).start()\n"
            "print('up', flush=True); time.sleep(60)",
        ],
        stdout=subprocess.PIPE,
    )
    try:
        assert proc.stdout is not None
        assert proc.stdout.readline() == b"up\n"  # both threads exist now
        set_priority(proc.pid, 7)
        tids = [int(t) for t in os.listdir(f"/proc/{proc.pid}/task")]
        assert len(tids) == 2
        assert {os.getpriority(os.PRIO_PROCESS, t) for t in tids} == {7}
    finally:
        proc.kill()
        proc.communicate()
    set_priority(proc.pid, 0)  # an exited process is ignored, not an error


@pytest.fixture
def files(workdir: Path) -> BundleFiles:
    return write_bundle(workdir, 2, domain_id=run_domain() + 7)


def _config(workdir: Path, files: BundleFiles) -> Path:
    return loopback_config(workdir, files)


def _env(**extra: str) -> dict[str, str]:
    return clean_env(**extra)


def test_swarmd_opens_no_socket_until_released(workdir: Path, files: BundleFiles) -> None:
    with StartBarrier(workdir / "b.sock") as barrier:
        proc = subprocess.Popen(
            [*SWARMD, "run", "--config", str(_config(workdir, files))],
            env=_env(SWARMD_START_BARRIER=str(workdir / "b.sock")),
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
            text=True,
        )
        try:
            barrier.wait_all([proc], timeout_s=JOIN_S)
            # config and bundle are loaded (it connected), its control socket not yet bound
            assert not (workdir / "ctl.sock").exists()
            barrier.release()
            for _ in range(int(JOIN_S / 0.05)):
                if (workdir / "ctl.sock").exists():
                    break
                assert proc.poll() is None, proc.communicate()[1]
                time.sleep(0.05)
            assert (workdir / "ctl.sock").exists(), "released swarmd never bound its socket"
            proc.terminate()
            _, err = proc.communicate(timeout=JOIN_S)
            assert proc.returncode == 0, err
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()


def test_swarmd_with_no_barrier_listening_exits_78_in_one_line(
    workdir: Path, files: BundleFiles
) -> None:
    missing = workdir / "nobody.sock"
    proc = subprocess.run(
        [*SWARMD, "run", "--config", str(_config(workdir, files))],
        env=_env(SWARMD_START_BARRIER=str(missing)),
        capture_output=True,
        text=True,
        timeout=JOIN_S * 3,
        check=False,
    )
    assert proc.returncode == 78
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    assert f"SWARMD_START_BARRIER={missing}: cannot connect" in lines[0]
    assert not (workdir / "ctl.sock").exists()


# a process that waits on the barrier as the peers do, then prints once released; "fork":
# behind a shell that forks it (the ROS 2 host's sh), so the barrier must walk its parents
_WAITER = (
    "import sys; sys.path[:0] = sys.argv[2:]\n"
    "from bench.wifi.peers.common import wait_start_barrier\n"
    "from pathlib import Path\n"
    "wait_start_barrier(Path(sys.argv[1])); print('gone', flush=True)\n"
)


def _waiter(path: Path, *, behind_shell: bool) -> subprocess.Popen[bytes]:
    argv = [sys.executable, "-c", _WAITER, str(path), *sys.path]
    if behind_shell:
        # `sh -c '...; exit $?'`: sh forks the waiter and waits (no exec)
        argv = ["sh", "-c", '"$@"; exit $?', "sh", *argv]
    return subprocess.Popen(argv, stdout=subprocess.PIPE)


def test_a_staggered_release_holds_each_drone_until_its_own_offset(workdir: Path) -> None:
    path = workdir / "b.sock"
    procs = [_waiter(path, behind_shell=i == 1) for i in range(3)]
    try:
        with StartBarrier(path) as barrier:
            barrier.wait_all(procs, timeout_s=JOIN_S)
            # drone 1 (behind a forking shell) far in the future, the others at once
            barrier.release_staggered(procs, [0.0, 600.0, 0.0])
            for i in (0, 2):
                out = procs[i].stdout
                assert out is not None
                assert out.readline() == b"gone\n"
            assert sorted(barrier.released_at) == [0, 2]
            assert procs[1].poll() is None, "drone 1 went before its offset"
        # closing the barrier lets the one still waiting go at once
        assert procs[1].stdout is not None
        assert procs[1].stdout.readline() == b"gone\n"
        assert sorted(barrier.released_at) == [0, 1, 2]
    finally:
        for p in procs:
            p.kill()
            p.communicate()  # reaps it and closes its stdout pipe


def test_a_connection_from_no_contender_is_refused_by_a_staggered_release(
    workdir: Path,
) -> None:
    path = workdir / "b.sock"
    stand_in = _sleeper()  # counted by wait_all, but the connection is this test's own
    client = threading.Thread(target=peer_wait, args=(path,), daemon=True)
    try:
        with StartBarrier(path) as barrier:
            client.start()
            barrier.wait_all([stand_in], timeout_s=JOIN_S)
            with pytest.raises(BarrierError, match="none of the contender processes"):
                barrier.release_staggered([stand_in], [1.0])
        client.join(JOIN_S)  # close() released it all the same
        assert not client.is_alive()
    finally:
        stand_in.kill()
        stand_in.wait()
