"""Who holds a UDP port: ``/proc/net/udp{,6}`` for the socket, ``/proc/*/fd`` for its process.

Issue 18: a local user who binds the PX4 link's port first stops swarmd from starting and
receives the autopilot's frames. When that happens anyway (swarmd started by hand, without
``swarmd-px4.socket``), start-up names the squatter in its one line: the socket's owner uid
comes from ``/proc/net/udp`` (readable by every user), the process from the
``socket:[INODE]`` link in some ``/proc/PID/fd`` (readable only for our own uid's processes,
or as root: otherwise the line says the pid was not readable).

Also used on a socket systemd passed us: a socket bound with ``SO_REUSEADDR`` (systemd sets
it on every socket it binds) lets any user bind the same address with ``SO_REUSEADDR`` too,
and Linux then delivers each datagram to the newest socket; such a co-bound socket is named
and refused the same way.
"""

from __future__ import annotations

import os
import pwd
from dataclasses import dataclass
from pathlib import Path
from typing import Final

from swarmd.loopback import proc_address, udp_table_rows

MAX_CMDLINE_CHARS: Final = 80  # one start-up line, not a process listing
MAX_PROCS_SCANNED: Final = 65536  # bounds the /proc walk (pid_max's default is 4 Mi)


@dataclass(frozen=True, slots=True)
class PortHolder:
    """A UDP socket bound to the port, and its process when we may see it."""

    address: str  # as bound: "127.0.0.1", "0.0.0.0", "::"
    port: int
    uid: int
    inode: int
    pid: int | None = None
    command: str | None = None

    def describe(self) -> str:
        try:
            user = pwd.getpwuid(self.uid).pw_name
        except KeyError:
            user = "?"
        who = f"user {user} (uid {self.uid})"
        if self.pid is None:
            return f"{who}, socket {self.address}:{self.port}, process not visible to us"
        return f"pid {self.pid} {who}: {self.command or '?'}"


def bound_sockets(proc: Path = Path("/proc")) -> list[PortHolder]:
    """Every bound UDP socket of this network namespace (IPv4 and IPv6)."""
    out: list[PortHolder] = []
    for table in ("udp", "udp6"):
        try:
            text = (proc / "net" / table).read_text()
        except OSError:
            continue  # no IPv6 in this kernel
        for address, port, uid, inode in udp_table_rows(text):
            try:
                out.append(PortHolder(proc_address(address), port, uid, inode))
            except ValueError:
                continue
    return out


def _overlaps(bound: str, host: str) -> bool:
    """Would a socket bound to ``bound`` take datagrams for ``host`` (or block its bind)?"""
    if bound in (host, "0.0.0.0", "::", f"::ffff:{host}"):  # noqa: S104 - a wildcard we read
        return True
    return host in ("0.0.0.0", "::")  # noqa: S104 - we would bind the wildcard ourselves


def holders(
    host: str, port: int, *, exclude_inode: int | None = None, proc: Path = Path("/proc")
) -> list[PortHolder]:
    """The sockets that take ``host:port``'s datagrams or block its bind, with their process."""
    found = [
        h
        for h in bound_sockets(proc)
        if h.port == port and h.inode != exclude_inode and _overlaps(h.address, host)
    ]
    if not found:
        return []
    wanted = {f"socket:[{h.inode}]": h for h in found if h.inode}
    named: dict[int, PortHolder] = {}
    for n, entry in enumerate(proc.iterdir()):
        if n >= MAX_PROCS_SCANNED or len(named) == len(wanted):
            break
        if not entry.name.isdigit():
            continue
        try:
            fds = list((entry / "fd").iterdir())
        except OSError:
            continue  # another user's process: not ours to look into
        for fd in fds:
            try:
                link = os.readlink(fd)
            except OSError:
                continue
            holder = wanted.get(link)
            if holder is not None and holder.inode not in named:
                named[holder.inode] = PortHolder(
                    holder.address,
                    holder.port,
                    holder.uid,
                    holder.inode,
                    int(entry.name),
                    _command(entry),
                )
    return [named.get(h.inode, h) for h in found]


def _command(entry: Path) -> str:
    try:
        raw = (entry / "cmdline").read_bytes()
    except OSError:
        return "?"
    text = raw.replace(b"\0", b" ").decode(errors="replace").strip()
    # a process names itself: keep the line one printable line
    text = "".join(c if c.isprintable() else "?" for c in text)
    if len(text) > MAX_CMDLINE_CHARS:
        text = text[: MAX_CMDLINE_CHARS - 3] + "..."
    return text or "?"


def describe(found: list[PortHolder]) -> str:
    """One phrase for a start-up line: "pid 42 user mallory (uid 1001): nc -ul 14540"."""
    return "; ".join(h.describe() for h in found) or "an unknown socket"
