"""First contact of a node under a local user's flood, on real sockets (swarmd.senderuid,
"First contact"; docs/security.md, "The local user"): the kernel's one-socket answer and the
source's query, what Linux answers for a port two uids share, and a spoof by ``IP_PKTINFO``
that no reading of the table can tell (open). Split from tests/test_sockdiag.py (its helpers).
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys

import pytest

from swarmd.senderuid import MISS_QUERY_BURST, TTL_S, SenderUids
from tests.test_sockdiag import ME, NOBODY, _bind, _free_port, _nobody_binds


def test_a_kept_users_new_source_is_found_past_a_spent_miss_budget_and_shares_stay_nobodys() -> (
    None
):
    """Attack (a local user against first contact): a flood of fresh ports spends the miss
    budget, so a node that bound its port after the last table read was dropped until the
    next read (on main: None here, the table read being fresh). A miss of a ``keep_uids``
    user's source is now the kernel's one-socket answer ("which socket would receive a
    reply to this source") and then the source's filtered query, outside the miss budget.
    The one-socket answer is never taken alone: Linux gives a port two uids share with
    SO_REUSEADDR to the newest socket, so it names one of them (either order here, and a
    wildcard beside the address); the query finds both, and the source stays nobody's.
    Another user's source and a port nobody holds go the miss path, as before; so does a
    connected sender unless the caller names the address it is connected to."""
    if os.geteuid() != 0 or shutil.which("setpriv") is None:
        pytest.skip("needs root and setpriv")
    now = [100.0]
    uids = SenderUids(clock=lambda: now[0], netlink=True, keep_uids={ME})
    assert uids.uid_of(("127.0.0.1", 9)) is None  # the table read, before anyone binds
    p = {name: _free_port() for name in ("node", "node6", "v6only", "first", "last", "wild")}
    theirs = _free_port()
    mine = [
        _bind("127.0.0.1", p["node"]), _bind("::1", p["node6"]), _bind("127.0.0.1", p["v6only"]),
        _bind("127.0.0.1", p["first"], reuse=True), _bind("127.0.0.1", p["wild"], reuse=True),
    ]  # fmt: skip
    holder = _nobody_binds(
        f"::,{p['v6only']},v6only", f"127.0.0.1,{p['first']},1", f"127.0.0.1,{p['last']},1",
        f"0.0.0.0,{p['wild']},1", f"127.0.0.1,{theirs},0",
    )  # fmt: skip
    try:
        mine.append(_bind("127.0.0.1", p["last"], reuse=True))  # the newest: root's
        now[0] += TTL_S / 2
        for fresh in range(1, int(MISS_QUERY_BURST) + 20):  # ports below 1024 nobody holds
            assert uids.uid_of(("127.0.0.1", fresh)) is None
        assert uids.counters["miss_reads_over_budget"] > 0  # the precondition: spent
        answers = {
            name: uids.uid_of(("::1", port, 0, 0) if name == "node6" else ("127.0.0.1", port))
            for name, port in p.items()
        }
        assert answers == {
            "node": ME, "node6": ME, "v6only": ME,  # nobody's [::] v6-only cannot send IPv4
            "first": None, "last": None, "wild": None,  # a port two uids hold
        }  # fmt: skip
        assert uids.uid_of(("127.0.0.1", theirs)) is None  # nobody's: the spent miss budget
        assert uids.counters["receiver_confirmed"] == 5  # all but "first" (nobody's answer)
        # a connected sender (PX4's XRCE-DDS client connects to the agent) is found when
        # the caller names its own socket (a wildcard: the source's address), else not
        client = _bind("127.0.0.1", 0)
        mine.append(client)
        client.connect(("127.0.0.1", 7))
        source = ("127.0.0.1", client.getsockname()[1])
        assert uids.uid_of(source) is None
        assert uids.uid_of(source, ("0.0.0.0", 7)) == ME  # noqa: S104 - a bound address
        assert uids.counters["receiver_refused"] == 0
    finally:
        holder.communicate(timeout=10)
        for s in mine:
            s.close()


# Run as ``nobody``: binds 127.0.0.2:P (beside a node's 127.0.0.1:P: other addresses,
# Linux allows it) and sends one datagram to 127.0.0.1:DEST from 127.0.0.1 by IP_PKTINFO's
# ipi_spec_dst (ip(7)); prints "sent".
PKTINFO_SENDER = """
import socket, struct, sys
port, dest = int(sys.argv[1]), int(sys.argv[2])
s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
s.bind(("127.0.0.2", port))
info = struct.pack("=i4s4s", 0, socket.inet_aton("127.0.0.1"), bytes(4))
s.sendmsg([b"as the node"], [(socket.IPPROTO_IP, 8, info)], 0, ("127.0.0.1", dest))
print("sent", flush=True)
"""


@pytest.mark.xfail(strict=True, reason="open: docs/security.md, The local user, residual (6)")
def test_a_socket_at_another_address_on_a_nodes_port_cannot_send_as_the_node() -> None:
    """Attack found this session, not defended: ``nobody`` binds the node's port at another
    loopback address and sends with ``IP_PKTINFO`` (8) naming the node's address as the
    source; the kernel sends it from the node's address and port (no privilege: the
    address is local). Every reading of the table names the node for that source, so the
    datagram passes as the node's. It should be nobody's (two uids can send from it)."""
    if os.geteuid() != 0 or shutil.which("setpriv") is None:
        pytest.skip("needs root and setpriv")
    port = _free_port()
    with _bind("127.0.0.1", port) as node, _bind("127.0.0.1", 0) as daemon:
        daemon.settimeout(5.0)
        sent = subprocess.run(  # noqa: S603 - fixed argv
            [
                "setpriv", f"--reuid={NOBODY}", f"--regid={NOBODY}", "--clear-groups",  # noqa: S607
                sys.executable, "-I", "-c", PKTINFO_SENDER, str(port),
                str(daemon.getsockname()[1]),
            ],
            capture_output=True, text=True, timeout=30, check=True,
        )  # fmt: skip
        assert sent.stdout.strip() == "sent"
        _data, source = daemon.recvfrom(64)
        assert source == ("127.0.0.1", node.getsockname()[1])  # the precondition: spoofed
        uids = SenderUids(netlink=True, keep_uids={ME})
        assert uids.uid_of(source) is None  # today: ME, the node's
