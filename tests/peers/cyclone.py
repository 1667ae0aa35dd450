"""Drive a stock Cyclone DDS participant (``cyclone_participant.py``) inside a namespace.

Cyclone is observed only through its discovery trace (reading DCPSParticipant from Python
aborts cyclonedds 11.0.1 with a double free). The lines that matter:

    SPDP ST0 <prefix>:1c1 bes <hex> NEW (data <locs> meta <locs>) QOS={...}   accepted
    SPDP ST3 <prefix>:1c1ddsi_delete_proxy_participant_by_guid(...) - deleting   disposed
    broadcasted SPDP packet -> answering                                        will reply
    PARTICIPANT <own prefix>:1c1 QOS={...liveliness=0:<lease ns>...}            its own QoS

Every wait has a deadline and polls the file; nothing sleeps a fixed long time.
"""

from __future__ import annotations

import os
import re
import select
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType
from typing import Final

from swarmd_lab.netns import Namespace

from swarmd.rtps import GuidPrefix

SCRIPT: Final = Path(__file__).with_name("cyclone_participant.py")
START_TIMEOUT_S: Final = 20.0  # importing cyclonedds and creating a domain: ~0.5 s here
POLL_S: Final = 0.02


class CycloneError(AssertionError):
    """The Cyclone peer did not do what the test waited for (message says what and where)."""


def spdp_new_pattern(prefix: GuidPrefix) -> re.Pattern[str]:
    """Cyclone accepted the participant ``prefix`` (ddsi_discovery_spdp.c handle_spdp_alive)."""
    return re.compile(
        rf"SPDP ST0 {re.escape(str(prefix))}:1c1 bes (?P<bes>[0-9a-f]+) NEW"
        rf" \((?P<locators>[^)]*)\) QOS=\{{(?P<qos>.*)\}}$"
    )


def spdp_deleted_pattern(prefix: GuidPrefix) -> re.Pattern[str]:
    """Cyclone deleted the proxy participant ``prefix`` after its DATA(p[UD])."""
    return re.compile(rf"SPDP ST3 {re.escape(str(prefix))}:1c1.*- deleting")


def own_participant_pattern(prefix: GuidPrefix) -> re.Pattern[str]:
    return re.compile(rf"PARTICIPANT {re.escape(str(prefix))}:1c1 QOS=\{{(?P<qos>.*)\}}$")


@dataclass
class CycloneTrace:
    """Cyclone's trace file, read incrementally."""

    path: Path
    _lines: list[str] = field(default_factory=list)
    _offset: int = 0
    _partial: str = ""

    def lines(self) -> list[str]:
        """Every complete line written so far."""
        try:
            with self.path.open("r", encoding="utf-8", errors="replace") as fh:
                fh.seek(self._offset)
                chunk = fh.read()
                self._offset = fh.tell()
        except FileNotFoundError:
            return self._lines
        text = self._partial + chunk
        *complete, self._partial = text.split("\n")
        self._lines.extend(complete)
        return self._lines

    def search(self, pattern: re.Pattern[str]) -> re.Match[str] | None:
        for line in self.lines():
            match = pattern.search(line)
            if match is not None:
                return match
        return None

    def wait_for(self, pattern: re.Pattern[str], timeout: float, what: str) -> re.Match[str]:
        """The first line matching ``pattern``; raise ``CycloneError`` after ``timeout`` s."""
        deadline = time.monotonic() + timeout
        while True:
            match = self.search(pattern)
            if match is not None:
                return match
            if time.monotonic() >= deadline:
                spdp = [line for line in self.lines() if "SPDP" in line][-10:]
                raise CycloneError(
                    f"Cyclone trace {self.path} shows no {what} within {timeout:.0f} s "
                    f"(pattern {pattern.pattern!r}); last SPDP lines: {spdp}"
                )
            time.sleep(POLL_S)


class CyclonePeer:
    """One ``cyclone_participant.py`` process in ``ns``; use as a context manager.

    After ``start()``: ``prefix`` (its GUID prefix, from its own READY line) and
    ``version`` (the cyclonedds package version). ``stop()`` deletes the participant
    cleanly, so Cyclone sends DATA(p[UD]) before exiting.
    """

    def __init__(self, ns: Namespace, trace_path: Path, *, duration: float = 60.0) -> None:
        self.ns = ns
        self.trace = CycloneTrace(trace_path)
        self.duration = duration
        self.proc: subprocess.Popen[bytes] | None = None
        self.prefix = GuidPrefix(bytes(12))
        self.version = ""

    def start(self) -> CyclonePeer:
        env = dict(os.environ)
        env.pop("CYCLONEDDS_URI", None)  # the script builds its own configuration
        argv = [
            sys.executable,
            str(SCRIPT),
            "--trace",
            str(self.trace.path),
            "--interface",
            self.ns.ifname,
            "--duration",
            str(self.duration),
        ]
        self.proc = self.ns.popen(argv, env=env, stdin=subprocess.PIPE, stdout=subprocess.PIPE)
        line = self._read_line(START_TIMEOUT_S)
        words = line.split()
        if len(words) != 3 or words[0] != "READY":
            self.stop()
            raise CycloneError(f"{SCRIPT.name} in {self.ns.name} printed {line!r}, not READY")
        self.prefix = GuidPrefix.parse(words[1])
        self.version = words[2]
        return self

    def _read_line(self, timeout: float) -> str:
        assert self.proc is not None and self.proc.stdout is not None
        ready, _, _ = select.select([self.proc.stdout], [], [], timeout)
        if not ready:
            raise CycloneError(f"{SCRIPT.name} in {self.ns.name} not ready within {timeout:.0f} s")
        return self.proc.stdout.readline().decode(errors="replace").strip()

    def stop(self, timeout: float = 10.0) -> int:
        """Ask the participant to leave (stdin EOF) and wait; kill it after ``timeout``."""
        if self.proc is None:
            return 0
        proc, self.proc = self.proc, None
        if proc.stdin is not None:
            proc.stdin.close()
        try:
            code = proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            proc.kill()
            code = proc.wait(timeout=timeout)
        if proc.stdout is not None:
            proc.stdout.close()
        return code

    def __enter__(self) -> CyclonePeer:
        return self.start()

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.stop()
