"""A plain stderr progress bar (no dependency): one line, redrawn in place on a TTY."""

from __future__ import annotations

from collections.abc import Callable
from typing import TextIO

WIDTH = 30


class ProgressBar:
    """``[ 3/12] swarmd n=50 seed=3 |#########.........| 45%`` for ``total`` runs."""

    def __init__(self, total: int, stream: TextIO) -> None:
        self.total = total
        self.stream = stream
        self._tty = stream.isatty()
        self._last = ""

    def reporter(self, index: int, label: str) -> Callable[[float], None]:
        """A callback taking the fraction of run ``index`` that is done."""

        def report(fraction: float) -> None:
            filled = int(round(fraction * WIDTH))
            line = (
                f"[{index + 1:>{len(str(self.total))}}/{self.total}] {label} "
                f"|{'#' * filled}{'.' * (WIDTH - filled)}| {fraction * 100:3.0f}%"
            )
            if self._tty:
                self.stream.write("\r" + line.ljust(len(self._last)))
            elif fraction >= 1.0:
                self.stream.write(line + "\n")  # no redraw on a pipe: one line per run
            self._last = line
            self.stream.flush()

        return report

    def close(self) -> None:
        if self._tty and self._last:
            self.stream.write("\n")
            self.stream.flush()
