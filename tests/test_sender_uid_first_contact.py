"""First contact of a node under a local user's flood, on real sockets (swarmd.senderuid,
"First contact"; docs/security.md, "The local user"): the kernel's one-socket answer and the
source's query, what Linux answers for a port two uids share, and a spoof by ``IP_PKTINFO``
from the node's port at another address (refused while the spoofer's socket lives; open
when it closes the socket before the lookup). Split from tests/test_sockdiag.py (its helpers).
"""

from __future__ import annotations

import os
import random
import shutil
import socket
import subprocess
from collections.abc import Callable
from typing import Any

import pytest
from swarmd_lab.pktinfo import nobody_spoofs

import swarmd.sockdiag
from swarmd.senderuid import (
    COST_SHARE,
    MISS_QUERY_BURST,
    RECEIVER_COST_BURST_S,
    RECEIVER_COST_SHARE,
    TTL_S,
    SenderUids,
)
from tests.test_sockdiag import (
    ME,
    NOBODY,
    _bind,
    _free_port,
    _huge_table_lookup,
    _HugeTable,
    _nobody_binds,
)


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


def _nobody_spoofs(
    bind: str, port: int, dest: tuple[str, int], spoof: str, hold: bool
) -> subprocess.Popen[str]:
    """One datagram from ``nobody``'s socket at ``bind:port`` naming ``spoof`` as its
    source (swarmd_lab.pktinfo), sent; the caller closes its stdin (``communicate``)."""
    sender = nobody_spoofs(bind, port, dest, spoof, hold=hold)
    assert sender.stdout is not None
    line = sender.stdout.readline().strip()
    if line != "sent":
        sender.kill()
        sender.communicate(timeout=10)
    assert line == "sent"
    return sender


class _Log:
    """A structlog-style logger that keeps its warnings."""

    def __init__(self) -> None:
        self.warnings: list[tuple[str, dict[str, object]]] = []

    def warning(self, event: str, **fields: object) -> None:
        self.warnings.append((event, fields))


# (the node's address, the attacker's bound address, and the address its datagram names)
SPOOFS = {
    "v4-other-loopback": ("127.0.0.1", "127.0.0.2", "127.0.0.1"),
    "v4-not-loopback": ("127.0.0.1", "198.51.100.7", "127.0.0.1"),
    "v6-other-address": ("::1", "2001:db8::7", "::1"),
    "v4-by-a-v4-mapped-v6-socket": ("127.0.0.1", "::ffff:127.0.0.2", "::ffff:127.0.0.1"),
}


@pytest.mark.parametrize("netlink", [True, False], ids=["netlink", "proc"])
@pytest.mark.parametrize("case", list(SPOOFS))
def test_a_socket_at_another_address_on_a_nodes_port_cannot_send_as_the_node(
    case: str, netlink: bool
) -> None:
    """Attack (found this session; docs/security.md, "The local user", residual (6)):
    ``nobody`` binds the node's port at another address (another of 127/8, one not on this
    computer by IP_FREEBIND, an IPv6 one, a v4-mapped one on a dual-stack IPv6 socket; Linux
    allows each beside the node's) and sends with ``IP_PKTINFO``/``IPV6_PKTINFO`` naming
    the node's address: the kernel sends it from the node's address and port (no
    privilege: the address is local). On main every reading of the table (dump, query,
    one-socket answer, /proc) named the node: the datagram passed as the node's. Now every
    socket on the port that can send from the source's family counts, at any address: the
    port is two uids', the answer None, counted ``port_shared`` and logged once."""
    if os.geteuid() != 0 or shutil.which("setpriv") is None:
        pytest.skip("needs root and setpriv")
    node_host, bind, spoof = SPOOFS[case]
    port = _free_port()
    with _bind(node_host, port) as node, _bind(node_host, 0) as daemon:
        daemon.settimeout(5.0)
        sender = _nobody_spoofs(bind, port, daemon.getsockname()[:2], spoof, hold=True)
        try:
            _data, source = daemon.recvfrom(64)
            assert source[:2] == (node_host, node.getsockname()[1])  # the precondition
            log = _Log()
            uids = SenderUids(netlink=netlink, keep_uids={ME}, log=log)
            assert uids.uid_of(source) is None  # on main: ME, the node's
            assert uids.uid_of(source) is None
            assert uids.counters["port_shared"] == 2
            assert log.warnings == [
                (
                    "sender_port_shared",
                    {
                        "host": node_host, "port": port, "taken_uids": [ME],
                        "other_uids": [NOBODY], "fix": log.warnings[0][1]["fix"],
                    },
                )
            ]  # fmt: skip
        finally:
            sender.communicate(timeout=10)


