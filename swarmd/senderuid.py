"""Which local user sent a loopback datagram: its source port's owner in the kernel's UDP
socket table (netlink ``sock_diag``, or ``/proc/net/udp{,6}`` when netlink is refused).

Daemon tier (an adapter's helper; the sans-IO cores get the answer, never this module).

Why it holds. A UDP datagram from a loopback source ``(A, P)`` was sent by a socket bound
to port ``P`` (an unbound socket is bound to the wildcard and a free port on its first
send), at *any* local address: ``IP_PKTINFO``'s ``ipi_spec_dst`` (ip(7)) and
``IPV6_PKTINFO`` (ipv6(7)) name any local source address, without privilege, whatever the
socket is bound to (tests/test_sender_uid_first_contact.py: ``127.0.0.2:P``, a non-loopback
address, ``fd00::2:P`` all sent as ``127.0.0.1:P`` or ``[::1]:P``). Only the family limits
it (``sends_from``): an IPv4 socket sends IPv4; an IPv6 socket bound to ``::`` (not
v6-only) or to a v4-mapped address sends both; one bound to another IPv6 address, or a
v6-only ``::``, IPv6 only (Linux: ``ENETUNREACH``). So a source is a uid's only when
*every* socket on ``P`` that can send from its family is that uid's: a port another user
binds anywhere is nobody's (a denial, counted ``port_shared`` and logged
``sender_port_shared``; never the other user passed as the node). ``/proc/net/udp`` and
``/proc/net/udp6`` list every socket of this network namespace with its local address,
port and owner uid, to every user (the unit's ``ProtectProc=invisible`` hides other users'
``/proc/PID``, not ``/proc/self/net``: systemd/swarmd.service). Where it cannot:

- the sender closed its socket before the lookup: the port is free, nothing is found, the
  answer is None (the caller drops it: a real node or PX4 keeps its socket); but when a
  node holds the port, a user who bound it at another address, sent by ``IP_PKTINFO`` and
  closed its socket at once is gone from the table and the node is named (open:
  docs/security.md, "The local user", residual (6); bench/sender_uid_pktinfo_race.py);
- two sockets of different uids hold the port (both ``SO_REUSEADDR``, or at two
  addresses): ambiguous, None;
- by /proc, a v6-only socket bound to ``::`` is not told from a dual-stack one (netlink
  tells it): another user's on a node's port makes the node's IPv4 datagrams ambiguous;
- a table read cut by a cap (below) may have left a second owner of a port unread: a
  source it names one owner for is asked by its own query (by /proc: nobody's);
- the table was read before the sender bound its port: a miss re-reads it, within a budget
  of ``MISS_READS_PER_S`` (burst ``MISS_READ_BURST``): a flood from fresh ports costs that
  many reads a second, not one per datagram, and while it spends the budget a new sender's
  first datagram can find nothing (it is dropped; nodes and PX4 resend), unless it is one
  of ``keep_uids`` and found by netlink ("First contact" below; a sender whose socket is
  connected to another peer than the wildcard is not: the miss path);
- a port held by a node when the table was read, then closed and bound by another user
  within ``TTL_S``: that user's datagrams pass as the node's for what is left of ``TTL_S``.
  The window is short and needs the exact port freed by the node (docs/security.md).

Every read is capped (``MAX_TABLE_BYTES``, ``MAX_INDEXED_SOCKETS``): a user opening sockets
by the ten thousand cuts the table read (counted ``truncated``), never grows memory. So
by netlink a miss after a cut read asks for its source, and a source answered as one of
``keep_uids`` (the users the caller takes) is kept and answered from its own query every
``TTL_S``, outside the table and the miss budget: such a user cannot hide a node or PX4
once found (tests/test_sockdiag.py). The cost is measured by ``bench/sender_uid.py``.

What it costs. A user holding ~34,000 sockets makes one dump cost 0.12-0.26 s and one query
2-8 ms (``bench/sender_uid_scale.py``): counted in calls, a dump each ``TTL_S`` and the miss
budget were most of a core. So every dump, /proc read and query (not the one-socket lookups
of "First contact", whose cost does not grow with the table) is charged its measured cost
(``cost_clock``, this thread's CPU time) to one bucket of seconds refilled at ``COST_SHARE``
of a core: over any ``T`` seconds the lookup works at most ``COST_SHARE * T`` plus
``COST_BURST_S``, ``KEPT_DEBT_S`` and one call. Who spends when it is short: a kept source's
re-check first (down to a debt of ``KEPT_DEBT_S``), then a due table read (down to
``READ_DEBT_S``), a miss only from what is saved; a read that came back cut is not repeated
before its cost is ``CUT_READ_SHARE`` of the share's worth (a cut read cannot answer what it
left; the sources' queries can). A table read older than ``TTL_S`` names nobody: while the
bucket or the back-off holds the next read, sources are answered by their queries or not at
all (dropped: nodes and PX4 resend), never from an old read.

First contact. A miss of a new sender of one of ``keep_uids`` must not wait for the miss
budget a flood spends, nor for a cut read to index it. So by netlink a miss first asks the
kernel which socket would receive a reply to its source (``UdpDiag.receiver``: the
delivery's own hashed lookup, ~8 us whatever the table holds, so outside the cost bucket;
at most ``RECEIVER_LOOKUPS_PER_S``, and at most ``RECEIVER_COST_SHARE`` of a core by their
measured cost: the lookup walks every socket bound to the source's address and port, and a
user binding 17,000 there with SO_REUSEADDR made each 0.34 ms and a flood from that port
spend the daemon's core, bench/sender_uid_receiver_walk.py). That answer is one socket,
never taken alone: Linux gives a port two uids share with ``SO_REUSEADDR`` to the newest
socket, or to the one bound to the address before a wildcard, so it can name either of
them. When it names one of ``keep_uids``, the source's filtered query runs at the kept
sources' priority (down to ``KEPT_DEBT_S``), outside the miss budget, and its answer (a
port two uids hold: nobody's) is the lookup's, as a miss query's always was; a source it
found shared is answered so for ``TTL_S`` without another (another user on a node's port,
flooding from the node's source by ``IP_PKTINFO``, held the bucket at ``KEPT_DEBT_S`` and
starved every other kept source's re-check: tests/test_sender_uid_first_contact.py). When it
names another user or nobody (a free port, the flood's fresh ports, a socket connected to
a peer other than ``to``), the miss path answers as before. A flood triggers only the
lookup (bounded in count and in cost); only the users the caller takes trigger the query.

Where the table comes from. The kernel's netlink ``sock_diag`` (swarmd.sockdiag) gives the
same rows in binary: the table every ``TTL_S`` as one dump, and a miss as a query for its
source, filtered in the kernel by port (and, for an IPv4 source's IPv6 sockets, to ``::``
and the v4-mapped addresses, the only ones that send IPv4), read until a second owner
shows (then more rows cannot change the answer: a flood of another user's rows on the
port stops the read at its first, and a node's own many sockets are read whole, up to
``MAX_PORT_ROWS``), so a miss costs a fraction of a table read and its budget
(``MISS_QUERIES_PER_S``) is wider. When netlink is refused (the unit's
``RestrictAddressFamilies=``, seccomp, no ``udp_diag`` in the kernel) or answers what we
cannot parse, the lookup reads ``/proc/self/net/udp{,6}`` from then on (counted:
``netlink_refused``), with the /proc budget.
"""

