"""sd_notify(3) without libsystemd: one datagram per state change to ``$NOTIFY_SOCKET``.

The protocol is newline-separated ``KEY=VALUE`` lines in one AF_UNIX datagram; a leading
``@`` in the socket path names the abstract namespace. With ``WatchdogSec=`` systemd exports
``WATCHDOG_USEC`` (and ``WATCHDOG_PID``) and expects ``WATCHDOG=1`` at least that often;
sd_watchdog_enabled(3) recommends pinging at half the interval. Sends never block and never
raise: a daemon must not die because its supervisor went away.
"""

from __future__ import annotations

import os
import socket
from collections.abc import Mapping
from typing import Final

WATCHDOG_FRACTION: Final = 0.5  # sd_watchdog_enabled(3): ping at half of WATCHDOG_USEC


def watchdog_interval_s(
    env: Mapping[str, str] | None = None, pid: int | None = None
) -> float | None:
    """Seconds between ``WATCHDOG=1`` pings, or None when no watchdog is asked of this process."""
    env = os.environ if env is None else env
    usec = env.get("WATCHDOG_USEC", "")
    if not usec.isdigit() or int(usec) == 0:
        return None
    target = env.get("WATCHDOG_PID", "")
    if target and target != str(os.getpid() if pid is None else pid):
        return None  # the watchdog is meant for another process (e.g. our parent)
    return int(usec) / 1e6 * WATCHDOG_FRACTION


class Notifier:
    """Sends sd_notify messages when ``NOTIFY_SOCKET`` is set; a no-op otherwise."""

    def __init__(self, env: Mapping[str, str] | None = None) -> None:
        env = os.environ if env is None else env
        path = env.get("NOTIFY_SOCKET", "")
        self.address: str | bytes | None = None
        if path.startswith("@"):
            self.address = b"\0" + path[1:].encode()
        elif path.startswith("/"):
            self.address = path
        self._sock: socket.socket | None = None
        self.errors = 0
        self.last_error: str | None = None

    @property
    def enabled(self) -> bool:
        return self.address is not None

    def send(self, **fields: str) -> bool:
        """Send ``KEY=VALUE`` lines (keys upper-cased); True when the datagram went out."""
        if self.address is None:
            return False
        # STATUS= is one line by protocol; a stray newline would start a bogus key
        payload = "\n".join(f"{k.upper()}={' '.join(v.split())}" for k, v in fields.items())
        try:
            if self._sock is None:
                self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC)
                self._sock.setblocking(False)
            self._sock.sendto(payload.encode(), self.address)
        except OSError as exc:
            self.errors += 1
            self.last_error = f"{type(exc).__name__}: {exc}"
            return False
        return True

    def ready(self, status: str | None = None) -> bool:
        return self.send(READY="1", **({"STATUS": status} if status else {}))

    def status(self, text: str) -> bool:
        return self.send(STATUS=text)

    def watchdog(self) -> bool:
        return self.send(WATCHDOG="1")

    def stopping(self, status: str | None = None) -> bool:
        return self.send(STOPPING="1", **({"STATUS": status} if status else {}))

    def close(self) -> None:
        if self._sock is not None:
            self._sock.close()
            self._sock = None
