"""Every exit code swarmd and swarmctl use, named once (sysexits.h where one fits).

systemd's ``RestartPreventExitStatus=78`` (``swarmd.service``) relies on ``EX_CONFIG``: a bad
config or a rejected bundle stops the restart loop instead of feeding it.
"""

from __future__ import annotations

from typing import Final

EX_OK: Final = 0
EX_FAILED: Final = 1  # a check found a difference (a fleet check, a take-off not confirmed)
EX_USAGE: Final = 2  # argparse's own code for a bad command line
EX_DATAERR: Final = 65  # sysexits.h: the input data was incorrect (a bad mission)
EX_UNAVAILABLE: Final = 69  # sysexits.h: a service is unavailable (control socket held)
EX_OSERR: Final = 71  # sysexits.h: a system error (a socket or serial port refused)
EX_CANTCREAT: Final = 73  # sysexits.h: an output file cannot be created
EX_CONFIG: Final = 78  # sysexits.h: configuration error (bad config, rejected bundle)


class StartupError(Exception):
    """Start-up failed for a reason outside the config file; one line, with an exit code."""

    def __init__(self, message: str, exit_code: int) -> None:
        super().__init__(message)
        self.exit_code = exit_code
