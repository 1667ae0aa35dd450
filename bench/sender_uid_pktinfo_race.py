"""How often a spoof by ``IP_PKTINFO`` passes when the spoofer closes its socket at once
(docs/security.md, "The local user", residual (6)): user ``nobody`` binds a node's port at
another address (``127.0.0.2:P``, or ``[2001:db8::7]:P`` by ``IPV6_FREEBIND`` for
``--family 6``), sends one datagram naming the node's address as its source, and closes
the socket; ``--wait-ms`` after the bind first (a socket held that long before it sends).
``--count`` such datagrams, one every ``--period-ms``. This process holds the node's
socket and a receiving one (``--port``: its number, 0 any), and looks each datagram's
source up as the daemon does (``SenderUids``, netlink, taking the node's user, on the real
clock: the node found and kept first). Prints how many passed as the node's, and how many
the kernel refused at ``sendmsg`` (``EPERM``: an nftables drop). Needs root and setpriv;
loopback only.

``--firewall`` runs that race twice in a network namespace it creates (and removes on
every exit path: swarmd_lab.netns.Lan), on the port ``swarmd local-firewall`` guards for
the family (IPv4: the XRCE agent's, IPv6: the ROS 2 relay's; swarmd_lab.pktinfo.GUARDED):
first the lookup alone, then with the table ``swarmd local-firewall --apply`` loads there.
Prints both rows and what ``--check`` reads from the rule's counter. ``--backend`` picks
how the table loads (swarmd_lab.pktinfo.backend_tools): ``nft`` (the default), ``iptables``
by the legacy x_tables tools (the Jetson Nano's path), or ``auto`` behind an ``nft`` that is
refused as on a kernel without nf_tables.

    .venv/bin/python bench/sender_uid_pktinfo_race.py [--family 4] [--count 200] \
        [--firewall [--backend nft|iptables|auto]]
"""

from __future__ import annotations

import argparse
import os
import signal
import socket
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path
from typing import NoReturn

ROOT = Path(__file__).resolve().parent.parent
sys.path[:0] = [str(ROOT), str(ROOT / "lab")]

from swarmd_lab.netns import Lan  # noqa: E402
from swarmd_lab.pktinfo import (  # noqa: E402
    BACKENDS,
    GUARDED,
    backend_tools,
    local_firewall,
    nobody_spoofs,
)

from swarmd.senderuid import TTL_S, SenderUids  # noqa: E402

MAX_COUNT = 2_000
RECV_TIMEOUT_S = 2.0
SPOOFER_SLACK_S = 30.0  # beyond the spoofer's own schedule (count x (period + wait))


def race(family: int, count: int, period_ms: float, wait_ms: float, port: int) -> str:
    """The race, in this process's namespace; its result row."""
    node_host, bind = ("127.0.0.1", "127.0.0.2") if family == 4 else ("::1", "2001:db8::7")
    af = socket.AF_INET if family == 4 else socket.AF_INET6
    with (
        socket.socket(af, socket.SOCK_DGRAM) as node,
        socket.socket(af, socket.SOCK_DGRAM) as daemon,
    ):
        node.bind((node_host, 0))
        daemon.bind((node_host, port))
        daemon.settimeout(RECV_TIMEOUT_S)
        port, dest = node.getsockname()[1], daemon.getsockname()[1]
        uids = SenderUids(netlink=True, keep_uids={os.geteuid()})
        node.sendto(b"node", (node_host, dest))  # the node's own: a table there lets it pass
        _data, source = daemon.recvfrom(64)
        assert uids.uid_of(source) == os.geteuid()  # found and kept
        answers: Counter[str] = Counter()
        with nobody_spoofs(
            bind, port, (node_host, dest), node_host, count=count,
            period_ms=period_ms, wait_ms=wait_ms,
        ) as spoofer:  # fmt: skip
            try:
                for _ in range(count):
                    _data, source = daemon.recvfrom(64)
                    uid = uids.uid_of(source)
                    answers["node's" if uid == os.geteuid() else str(uid)] += 1
            except TimeoutError:
                pass  # the rest never came (refused at sendmsg, or lost)
            try:
                out, _ = spoofer.communicate(
                    timeout=count * (period_ms + wait_ms) / 1000 + SPOOFER_SLACK_S
                )
            finally:
                spoofer.kill()
    words = out.split()  # "sent", then "refused N" when a rule dropped some
    refused = int(words[words.index("refused") + 1]) if "refused" in words else 0
    passed, denied = answers["node's"], answers["None"]
    other = count - passed - denied - refused
    shared, queries = uids.counters["port_shared"], uids.counters["port_queries"]
    return (
        f"spoofs: {count}, passed as the node's: {passed}, nobody's (None): {denied}, "
        f"refused at sendmsg (EPERM): {refused}, other: {other}; "
        f"port_shared: {shared}, port queries: {queries}"
    )