from __future__ import annotations

import socket
import time
from collections.abc import Callable, Collection, Hashable
from pathlib import Path
from typing import Any, Final

from swarmd.loopback import loopback_host, proc_address, udp_table_rows
from swarmd.sockdiag import SockDiagError, UdpDiag, UdpRow
from swarmd.tokenbucket import TokenBucket

# A read of the table is reused this long: how long a freed port may keep its old owner's
# uid (module docstring). A node or PX4 sends several datagrams a second: one read each
# quarter second under steady traffic.
TTL_S: Final = 0.25
# A miss (a port not in the table read) re-reads it, within this budget: a flood from fresh
# ports costs at most this many reads a second (each read's cost grows with the sockets on
# the computer: bench/sender_uid.py), and a quiet table re-reads at once for a new sender.
MISS_READS_PER_S: Final = 10.0
MISS_READ_BURST: Final = 5.0
# The same budget when a miss is one port's netlink query (both families, filtered in the
# kernel): at 2,000 other sockets a query costs ~1/50 of a /proc read (0.17 ms against
# 9.3 ms: bench/results/security/sender_uid.txt), so a budget 20x wider costs a flood
# ~35 ms a second there against the /proc budget's ~90, and a flood must send 20x the
# fresh ports to starve a new sender's first datagram.
MISS_QUERIES_PER_S: Final = 200.0
MISS_QUERY_BURST: Final = 40.0
# The lookup's work, in seconds a second (module docstring, "What it costs"): 10 % of one
# core. At 2,000 sockets the budgeted work (a dump each TTL_S, ~14 ms a second, and
# MISS_QUERIES_PER_S queries, ~30: bench/results/security/sender_uid.txt) fits under it, so
# it binds only on a table another user grew; whatever that user does, the daemon keeps 90 %
# of a core for RTPS and XRCE on a two-core companion computer.
COST_SHARE: Final = 0.10
COST_BURST_S: Final = 0.05  # saved while quiet: a dump and a new sender's query at once
# The floors of the one bucket (who spends first when it is short): a kept source's
# re-check may run it into this debt (a configured user's source is answered whatever a
# flood spends; at most MAX_KEPT_SOURCES queries a TTL_S, sources only they open), a due
# table read into this one; a miss (a flood's) only spends what is saved.
KEPT_DEBT_S: Final = 0.5
READ_DEBT_S: Final = 0.05
# After a read that came back cut, the next waits until its cost is this part of the
# share's worth: at 34,000 sockets a 0.2 s dump every 4 s, half the share left to queries.
CUT_READ_SHARE: Final = 0.5
# Bytes read from each table (~150 bytes a socket: ~40,000 sockets), and loopback or
# wildcard sockets indexed: a local user can open sockets until its file limit, and must not
# grow this process's memory with them.
MAX_TABLE_BYTES: Final = 6 << 20
MAX_INDEXED_SOCKETS: Final = 32_768
# Rows taken from one netlink dump of a family (what MAX_TABLE_BYTES is to the text), and
# from one port's query. A query stops at a second owner (its answer is then nobody's
# whatever follows), so this cap binds only on a port one uid holds by the tens of
# thousands (or on v6-only rows, which an IPv4 source's query reads and does not count):
# a node's own sockets on its port, however many, stay under it.
MAX_DUMP_ROWS: Final = MAX_TABLE_BYTES // 150
MAX_PORT_ROWS: Final = MAX_DUMP_ROWS
# ... except that, when the caller takes only some users (``keep_uids``), a query whose
# rows so far are all another user's stops past this many (its answer can no longer be
# one of the caller's users: the port is that user's, or nobody's): a user holding a
# node's port by the ten thousand costs each query about one chunk, not all its rows.
FOREIGN_ROWS: Final = 64
# The owner of the rows a capped query left unread: a second uid, so the answer is None.
UNREAD_UID: Final = -1
# The kernel's one-socket answers a second ("First contact"): ~8 us each whatever the table
# holds (bench/sender_uid_scale.py), a flood's datagram's own order of cost, so outside the
# cost bucket and capped only here, past what the daemon reads from the loopback anyway (at
# most ~0.4 s a second). Past it, a new node's datagram gets one with the chance
# RECEIVER_LOOKUPS_PER_S / the flood's misses a second (the miss path otherwise, as before).
RECEIVER_LOOKUPS_PER_S: Final = 50_000.0
RECEIVER_BURST: Final = 5_000.0
# ... and in seconds of work: the hashed lookup walks the sockets bound to the source's
# address and port (and then to the wildcard and port), and a user holding them by the
# thousand with SO_REUSEADDR makes each walk long (~0.12 ms at 5,000 sockets, linear:
# bench/sender_uid_receiver_walk.py), so a count alone let a flood from that port spend a
# whole core. This is the count cap's cost at ~8 us: cheap lookups are capped by the
# count as before, long walks by their measured cost (a bucket of seconds, as COST_SHARE).
RECEIVER_COST_SHARE: Final = 0.40
RECEIVER_COST_BURST_S: Final = 0.04
# Sources answered as one of ``keep_uids`` (the users the caller takes: a declared node's,
# PX4's) are answered from their own filtered query every TTL_S, not from the table read
# (which a user holding more than MAX_INDEXED_SOCKETS sockets cuts before them) nor from the
# miss budget (which a flood of fresh ports spends). This many, least recently looked up
# first out; another user's source is never kept, so it cannot fill them.
MAX_KEPT_SOURCES: Final = 64
# A port shared by a user the caller takes and another uid is logged once per this long
# (per port and owners; at most MAX_KEPT_SOURCES remembered): the node's every datagram
# is dropped while it lasts, and one line says why.
PORT_SHARED_LOG_S: Final = 60.0
_WILDCARDS: Final = frozenset({"0.0.0.0", "::"})  # noqa: S104 - addresses we read, not bind
# What a socket can send from, at any local address (IP_PKTINFO, IPV6_PKTINFO: module
# docstring): IPv4 sources, IPv6 sources, or both.
SENDS_V4: Final = "v4"
SENDS_V6: Final = "v6"
SENDS_BOTH: Final = "both"
_V4_MAPPED: Final = bytes(10) + b"\xff\xff"  # ::ffff:0:0/96
# The IPv6 sockets that can send IPv4 (an IPv4 source's query of AF_INET6, in the kernel)
_V4_SENDING_V6: Final = ((socket.AF_INET6, bytes(16)), (socket.AF_INET6, _V4_MAPPED))