def test_a_kept_node_is_rechecked_within_ttl_when_its_port_gains_another_owner() -> None:
    """A node found and kept (``keep_uids``) is answered from its own query every
    ``TTL_S``: once ``nobody`` binds the node's port at another address, the node's next
    datagram after the kept answer's ``TTL_S`` is nobody's (on main: the node's for as long
    as both sockets live, the query reading the node's address and wildcards only). Within
    ``TTL_S`` the kept answer stands: the window this leaves (docs/security.md)."""
    if os.geteuid() != 0 or shutil.which("setpriv") is None:
        pytest.skip("needs root and setpriv")
    now = [100.0]
    uids = SenderUids(clock=lambda: now[0], netlink=True, keep_uids={ME})
    port = _free_port()
    with _bind("127.0.0.1", port):
        source = ("127.0.0.1", port)
        assert uids.uid_of(source) == ME  # found, kept
        holder = _nobody_binds(f"127.0.0.2,{port},0")
        try:
            now[0] += TTL_S / 2
            assert uids.uid_of(source) == ME  # the kept answer, still fresh
            now[0] += TTL_S / 2
            assert uids.uid_of(source) is None  # its re-check: two uids
            assert uids.counters["port_shared"] == 1
        finally:
            holder.communicate(timeout=10)
        now[0] += TTL_S
        assert uids.uid_of(source) == ME  # the port the node's alone again


@pytest.mark.xfail(
    strict=True,
    reason="the lookup alone cannot see it; the nftables rule closes it: "
    "tests/test_local_firewall_netns.py (docs/security.md, The local user, residual (6))",
)
def test_a_sender_that_closes_its_socket_at_once_is_not_seen() -> None:
    """Still open: ``nobody`` binds the node's port at 127.0.0.2, sends as 127.0.0.1 by
    ``IP_PKTINFO`` and closes the socket before the lookup runs. The table no longer holds
    it, so the lookup names the node: the datagram passes as the node's. A table read only
    sees sockets alive when it runs (module docstring of swarmd.senderuid). Where the unit
    loads ``swarmd local-firewall``'s table, the kernel drops it at send time instead
    (tests/test_local_firewall_netns.py); this stays the lookup's own limit."""
    if os.geteuid() != 0 or shutil.which("setpriv") is None:
        pytest.skip("needs root and setpriv")
    port = _free_port()
    with _bind("127.0.0.1", port) as node, _bind("127.0.0.1", 0) as daemon:
        daemon.settimeout(5.0)
        sender = _nobody_spoofs("127.0.0.2", port, daemon.getsockname(), "127.0.0.1", False)
        sender.communicate(timeout=10)  # exited: its socket closed
        _data, source = daemon.recvfrom(64)
        assert source == ("127.0.0.1", node.getsockname()[1])  # the precondition: spoofed
        uids = SenderUids(netlink=True, keep_uids={ME})
        assert uids.uid_of(source) is None  # today: ME, the node's


# A one-socket lookup's walk past ~19,000 of another user's SO_REUSEADDR sockets on the
# flood's address and port (bench/sender_uid_receiver_walk.py: linear in them)
LONG_WALK_S = 0.0005


class _LongChain(_HugeTable):
    """``_HugeTable`` whose one-socket lookup walks a long hash chain: on the cost clock."""

    def receiver(
        self, family: int, address: bytes, port: int, peer: Any = None
    ) -> swarmd.sockdiag.UdpRow | None:
        _HugeTable.spent[0] += LONG_WALK_S
        return super().receiver(family, address, port, peer)


