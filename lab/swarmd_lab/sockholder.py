"""User ``nobody`` holding many UDP sockets on one port, each at its own address of 127/8
(``127.1.X.Y``): the local user of docs/security.md, "The local user", who grows the kernel's
socket table around a node's port (tests/test_sockdiag.py, bench/sender_uid_scale.py,
bench/sender_uid_starve.py). Needs root and ``setpriv``; run it inside a throw-away network
namespace (swarmd_lab.netns) when the count is large, so the host's table is never touched.

Linux lets another user bind a port at other addresses beside a node's ``127.0.0.1:P``
(no wildcard, no overlap), and lists a port's newest sockets first. ``nobody``'s file limit
is 20,000 on the test box, so the sockets are spread over processes of ``per_process``.
"""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Final

NOBODY: Final = 65534
# Under nobody's RLIMIT_NOFILE (20,000 here), with room for the interpreter's own files.
PER_PROCESS: Final = 17_000
# Binds sockets first .. first + count - 1 on the port at 127.1.(i >> 8).(i & 255) (or, with
# "same", all at 127.0.0.1 with SO_REUSEADDR: one hash chain in the kernel), prints "ready",
# holds them until its stdin closes, at most hold_s seconds.
HOLDER: Final = """
import socket, sys, select
port, first, count = map(int, sys.argv[1:4])
hold_s, same = float(sys.argv[4]), sys.argv[5] == "same"
socks = []
for i in range(first, first + count):
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, same)
    s.bind(("127.0.0.1" if same else f"127.1.{i >> 8}.{i & 255}", port))
    socks.append(s)
print("ready", flush=True)
select.select([sys.stdin], [], [], hold_s)
"""
STOP_TIMEOUT_S: Final = 30.0  # a holder whose stdin closed exits at once; past this, killed


class HolderNotReady(RuntimeError):
    """A holder exited (or printed something else) before binding all its sockets."""


@contextmanager
def nobody_holds(
    port: int,
    count: int,
    *,
    first: int = 1,
    per_process: int = PER_PROCESS,
    hold_s: float = 900.0,
    same_address: bool = False,
) -> Iterator[list[subprocess.Popen[str]]]:
    """``nobody`` holds ``count`` sockets on ``port`` (socket ``first`` onwards) while the
    block runs (``same_address``: all at 127.0.0.1, SO_REUSEADDR); the processes are stopped
    on every way out of it, a failed start included.
    Raises ``HolderNotReady`` when a holder did not bind all its sockets."""
    procs: list[subprocess.Popen[str]] = []
    try:
        for start in range(first, first + count, per_process):
            n = min(per_process, first + count - start)
            argv = ["setpriv", f"--reuid={NOBODY}", f"--regid={NOBODY}", "--clear-groups"]
            argv += [sys.executable, "-I", "-c", HOLDER, str(port), str(start), str(n)]
            procs.append(
                subprocess.Popen(  # noqa: S603 - fixed argv
                    [*argv, str(hold_s), "same" if same_address else "spread"],
                    stdin=subprocess.PIPE,
                    stdout=subprocess.PIPE,
                    text=True,
                )
            )
        for proc in procs:
            line = proc.stdout.readline().strip() if proc.stdout is not None else ""
            if line != "ready":
                raise HolderNotReady(f"nobody's sockets were not bound (holder said {line!r})")
        yield procs
    finally:
        for proc in procs:
            _stop(proc)


def _stop(proc: subprocess.Popen[str]) -> None:
    """Close its stdin (it lets go and exits); kill it if it does not."""
    try:
        proc.communicate(timeout=STOP_TIMEOUT_S)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.communicate()
