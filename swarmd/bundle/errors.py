"""The two ways a firmware bundle goes wrong, each told in one line.

``MissionError``: the operator's mission file is bad (exit 65, EX_DATAERR). Its ``str()`` is
``FILE:LINE: field PATH: problem; fix: ...`` so an editor can jump to the line.

``BundleError``: a bundle file fails verification (exit 78, EX_CONFIG): tampered, truncated,
wrongly signed, or not trusted. Its ``str()`` is ``FILE: problem; fix: ...``. The daemon
stops on it with that one line and no traceback.
"""

from __future__ import annotations

from swarmd.yamldoc import FieldError


def _one_line(text: str) -> str:
    # A message that names user input may carry newlines (a YAML scalar, a path); the
    # promise is one line, so fold them.
    return " ".join(text.split())


class MissionError(FieldError):
    """A mission file that cannot become a bundle; nothing has been written."""


class FileProblem(ValueError):
    """A file that must not be used, as one line: ``file: problem; fix: fix`` (the shape
    every bundle and key file error shares, written once)."""

    def __init__(self, file: str, problem: str, fix: str) -> None:
        self.file = file
        self.problem = problem
        self.fix = fix
        super().__init__(str(self))

    def __str__(self) -> str:
        return _one_line(f"{self.file}: {self.problem}; fix: {self.fix}")


class BundleError(FileProblem):
    """A bundle that must not be used: its ``str()`` is one line naming file, problem, fix."""


class FlashError(RuntimeError):
    """Writing a bundle to a drone failed; the previous bundle is still in place."""


class SerialRefused(FlashError):
    """``swarmctl bundle`` refuses to put a bundle in place that the drone's swarmd would
    refuse at start for its serial (below the floor, or the floor's serial with another
    hash; docs/security.md, "Bundle rollback"): exit 78, the daemon's code for it. One line,
    nothing written."""


class KeyFileError(FileProblem):
    """A key file that is missing, unreadable or not an Ed25519 key; one line, like the rest."""