def sends_from(family: int, raw: bytes, v6only: bool) -> str:
    """Which sources a socket of ``family`` bound to ``raw`` (octets) can send from, at any
    local address (``IP_PKTINFO``/``IPV6_PKTINFO``; tried on Linux 6.18 with real sockets):
    an IPv4 socket IPv4 ones; an IPv6 socket bound to ``::`` or a v4-mapped address both
    (a v6-only ``::``: IPv6); bound to another IPv6 address IPv6 only (an IPv4 destination
    is ``ENETUNREACH``). /proc does not show v6-only: a ``::`` row there is both (residual
    (4): a denial, never a spoof)."""
    if family == socket.AF_INET:
        return SENDS_V4
    if raw == bytes(16):
        return SENDS_V6 if v6only else SENDS_BOTH
    return SENDS_BOTH if raw.startswith(_V4_MAPPED) else SENDS_V6


def can_send(kind: str, host: str) -> bool:
    """Whether a socket ``sends_from`` ``kind`` can send from ``host``'s family."""
    return kind == SENDS_BOTH or kind == (SENDS_V6 if ":" in host else SENDS_V4)


def _local_sender(address: str) -> str | None:
    """The loopback address a socket bound to ``address`` sends from (a v4-mapped one as
    its IPv4 form, as ``loopback_host`` gives sources), the wildcard, or None."""
    if address in _WILDCARDS:
        return address
    return loopback_host((address, 0))


