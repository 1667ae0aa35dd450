"""Every exit code swarmd and swarmctl use, named once (sysexits.h names where one fits).

systemd's ``RestartPreventExitStatus=78`` (``systemd/swarmd.service``) relies on
``EX_CONFIG``: a bad config or a rejected bundle stops the restart loop instead of feeding it.
Codes below 64 are swarmctl's own verdicts (and argparse's 2); 64..78 are sysexits.h.
"""

from __future__ import annotations

from typing import Final

EX_OK: Final = 0
EX_FAILED: Final = 1  # a check found a difference (fleet check), not every drone took off
EX_BAD_ARGS: Final = 2  # argparse's own code for a bad command line
EX_UNREACHABLE: Final = 2  # swarmctl: the daemon's control socket does not answer
EX_NOT_READY: Final = 3  # swarmctl takeoff --require-all: some drone is not ready
EX_USAGE: Final = 64  # sysexits.h: the command was used incorrectly (takeoff targets)
EX_DATAERR: Final = 65  # sysexits.h: the input data was incorrect (a bad mission, key file)
EX_UNAVAILABLE: Final = 69  # sysexits.h: a service is unavailable (control socket held)
EX_OSERR: Final = 71  # sysexits.h: a system error (a socket or serial port refused)
EX_CANTCREAT: Final = 73  # sysexits.h: an output file cannot be created
EX_CONFIG: Final = 78  # sysexits.h: configuration error (bad config, rejected bundle)
EX_INTERRUPTED: Final = 130  # 128 + SIGINT, as a shell reports it


class StartupError(Exception):
    """Start-up failed for a reason outside the config file: one line, with an exit code.

    Raised by every part of the daemon's start-up (sockets, the swarm layer, a ``before_run``
    hook); ``swarmd run`` prints it and exits with ``exit_code``."""

    def __init__(self, message: str, exit_code: int) -> None:
        super().__init__(message)
        self.exit_code = exit_code
