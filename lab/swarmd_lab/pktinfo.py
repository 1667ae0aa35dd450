"""User ``nobody`` sending as another socket's address by ``IP_PKTINFO``/``IPV6_PKTINFO``
(docs/security.md, "The local user", residual (6); tests/test_sender_uid_first_contact.py,
bench/sender_uid_pktinfo_race.py). Needs root and ``setpriv``; loopback destinations only.

Each round binds ``bind:port`` (``IP_FREEBIND``/``IPV6_FREEBIND``, open to every user: any
address, local or not), waits ``wait_ms``, sends one datagram to ``dest:dest_port`` naming
``spoof`` as its source (ip(7) ``ipi_spec_dst``, ipv6(7) ``ipi6_addr``), closes the socket
and waits ``period_ms``. With ``hold`` the last round's socket stays open after it prints
"sent", until stdin closes (at most 30 s). A send that an nftables rule drops on the output
hook fails with ``EPERM``; the spoofer goes on and, after "sent", prints "refused N"
(swarmd local-firewall: tests/test_local_firewall_netns.py).
"""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Sequence
from typing import Final

NOBODY: Final = 65534
SPOOFER: Final = """
import select, socket, struct, sys, time
bind, port, dest, dest_port, spoof = sys.argv[1:6]
count, period_ms, wait_ms = int(sys.argv[6]), float(sys.argv[7]), float(sys.argv[8])
hold = sys.argv[9] == "1"
refused = 0
v6 = ":" in bind
if v6 and ":" not in dest:
    dest = "::ffff:" + dest  # an IPv4 destination from an IPv6 socket
for i in range(count):
    s = socket.socket(socket.AF_INET6 if v6 else socket.AF_INET, socket.SOCK_DGRAM)
    if v6:
        s.setsockopt(socket.IPPROTO_IPV6, 78, 1)  # IPV6_FREEBIND
        info = (socket.IPPROTO_IPV6, 50, socket.inet_pton(socket.AF_INET6, spoof) + bytes(4))
    else:
        s.setsockopt(socket.IPPROTO_IP, 15, 1)  # IP_FREEBIND
        info = (socket.IPPROTO_IP, 8, struct.pack("=i4s4s", 0, socket.inet_aton(spoof), bytes(4)))
    s.bind((bind, int(port)))
    time.sleep(wait_ms / 1000)
    try:
        s.sendmsg([b"spoof %d" % i], [info], 0, (dest, int(dest_port)))
    except PermissionError:  # a netfilter drop on the output hook
        refused += 1
    if hold and i == count - 1:
        break
    s.close()
    time.sleep(period_ms / 1000)
print("sent", flush=True)
if refused:
    print("refused", refused, flush=True)
if hold:
    select.select([sys.stdin], [], [], 30.0)
"""


def nobody_spoofs(
    bind: str,
    port: int,
    dest: tuple[str, int],
    spoof: str,
    *,
    count: int = 1,
    period_ms: float = 0.0,
    wait_ms: float = 0.0,
    hold: bool = False,
    within: Sequence[str] = (),
) -> subprocess.Popen[str]:
    """``SPOOFER`` as user ``nobody``, started (stdin and stdout piped); the caller reads
    its "sent" line and closes its stdin (``communicate``) or kills it. ``within``: an argv
    prefix that runs it elsewhere (``Namespace.command([])``: in a test's namespace)."""
    argv = [*within, "setpriv", f"--reuid={NOBODY}", f"--regid={NOBODY}", "--clear-groups"]
    argv += [sys.executable, "-I", "-c", SPOOFER, bind, str(port), dest[0], str(dest[1])]
    argv += [spoof, str(count), str(period_ms), str(wait_ms), "1" if hold else "0"]
    return subprocess.Popen(  # noqa: S603 - fixed argv
        argv, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True
    )
