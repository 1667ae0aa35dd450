"""A reader that closes stdout early (``swarmctl status --json | head``) is not an error.

Python ignores SIGPIPE, so a write to a pipe whose reader left raises ``BrokenPipeError``,
and the interpreter's last flush at exit raises it again ("Exception ignored ..."). The
Python documentation's recipe (library/signal, "Note on SIGPIPE"): point stdout at
/dev/null and exit. The exit code is the one a shell reports for a process a closed pipe
stopped (128 + SIGPIPE), so ``set -o pipefail`` scripts still see that output was cut.
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys
from collections.abc import Iterator
from typing import Final

EXIT_PIPE_CLOSED: Final = 128 + int(signal.SIGPIPE)


@contextlib.contextmanager
def reader_may_close_stdout() -> Iterator[None]:
    """Run a command's main under this: a closed stdout ends it quietly with 141."""
    try:
        try:
            yield
        finally:
            # inside the guard, also after argparse's SystemExit (--help): buffered output
            # meets the closed pipe here rather than in the interpreter's final flush
            sys.stdout.flush()
    except BrokenPipeError:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        raise SystemExit(EXIT_PIPE_CLOSED) from None
