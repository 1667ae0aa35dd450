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

``GUARDED`` and ``local_firewall`` are the other half of that test and of
``bench/sender_uid_pktinfo_race.py --firewall``: a config whose port the table guards, and
``swarmd local-firewall`` run in a namespace (its own nftables tables; the host's ruleset
untouched); ``backend_tools`` makes it use the backend a drone would: nft, the legacy x_tables
iptables tools (the Jetson Nano's path), or those behind an ``nft`` that its kernel refuses.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Final

from swarmd_lab.configs import MINIMAL_CONFIG
from swarmd_lab.netns import Namespace

NOBODY: Final = 65534
RELAY_PORT: Final = 7399
AGENT_PORT: Final = 888


@dataclass(frozen=True, slots=True)
class Guarded:
    """A receiving port of swarmd that ``swarmd local-firewall`` guards, root its user."""

    config: str  # the whole config file
    receiver: tuple[str, int]  # the port's address and number
    bind: str  # the spoofer's other address on the node's port (same family)
    comment: str  # the rule's comment (``nft list``, ``--check``)


# family case -> the port: the ROS 2 relay on IPv6, the XRCE agent on IPv4
GUARDED: Final = {
    "ros2_relay_v6": Guarded(
        MINIMAL_CONFIG + f"ros2:\n  relay_port: {RELAY_PORT}\n  node_users: [root]\n",
        ("::1", RELAY_PORT),
        "2001:db8::7",
        "ros2.relay_port: ros2.node_users only",
    ),
    "xrce_agent_v4": Guarded(
        MINIMAL_CONFIG + "px4:\n  backend: xrce-agent\n"
        f"  connection: udp:127.0.0.1:{AGENT_PORT}\n  loopback_user: root\n",
        ("127.0.0.1", AGENT_PORT),
        "127.0.0.2",
        "px4.connection: px4.loopback_user only",
    ),
}


def local_firewall(
    ns: Namespace, config: Path, *flags: str, env: Mapping[str, str] | None = None
) -> subprocess.CompletedProcess[str]:
    """``swarmd local-firewall --config CONFIG FLAGS`` in ``ns`` (``--apply``: the unit's
    ``ExecStartPre``), run to completion (at most 60 s), output captured, not checked;
    ``env`` replaces the environment (a ``PATH`` that picks the firewall tools)."""
    argv = [sys.executable, "-m", "swarmd.cli.swarmd_main", "local-firewall"]
    return ns.run([*argv, "--config", str(config), *flags], check=False, timeout=60.0, env=env)


# what `nft -f` says on a kernel without nf_tables (EOPNOTSUPP from nfnetlink)
REFUSING_NFT: Final = """#!/bin/sh
echo "Error: Could not process rule: Operation not supported" >&2
exit 1
"""
LEGACY_TOOLS: Final = [
    f"{t}-legacy-{v}" for t in ("iptables", "ip6tables") for v in ("save", "restore")
]
BACKENDS: Final = ("nft", "iptables", "auto")


def backend_tools(name: str, tools: Path) -> tuple[tuple[str, ...], dict[str, str]] | str:
    """How to run ``swarmd local-firewall`` with backend ``name`` (``BACKENDS``): its flags
    and environment, or why it cannot run here (a missing tool). ``nft``: forced; ``iptables``:
    forced, the legacy tools under the plain names (``iptables-save`` -> ``iptables-legacy-
    save``, linked in the empty folder ``tools``); ``auto``: those, behind an ``nft`` that
    fails as a kernel without nf_tables makes it fail (``REFUSING_NFT``)."""
    if name == "nft":
        if shutil.which("nft") is None:
            return "needs nft (Debian: nftables)"
        return ("--backend", "nft"), dict(os.environ)
    missing = [tool for tool in LEGACY_TOOLS if shutil.which(tool) is None]
    if missing:
        return f"needs {', '.join(missing)} (Debian: iptables)"
    for tool in LEGACY_TOOLS:
        (tools / tool.replace("-legacy", "")).symlink_to(str(shutil.which(tool)))
    if name == "auto":
        (tools / "nft").write_text(REFUSING_NFT)
        (tools / "nft").chmod(0o755)
    path = f"{tools}{os.pathsep}{os.environ.get('PATH', '')}"
    flags = ("--backend", "iptables") if name == "iptables" else ()
    return flags, {**os.environ, "PATH": path}


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