def _peer(family: int, host: str, to: tuple[str, int] | None) -> tuple[bytes, int]:
    """The peer of a one-socket lookup: the caller's socket, a wildcard as the source's own
    address (a loopback client connected to 127.0.0.1 or ::1 sends from it); the zero peer
    when unknown or of the other family (then only unconnected sockets match)."""
    if to is None:
        return b"", 0
    address = _local_sender(to[0])
    if address in _WILDCARDS:
        address = host
    if address is None or (":" in address) != (family == socket.AF_INET6):
        return b"", 0
    return socket.inet_pton(family, address), to[1]


def log_firewall_expected(log: Any, port_field: str) -> None:
    """Say, once at start, that the send-and-close race on ``port_field`` is closed only by
    the firewall rules the unit's ``ExecStartPre=+`` loads (``swarmd local-firewall``: the
    nftables table, or the iptables chain on a kernel without nf_tables; docs/security.md
    residual (6)). The daemon cannot see them: reading either needs ``CAP_NET_ADMIN``, and
    its capability set is empty (systemd/swarmd.service); rules that did not load already
    failed the start there, so this is a pointer for the operator, not an alarm.
    """
    log.info(
        "sender_uid_race_closed_by_firewall",
        port=port_field,
        check="swarmd local-firewall --config FILE --check (as root; docs/operations.md)",
    )