def _terminate(signum: int, _frame: object) -> NoReturn:
    raise SystemExit(128 + signum)  # unwinds the Lan: its namespaces go


def with_firewall(args: argparse.Namespace, count: int) -> None:
    """The race in a namespace of its own, without then with the guarded port's table."""
    guarded = GUARDED["xrce_agent_v4" if args.family == 4 else "ros2_relay_v6"]
    argv = [sys.executable, str(Path(__file__).resolve()), "--family", str(args.family)]
    argv += ["--count", str(count), "--period-ms", str(args.period_ms)]
    argv += ["--wait-ms", str(args.wait_ms), "--port", str(guarded.receiver[1])]
    timeout = count * (args.period_ms + args.wait_ms) / 1000 + 2 * SPOOFER_SLACK_S
    signal.signal(signal.SIGTERM, _terminate)
    started = time.monotonic()
    with Lan(1) as lan, tempfile.TemporaryDirectory() as tmp:
        how = backend_tools(args.backend, Path(tmp))
        if isinstance(how, str):
            sys.exit(f"--backend {args.backend} {how}")
        flags, env = how
        ns = lan.hosts[0]
        config = Path(tmp) / "swarmd.yaml"
        config.write_text(guarded.config)
        alone = ns.run(argv, timeout=timeout).stdout.splitlines()[-1]
        applied = local_firewall(ns, config, *flags, "--apply", env=env)
        if applied.returncode != 0:
            sys.exit(f"swarmd local-firewall --apply failed: {applied.stderr.strip()}")
        fenced = ns.run(argv, timeout=timeout).stdout.splitlines()[-1]
        check = local_firewall(ns, config, *flags, "--check", env=env).stdout
    elapsed = time.monotonic() - started
    print(f"# {' '.join(sys.argv)}  (TTL_S = {TTL_S}; one namespace; {elapsed:.1f} s)")
    print(f"swarmd local-firewall --apply: {applied.stdout.strip()}")
    print(f"lookup alone:      {alone}")
    print(f"with the firewall: {fenced}")
    dropped = [line.strip() for line in check.splitlines() if guarded.comment in line]
    print(f"swarmd local-firewall --check: {'; '.join(dropped) or check.strip()}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--family", type=int, choices=(4, 6), default=4)
    parser.add_argument("--count", type=int, default=200)
    parser.add_argument("--period-ms", type=float, default=20.0)
    parser.add_argument("--wait-ms", type=float, default=0.0)
    parser.add_argument("--port", type=int, default=0, help="the receiving port (0: any)")
    parser.add_argument(
        "--firewall", action="store_true", help="also with swarmd local-firewall, in a namespace"
    )
    parser.add_argument(
        "--backend",
        choices=BACKENDS,
        default="nft",
        help="with --firewall: nft, iptables (the legacy tools, as on the Nano), or auto with "
        "nft refused (default: nft)",
    )
    args = parser.parse_args()
    if os.geteuid() != 0:
        sys.exit("needs root (setpriv to user nobody)")
    count = min(args.count, MAX_COUNT)
    if args.firewall:
        with_firewall(args, count)
        return
    started = time.monotonic()
    row = race(args.family, count, args.period_ms, args.wait_ms, args.port)
    print(f"# {' '.join(sys.argv)}  (TTL_S = {TTL_S}; {time.monotonic() - started:.1f} s)")
    print(row)


if __name__ == "__main__":
    main()
