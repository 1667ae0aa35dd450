"""The testbed's fair start, as a launcher around ``swarmd``'s entry point.

``SWARMD_START_BARRIER=PATH python -m swarmd_lab.start_barrier run --config FILE`` runs
``swarmd`` exactly as ``swarmd run`` does, with one hook between loading and binding: after
the config and bundle are loaded but before any socket is opened, it connects to the UNIX
stream socket at PATH (the harness, ``bench/wifi/barrier.py``) and waits until the harness
sends a byte or closes the connection, so N daemons finish their start-up work first and
then begin at one instant. Unset, nothing is awaited. Unreachable PATH: exit 78 in one line.

The hook lives here, not in the daemon's entry point: the drone's ``swarmd`` has no
knowledge of benchmark harnesses (issue 11).
"""

from __future__ import annotations

import os
import socket
import sys
from collections.abc import Sequence

from swarmd.cli import swarmd_main
from swarmd.exitcodes import EX_CONFIG, StartupError

ENV: str = "SWARMD_START_BARRIER"


def wait_start_barrier(path: str) -> None:
    """Block until the harness listening on the UNIX socket ``path`` releases us.

    Connecting registers this process as waiting (the harness counts connections); the
    release is one byte or the connection closing. Raises ``OSError`` if nobody listens.
    """
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as sock:
        sock.connect(path)
        sock.recv(1)


def _hook(path: str) -> None:
    try:
        wait_start_barrier(path)
    except OSError as exc:
        raise StartupError(
            f"{ENV}={path}: cannot connect ({exc.strerror or exc}); "
            "start the harness first or unset the variable",
            EX_CONFIG,
        ) from None


def main(argv: Sequence[str] | None = None) -> int:
    """``swarmd``'s ``main`` with the barrier hook when ``SWARMD_START_BARRIER`` is set."""
    path = os.environ.get(ENV)
    if not path:
        return swarmd_main.main(argv)
    return swarmd_main.main(argv, before_run=lambda: _hook(path))


if __name__ == "__main__":
    sys.exit(main())