def test_a_flood_from_a_port_with_a_long_hash_chain_costs_a_bounded_share_of_a_core(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Attack (a local user against the one-socket lookup's cap): ``nobody`` binds ~19,000
    sockets with SO_REUSEADDR to 127.0.0.1:P (and holds enough elsewhere to cut every
    dump), then floods from P. Each datagram misses the cut table, so each asks the kernel's
    one-socket answer, which walks all of them (not the ~8 us of sockets spread over
    addresses). On main that lookup was capped by count only (50,000 a second): 20 lookups
    a virtual millisecond for 10 virtual seconds cost 100 s of walks, ten cores. Now its
    measured cost is capped too, at RECEIVER_COST_SHARE of the time; the table's reads and
    queries keep their own share; a kept node is still answered at every datagram."""
    now = [100.0]
    uids = _huge_table_lookup(monkeypatch, now, keep_uids=frozenset({ME}))
    uids._diag = _LongChain()  # type: ignore[assignment]
    _HugeTable.owners = {5000: ME, 40_000: NOBODY}
    while uids.uid_of(("127.0.0.1", 5000)) != ME and now[0] < 105.0:  # the node, kept
        now[0] += 0.01
    assert uids.uid_of(("127.0.0.1", 5000)) == ME
    start, spent_before = now[0], _HugeTable.spent[0]
    answered = 0
    for ms in range(10_000):
        now[0] += 0.001
        for _ in range(20):
            assert uids.uid_of(("127.0.0.1", 40_000)) in (None, NOBODY)  # never the node
        if ms % 10 == 0:
            answered += uids.uid_of(("127.0.0.1", 5000)) == ME
    elapsed = now[0] - start
    walks = uids.counters["receiver_us"] / 1e6
    assert walks <= RECEIVER_COST_SHARE * elapsed + RECEIVER_COST_BURST_S + LONG_WALK_S, walks
    share = COST_SHARE + RECEIVER_COST_SHARE
    assert _HugeTable.spent[0] - spent_before <= share * elapsed + 0.04 + 0.05 + 0.5 + 0.2
    assert uids.counters["receiver_over_budget"] > 0
    assert answered == 1000  # the kept node: every one of its datagrams


def test_a_new_node_is_found_within_seconds_under_a_long_hash_chain_flood(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Review 14, the cost cap's residual: under the flood above (20 lookups a virtual
    millisecond, each walk LONG_WALK_S), a node that appears later and sends every 10 ms
    (its datagrams at a seeded place among the flood's) is found only when its datagram is
    the first to find the one-socket lookup's bucket refilled (the miss path is the
    flood's): a chance of about RECEIVER_COST_SHARE / LONG_WALK_S over the flood's rate a
    datagram (here ~800 walks a second against 20,000 lookups: about 1 in 25), so it
    waits, a geometric time, not a hard bound (seed 0: found after 0.42 s, 42 datagrams
    dropped; docs/security.md, "Residual risks: the local user"). Pinned: found within
    FOUND_WITHIN_S, by the one-socket lookup (the miss path stays the flood's)."""
    rng = random.Random(0)
    now = [100.0]
    uids = _huge_table_lookup(monkeypatch, now, keep_uids=frozenset({ME}))
    uids._diag = _LongChain()  # type: ignore[assignment]
    _HugeTable.owners = {40_000: NOBODY, 7000: ME}
    for _ in range(2000):  # the flood's first 2 s: the buckets spent
        now[0] += 0.001
        for _ in range(20):
            uids.uid_of(("127.0.0.1", 40_000))
    found_after = None
    for ms in range(round(FOUND_WITHIN_S * 1000)):
        now[0] += 0.001
        node_at = rng.randrange(21) if ms % 10 == 0 else -1
        for i in range(21):
            if i == node_at and uids.uid_of(("127.0.0.1", 7000)) == ME:
                found_after = ms / 1000.0
            elif i != node_at and i < 20:
                assert uids.uid_of(("127.0.0.1", 40_000)) in (None, NOBODY)
        if found_after is not None:
            break
    assert found_after is not None  # within FOUND_WITHIN_S
    # the seed's wait, cited in docs/security.md: a change of the lookup's budgets moves it
    # (re-measure here and update the docs)
    assert found_after == pytest.approx(0.42)
    assert uids.counters["receiver_confirmed"] == 1


FOUND_WITHIN_S = 5.0

SHARED_PORT = 6000  # a node's port that ``nobody`` binds too, at another address


class _SharedPort(_HugeTable):
    """``_HugeTable`` where ``nobody`` also holds SHARED_PORT at another address (it sends
    from the node's source there by ``IP_PKTINFO``): the kernel's one-socket answer names
    the node (the socket bound to the source's address), the port's query both users
    while ``held``."""

    held = True

    def rows(
        self, family: int, port: int, max_rows: int, addresses: Any = None, enough: Any = None
    ) -> tuple[list[swarmd.sockdiag.UdpRow], bool]:
        rows, more = super().rows(family, port, max_rows, addresses, enough)
        if port == SHARED_PORT and family == socket.AF_INET and _SharedPort.held:
            raw = socket.inet_aton("127.0.0.2")
            rows = [*rows, swarmd.sockdiag.UdpRow(socket.AF_INET, raw, port, NOBODY, 2)]
        return rows, more


def test_a_user_sharing_one_nodes_port_cannot_starve_the_other_kept_sources(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Attack (a local user against the kept priority): ``nobody`` binds node B's port at
    127.0.0.2 (a denial of B, counted ``port_shared``) and floods from B's own source
    127.0.0.1:P by ``IP_PKTINFO``, beside a table large enough to hold the reads back. Each
    datagram missed the stale table, the one-socket answer named B's socket, and B's port
    was queried at the kept sources' priority: the flood held the cost bucket at the kept
    debt, so node A's re-checks (a kept source, another port) found no budget and A's
    datagrams were dropped (on main: 0 of 1,000 answered after the first). Now a kept-
    priority confirmation that found the port shared is remembered for TTL_S: the flood
    spends one query per TTL_S on it, and A is answered at every datagram."""
    node_b = ("127.0.0.1", SHARED_PORT)
    now, uids, answered = _node_a_beside_a_flood(monkeypatch, lambda _: node_b)
    assert answered == 1000  # A: every one of its datagrams
    assert uids.counters["port_shared"] >= 200_000  # the denial of B, counted each time
    _SharedPort.held = False  # nobody closes its socket: B is B's again within TTL_S
    now[0] += TTL_S
    assert uids.uid_of(node_b) == ME


def test_a_user_sharing_a_nodes_wildcard_port_cannot_evict_the_shared_memory(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Attack (a local user against the shared-source memory's cap, review 14): node B
    holds its port on the wildcard (with SO_REUSEADDR, so ``nobody`` binds it too, at
    127.0.0.2). Every 127.0.0.N is then a source whose one-socket answer names B, and the
    memory was keyed by address and port: ``nobody`` flooding from SOURCES addresses, more
    than the memory's 64, evicted each entry before its turn came again, so each datagram
    was a kept-priority query again, as before the memory, and node A's re-checks starved
    (on main: A answered 50 of 1,000). The port's query does not depend on the source's
    address within a family (swarmd.senderuid, ``_V4_SENDING_V6``), so the memory keys by
    family and port: one entry for the flood, A answered at every datagram."""
    sources = 65  # one past the memory's cap (MAX_KEPT_SOURCES)
    _, _, answered = _node_a_beside_a_flood(
        monkeypatch, lambda n: (f"127.0.0.{3 + n % sources}", SHARED_PORT)
    )
    assert answered == 1000  # A: every one of its datagrams


def _node_a_beside_a_flood(
    monkeypatch: pytest.MonkeyPatch, flood: Callable[[int], tuple[str, int]]
) -> tuple[list[float], SenderUids, int]:
    """Node A found and kept, then ``nobody``'s flood from B's shared port (``_SharedPort``,
    held): 20 datagrams a virtual millisecond for 10 s, the nth from ``flood(n)``, each
    nobody's (never B), and one of A's every 10 ms. Returns the clock, the lookup and how
    many of A's 1,000 were answered as A's."""
    now = [100.0]
    uids = _huge_table_lookup(monkeypatch, now, keep_uids=frozenset({ME}))
    uids._diag = _SharedPort()  # type: ignore[assignment]
    _SharedPort.held = True
    _HugeTable.owners = {5000: ME, SHARED_PORT: ME}
    node_a = ("127.0.0.1", 5000)
    while uids.uid_of(node_a) != ME and now[0] < 105.0:  # A found and kept
        now[0] += 0.01
    assert uids.uid_of(node_a) == ME
    answered = 0
    for ms in range(10_000):
        now[0] += 0.001
        for i in range(20):
            assert uids.uid_of(flood(ms * 20 + i)) is None  # B's port is shared: never B
        if ms % 10 == 0:
            answered += uids.uid_of(node_a) == ME
    return now, uids, answered