class SenderUids:
    """``uid_of((host, port))``: the uid owning a loopback source's socket, or None.

    ``proc`` and ``clock`` are injected for tests (a recorded table, a hand-set clock);
    ``cost_clock`` too (what a table read or query cost: a fake's counter in tests).
    ``netlink``: ask the kernel by sock_diag first; by default when ``proc`` is the live
    ``/proc/self`` (a recorded table is read as given). ``keep_uids``: the users the caller
    takes; their sources are kept (``MAX_KEPT_SOURCES``) and, by netlink, answered from
    their own query, whatever another user does to the table read or the miss budget.
    ``log``: a structlog-style logger (``warning(event, **fields)``) for
    ``sender_port_shared``, a port of one of ``keep_uids`` that another uid holds too."""

    def __init__(
        self,
        proc: Path = Path("/proc/self"),
        clock: Callable[[], float] = time.monotonic,
        netlink: bool | None = None,
        keep_uids: Collection[int] = (),
        cost_clock: Callable[[], float] = time.thread_time,
        log: Any = None,
    ) -> None:
        self.proc = proc
        self.log = log
        # (port, owners) -> when it was last logged (PORT_SHARED_LOG_S)
        self._shared_logged: dict[tuple[int, frozenset[int]], float] = {}
        self.clock = clock
        # this thread's CPU time (the kernel's work for our netlink dump is charged to it):
        # the share is of a core, so another process preempting us is not our cost
        self.cost_clock = cost_clock
        self._cost = TokenBucket(COST_SHARE, COST_BURST_S, clock())
        self._read_interval = TTL_S  # longer after a cut read (CUT_READ_SHARE)
        self.keep_uids = frozenset(keep_uids)
        # (host, port) -> (when its uids were read, the uids): sources of keep_uids, in
        # order of their last lookup (the first is the first out)
        self._kept: dict[tuple[str, int], tuple[float, set[int]]] = {}
        # (family, port) a kept-priority confirmation found shared (two uids): answered so
        # for TTL_S without another query (at most MAX_KEPT_SOURCES, the oldest out). By
        # family, not address: the port's query reads the same sockets for every address of
        # a family, and keyed by address a flood from 65 addresses of 127/8 evicted each
        # entry before its turn came again (review 14, docs/security-history.md)
        self._shared: dict[tuple[int, int], tuple[float, set[int]]] = {}
        # port -> {(sends_from, uid)} for every socket on the port (any address)
        self._index: dict[int, set[tuple[str, int]]] = {}
        self._read_at: float | None = None
        self._table_cut = False  # the last read left sockets unread (a cap)
        self._miss_reads = MISS_READ_BURST  # tokens of the miss budget
        self._miss_reads_at: float | None = None
        # a /proc row's hex address -> its sends_from (None: unparsable), remembered
        self._addresses: dict[str, str | None] = {}
        self.counters: dict[str, int] = {
            "lookups": 0,
            "reads": 0,
            "not_found": 0,
            "ambiguous": 0,
            "port_shared": 0,  # ... of them, a keep_uids user's port another uid holds too
            "unreadable": 0,
            "truncated": 0,
            "miss_reads_over_budget": 0,
            "port_queries": 0,
            "netlink_refused": 0,
            "kept_evicted": 0,
            "cost_over_budget": 0,  # a read or query the cost bucket held back
            "cost_us": 0,  # what the reads and queries cost, in microseconds
            "receiver_lookups": 0,  # a miss's one-socket lookup ("First contact")
            "receiver_confirmed": 0,  # ... that named a keep_uids user: its source's query
            "receiver_refused": 0,  # the kernel refused it: not asked again
            # a miss past RECEIVER_LOOKUPS_PER_S or RECEIVER_COST_SHARE: the miss path
            "receiver_over_budget": 0,
            "receiver_us": 0,  # what those lookups cost (outside the cost bucket)
        }
        self._taken = False  # this lookup's source was a keep_uids user's (uid_of)
        self._receiver_works = True
        self._receivers = TokenBucket(RECEIVER_LOOKUPS_PER_S, RECEIVER_BURST, clock())
        self._receiver_cost = TokenBucket(RECEIVER_COST_SHARE, RECEIVER_COST_BURST_S, clock())
        self._diag: UdpDiag | None = None
        if netlink if netlink is not None else proc == Path("/proc/self"):
            try:
                self._diag = UdpDiag()
            except OSError:
                self.counters["netlink_refused"] += 1

    def uid_of(self, source: Hashable, to: tuple[str, int] | None = None) -> int | None:
        """None for a non-loopback source, a port nobody holds, or a port two uids hold.
        ``to``: the caller's socket (address as bound, port), the peer a sender's connected
        socket may be connected to ("First contact"; a wildcard: the source's address)."""
        host = loopback_host(source)
        if host is None or not isinstance(source, tuple) or not isinstance(source[1], int):
            return None
        port: int = source[1]
        self.counters["lookups"] += 1
        now = self.clock()
        self._taken = False  # a keep_uids user was seen holding the source (kept, confirmed)
        uids = self._kept_uids(host, port, now)
        if uids is None:
            if self._read_at is None or not 0.0 <= now - self._read_at < TTL_S:
                self._index = {}  # too old to name a port's owner (module docstring)
                if self._read_due(now):
                    self._read(now)
            read_at = self._read_at
            uids = self._uids(host, port)
            if self._table_cut and len(uids) == 1:
                uids = set()  # a second owner may be past the cut: asked as a miss
            # it may have bound its port after our last read, or the read was cut before it
            # (then its own query finds it: a re-read of /proc would be cut the same way)
            retry = self._read_at != now or (self._table_cut and self._diag is not None)
            if not uids and retry:
                confirmed = self._receiver_query(host, port, now, to)
                if confirmed is not None:
                    read_at, uids = now, confirmed
                elif self._miss_read(now):
                    if self._query_source(host, port) is None:
                        self._read(now)
                    read_at, uids = now, self._uids(host, port)
            if len(uids) == 1 and uids <= self.keep_uids and self._diag is not None:
                self._keep((host, port), read_at if read_at is not None else now, uids)
        if len(uids) == 1:
            return next(iter(uids))
        self.counters["ambiguous" if uids else "not_found"] += 1
        if len(uids) > 1 and (self._taken or uids & self.keep_uids):
            self._port_shared(host, port, uids, now)
        return None

    def _port_shared(self, host: str, port: int, uids: set[int], now: float) -> None:
        """Count, and log once per ``PORT_SHARED_LOG_S``, a source of a user the caller
        takes dropped because another uid can send from it too (module docstring: a
        denial by binding the port elsewhere, or a spoof by ``IP_PKTINFO`` refused)."""
        self.counters["port_shared"] += 1
        key = (port, frozenset(uids))
        logged = self._shared_logged.pop(key, None)
        if logged is not None and 0.0 <= now - logged < PORT_SHARED_LOG_S:
            self._shared_logged[key] = logged
            return
        if len(self._shared_logged) >= MAX_KEPT_SOURCES:
            del self._shared_logged[next(iter(self._shared_logged))]
        self._shared_logged[key] = now
        if self.log is not None:
            self.log.warning(
                "sender_port_shared",
                host=host,
                port=port,
                taken_uids=sorted(uids & self.keep_uids),
                other_uids=sorted(uids - self.keep_uids),  # -1: rows past a cap, unread
                fix="find who holds the port (ss -uanp sport = :PORT) and stop it",
            )

    def _receiver_query(
        self, host: str, port: int, now: float, to: tuple[str, int] | None
    ) -> set[int] | None:
        """A miss answered outside the miss budget when it is a ``keep_uids`` user's source
        (module docstring, "First contact"): the kernel's receiver of a reply to the source
        (one hashed lookup, not charged to the cost bucket: it does not grow with the
        table), and when that socket is one of ``keep_uids``', the source's filtered query at
        the kept sources' priority, whose answer this is (a port two uids hold: both).
        None when it is not such a source, netlink failed or the bucket is past
        ``KEPT_DEBT_S``: the miss path answers, as before."""
        diag = self._diag
        if diag is None or not self.keep_uids or not self._receiver_works:
            return None
        family = socket.AF_INET6 if ":" in host else socket.AF_INET
        shared = self._shared.get((family, port))
        if shared is not None and 0.0 <= now - shared[0] < TTL_S:
            self._taken = True
            return shared[1]  # confirmed shared within TTL_S: nobody's, without a query
        if self._receiver_cost.balance(now) <= 0.0 or not self._receivers.take(now):
            self.counters["receiver_over_budget"] += 1
            return None
        self.counters["receiver_lookups"] += 1
        started = self.cost_clock()
        try:
            row = diag.receiver(
                family, socket.inet_pton(family, host), port, _peer(family, host, to)
            )
        except (OSError, SockDiagError):
            # a kernel that does not answer a non-dump request: the dumps and queries do
            self._receiver_works = False
            self.counters["receiver_refused"] += 1
            return None
        finally:
            spent = max(0.0, self.cost_clock() - started)
            self._receiver_cost.spend(spent)
            self.counters["receiver_us"] += round(spent * 1e6)
        if row is None or row.uid not in self.keep_uids:
            return None  # nobody's now, or another user's: the miss path, as before
        if self._cost.balance(now) <= -KEPT_DEBT_S:
            self.counters["cost_over_budget"] += 1
            return None
        self.counters["receiver_confirmed"] += 1
        self._taken = True
        answer = self._query_source(host, port)
        if answer is not None and len(answer) > 1:
            # another user on the node's port, sending from its source (IP_PKTINFO): its
            # flood would repeat this kept-priority query at each datagram and hold the
            # bucket at KEPT_DEBT_S, starving every kept source's re-check; once per TTL_S
            self._shared.pop((family, port), None)
            if len(self._shared) >= MAX_KEPT_SOURCES:
                del self._shared[next(iter(self._shared))]
            self._shared[family, port] = (now, answer)
        return answer

    def _kept_uids(self, host: str, port: int, now: float) -> set[int] | None:
        """A kept source's uids, re-read by its own query once ``TTL_S`` old (not charged to
        the miss budget: at most MAX_KEPT_SOURCES queries a TTL_S); None when the source is
        not kept or netlink failed. A source no longer one ``keep_uids`` owner's leaves."""
        key = (host, port)
        kept = self._kept.pop(key, None)
        if kept is None or self._diag is None:
            return None
        read_at, uids = kept
        if not 0.0 <= now - read_at < TTL_S:
            if self._cost.balance(now) <= -KEPT_DEBT_S:
                self.counters["cost_over_budget"] += 1
                self._kept[key] = kept  # still kept; this datagram is not answered by it
                return None
            fresh = self._query_source(host, port)
            if fresh is None:
                return None
            read_at, uids = now, fresh
            self._taken = True
        if len(uids) == 1 and uids <= self.keep_uids:
            self._kept[key] = (read_at, uids)  # to the end: the last looked up
        return uids

    def _keep(self, key: tuple[str, int], read_at: float, uids: set[int]) -> None:
        if self._kept.pop(key, None) is None and len(self._kept) >= MAX_KEPT_SOURCES:
            del self._kept[next(iter(self._kept))]
            self.counters["kept_evicted"] += 1
        self._kept[key] = (read_at, uids)

    def _miss_read(self, now: float) -> bool:
        """A token of the miss budget, if one is left (a bucket refilled by ``now``) and
        the cost bucket has something saved (a miss spends last: module docstring)."""
        if self._cost.balance(now) <= 0.0:
            self.counters["cost_over_budget"] += 1
            return False
        rate, burst = (
            (MISS_READS_PER_S, MISS_READ_BURST)
            if self._diag is None
            else (MISS_QUERIES_PER_S, MISS_QUERY_BURST)
        )
        if self._miss_reads_at is not None:
            elapsed = max(0.0, now - self._miss_reads_at)
            self._miss_reads = min(burst, self._miss_reads + elapsed * rate)
        self._miss_reads_at = now
        if self._miss_reads < 1.0:
            self.counters["miss_reads_over_budget"] += 1
            return False
        self._miss_reads -= 1.0
        return True

    def _uids(self, host: str, port: int) -> set[int]:
        return {uid for kind, uid in self._index.get(port, ()) if can_send(kind, host)}

    def _netlink_failed(self) -> None:
        """Netlink refused or garbled: /proc from now on (module docstring)."""
        self.counters["netlink_refused"] += 1
        if self._diag is not None:
            self._diag.close()
            self._diag = None

    def _query_source(self, host: str, port: int) -> set[int] | None:
        """Re-index the sockets that can send from ``(host, port)`` from the kernel (every
        socket on the port of a family that can send from ``host``, at any address: module
        docstring); their uids, or None when netlink failed (read /proc). The read stops at
        a second owner; past ``MAX_PORT_ROWS`` of one owner the answer has an owner we did
        not read: ambiguous."""
        if self._diag is None:
            return None
        self.counters["port_queries"] += 1
        started = self.cost_clock()
        try:
            return self._query_rows(self._diag, host, port)
        finally:
            self._charge(self.cost_clock() - started)

    def _charge(self, cost: float) -> float:
        """Spend what a read or query cost (on ``cost_clock``); the cost."""
        cost = max(0.0, cost)
        self._cost.spend(cost)
        self.counters["cost_us"] += round(cost * 1e6)
        return cost

    def _read_due(self, now: float) -> bool:
        """Whether a table read may run at ``now``: past the back-off after a cut read and
        within ``READ_DEBT_S`` of the cost bucket."""
        if self._read_at is not None and 0.0 <= now - self._read_at < self._read_interval:
            return False
        if self._cost.balance(now) <= -READ_DEBT_S:
            self.counters["cost_over_budget"] += 1
            return False
        return True

    def _query_rows(self, diag: UdpDiag, host: str, port: int) -> set[int] | None:
        ipv4 = ":" not in host
        entries: set[tuple[str, int]] = set()
        owners: set[int] = set()  # uids of the rows that can send from host, so far
        seen = [0]  # rows read so far

        def enough(rows: list[UdpRow]) -> bool:
            owners.update(
                row.uid for row in rows
                if can_send(sends_from(row.family, row.raw_address, row.v6only), host)
            )  # fmt: skip
            seen[0] += len(rows)
            # nobody's, whatever the rows left say; or, past FOREIGN_ROWS, not one of the
            # users the caller takes (a user holding the node's port by the ten thousand,
            # listed first, would otherwise make each query read them all: ~140 ms at
            # 34,000, bench/sender_uid_scale.py)
            foreign = bool(self.keep_uids and owners - self.keep_uids)
            return len(owners) > 1 or (foreign and seen[0] >= FOREIGN_ROWS)

        # an IPv4 source: every IPv4 socket, and the IPv6 ones that send IPv4
        plan = (
            ((socket.AF_INET, None), (socket.AF_INET6, _V4_SENDING_V6))
            if ipv4
            else ((socket.AF_INET6, None),)
        )
        try:
            for family, addresses in plan:
                rows, more = diag.rows(family, port, MAX_PORT_ROWS, addresses, enough)
                for row in rows:
                    entries.add((sends_from(row.family, row.raw_address, row.v6only), row.uid))
                answer = {uid for kind, uid in entries if can_send(kind, host)}
                if len(answer) > 1:
                    break  # stopped at a second owner, or read whole: nobody's either way
                if more:  # a cap or another user's rows first: an owner we did not read
                    self.counters["truncated"] += 1
                    entries.add((SENDS_V4 if ipv4 else SENDS_V6, UNREAD_UID))
        except (OSError, SockDiagError):
            self._netlink_failed()
            return None
        # the port's rows of the kinds this query did not read whole stay as the last read
        # gave them (an IPv4 source's query leaves IPv6 sockets at IPv6 addresses)
        read = {SENDS_V4, SENDS_BOTH} if ipv4 else {SENDS_V6, SENDS_BOTH}
        index = {pair for pair in self._index.get(port, ()) if pair[0] not in read} | entries
        if index:
            self._index[port] = index
        else:
            self._index.pop(port, None)
        return {uid for kind, uid in entries if can_send(kind, host)}

    def _dump(self) -> list[UdpRow] | None:
        """Every UDP socket by netlink, or None when it failed (read /proc)."""
        if self._diag is None:
            return None
        out: list[UdpRow] = []
        try:
            for family in (socket.AF_INET, socket.AF_INET6):
                rows, more = self._diag.rows(family, 0, MAX_DUMP_ROWS)
                if more:
                    self.counters["truncated"] += 1
                out.extend(rows)
        except (OSError, SockDiagError):
            self._netlink_failed()
            return None
        return out

    def _read(self, now: float) -> None:
        self.counters["reads"] += 1
        self._read_at = now
        cut_before = self.counters["truncated"]
        started = self.cost_clock()
        rows = self._dump()
        if rows is not None:
            self._index_rows(rows)
        else:
            self._read_proc()
        cost = self._charge(self.cost_clock() - started)
        self._table_cut = self.counters["truncated"] != cut_before
        # a cut read is not repeated before its cost is CUT_READ_SHARE of the share's worth
        cut_wait = cost / (COST_SHARE * CUT_READ_SHARE) if self._table_cut else 0.0
        self._read_interval = max(TTL_S, cut_wait)

    def _index_rows(self, rows: list[UdpRow]) -> None:
        # every socket, at any address: each can send from a loopback source of its family
        index: dict[int, set[tuple[str, int]]] = {}
        for indexed, row in enumerate(rows):
            if indexed >= MAX_INDEXED_SOCKETS:
                self.counters["truncated"] += 1
                break
            kind = sends_from(row.family, row.raw_address, row.v6only)
            index.setdefault(row.port, set()).add((kind, row.uid))
        self._index = index

    def _read_proc(self) -> None:
        index: dict[int, set[tuple[str, int]]] = {}
        indexed = 0
        for table in ("udp", "udp6"):
            try:
                with (self.proc / "net" / table).open("rb") as f:
                    raw = f.read(MAX_TABLE_BYTES + 1)
            except OSError:
                self.counters["unreadable"] += 1  # no IPv6 in this kernel, or no /proc
                continue
            if len(raw) > MAX_TABLE_BYTES:
                self.counters["truncated"] += 1
                raw = raw[:MAX_TABLE_BYTES]
            for hex_address, port, uid, _inode in udp_table_rows(raw.decode("ascii", "replace")):
                kind = self._proc_kind(hex_address)
                if kind is None:
                    continue  # a line we cannot parse names nobody
                if indexed >= MAX_INDEXED_SOCKETS:
                    self.counters["truncated"] += 1
                    break
                index.setdefault(port, set()).add((kind, uid))
                indexed += 1
        self._index = index

    def _proc_kind(self, hex_address: str) -> str | None:
        """``sends_from`` of a /proc row's address (no v6-only flag there: a ``::`` row
        sends both), remembered (the few addresses there are); None when unparsable."""
        if hex_address in self._addresses:
            return self._addresses[hex_address]
        kind: str | None = None
        try:
            text = proc_address(hex_address)
            family = socket.AF_INET6 if ":" in text else socket.AF_INET
            kind = sends_from(family, socket.inet_pton(family, text), False)
        except (ValueError, OSError):
            pass
        if len(self._addresses) < MAX_INDEXED_SOCKETS:
            self._addresses[hex_address] = kind
        return kind
