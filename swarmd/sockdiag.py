"""The kernel's UDP socket table by netlink ``sock_diag``: each socket's address, port, uid.

Daemon tier (swarmd.senderuid's source; the sans-IO cores never see it). The same rows
``/proc/net/udp{,6}`` prints as text, in binary, and filtered by local port in the kernel
(``udp_dump`` skips a socket whose port differs from the request's ``idiag_sport``): a miss
asks for one port instead of reading every socket on the computer (bench/sender_uid.py).

Wire format (linux/netlink.h, linux/sock_diag.h, linux/inet_diag.h): a ``nlmsghdr`` (16
octets, host order) and an ``inet_diag_req_v2`` (56 octets: family, protocol, ext, pad,
states, then ``inet_diag_sockid``: ports and addresses big-endian, interface, cookie); each
reply row a ``nlmsghdr`` and an ``inet_diag_msg`` (72 octets: the same sockid at offset 4,
then expires, rqueue, wqueue, uid, inode) and ``nlattr`` attributes, of which we read one:
``INET_DIAG_SKV6ONLY`` (an IPv6 socket's IPV6_V6ONLY, sent for every AF_INET6 row whatever
the request's ``ext``: ``inet_diag_msg_attrs_fill``), because a v6-only socket bound to
``::`` cannot send from an IPv4 address and a dual-stack one can (ipv6(7)). A dump ends with
``NLMSG_DONE``; a refusal is ``NLMSG_ERROR`` with a negative errno.

A one-port query may also carry an ``INET_DIAG_REQ_BYTECODE`` attribute: the kernel runs it
on each socket of the port (``inet_diag_bc_run``, open to every user) and sends only those
it accepts. We send an OR of ``INET_DIAG_BC_S_COND`` host conditions (a local address and
a prefix): for an IPv4 source's query of the IPv6 sockets, ``::`` and ``::ffff:0:0/96``,
the only IPv6 sockets that can send IPv4 (swarmd.senderuid.sends_from). An ``AF_INET``
condition also matches an IPv6 socket bound to that address v4-mapped (the kernel
compares the mapped form).

A request without ``NLM_F_DUMP`` (``encode_receiver_request``) asks for one socket: the one
the kernel's delivery would pick for a datagram to an address and port (``udp_dump_one``), or
``ENOENT``; one hashed lookup, whatever the table holds (swarmd.senderuid, "First contact").

A reply that does not parse raises ``SockDiagError``: the caller falls back to ``/proc``.
"""

from __future__ import annotations

import errno
import socket
import struct
from collections.abc import Callable, Sequence
from typing import Final, NamedTuple

NETLINK_SOCK_DIAG: Final = 4
SOCK_DIAG_BY_FAMILY: Final = 20
NLMSG_ERROR: Final = 2
NLMSG_DONE: Final = 3
NLM_F_REQUEST: Final = 0x01
NLM_F_DUMP: Final = 0x300  # NLM_F_ROOT | NLM_F_MATCH
# every TCP_* state: a UDP socket is TCP_CLOSE (7) unbound-peer or TCP_ESTABLISHED connected
ALL_STATES: Final = 0xFFFF_FFFF
NO_COOKIE: Final = 0xFFFF_FFFF_FFFF_FFFF  # INET_DIAG_NOCOOKIE: any socket
_HEADER: Final = struct.Struct("=IHHII")  # nlmsghdr: len, type, flags, seq, pid
_REQUEST: Final = struct.Struct("=BBBBI2s2s16s16sIQ")  # inet_diag_req_v2
# inet_diag_msg: family, (state, timer, retrans), sport (network order), (dport), src,
# (dst, interface, cookie, expires, rqueue, wqueue), uid, inode
_ROW: Final = struct.Struct("=B3xH2x16s16x12x12xII")
_ROW_BYTES: Final = 72
_ATTR: Final = struct.Struct("=HH")  # nlattr: len (header included), type
INET_DIAG_SKV6ONLY: Final = 11  # enum inet_diag_attr: a u8, 1 when IPV6_V6ONLY
INET_DIAG_REQ_BYTECODE: Final = 1  # the request's attribute: a filter program
INET_DIAG_BC_JMP: Final = 1  # enum of linux/inet_diag.h: always "no"
INET_DIAG_BC_S_COND: Final = 7  # the local address matches a prefix (and port, -1: any)
_OP: Final = struct.Struct("=BBH")  # inet_diag_bc_op: code, yes, no (jumps in octets)
_HOSTCOND: Final = struct.Struct("=BBxxi")  # inet_diag_hostcond: family, prefix_len, port
# A dump's chunks are at most 32 KiB (the kernel's netlink_dump allocation); one buffer
# this size never truncates one.
RECV_BYTES: Final = 1 << 16


class SockDiagError(ValueError):
    """A reply that is not a well-formed sock_diag answer to our request."""


class SockDiagRefused(OSError):
    """The kernel answered NLMSG_ERROR (no udp_diag module, a filtered request refused)."""


class UdpRow(NamedTuple):
    """One socket: its family, local address (4 or 16 octets, network order), local port,
    owner uid (as this process's user namespace maps it), inode, and whether an IPv6 socket
    is v6-only (False for IPv4 rows, and for an IPv6 row without the attribute)."""

    family: int
    raw_address: bytes
    port: int
    uid: int
    inode: int
    v6only: bool = False

    @property
    def address(self) -> str:
        """The local address as text (``"::ffff:127.0.0.1"`` as the kernel holds it)."""
        return socket.inet_ntop(self.family, self.raw_address)


def encode_local_filter(addresses: Sequence[tuple[int, bytes]]) -> bytes:
    """A filter program accepting a socket whose local address is one of ``addresses``
    (family, octets: 4 or 16 for the whole address, fewer for a prefix of that many
    octets, ``::ffff:0:0/96`` being every v4-mapped address). An OR as ``ss`` compiles
    one (iproute2 misc/ss.c): each condition's "yes" lands on a JMP whose "no" skips to the
    end (accept), its "no" on the next condition; the last one's "no" lands 4 octets past
    the end (reject). The kernel
    audits that every jump lands on an operation of the "yes" chain (``inet_diag_bc_audit``)."""
    if not addresses:
        raise ValueError("an empty filter accepts nothing")
    conds = [
        _HOSTCOND.pack(family, len(raw) * 8, -1)
        + raw.ljust(16 if family == socket.AF_INET6 else 4, b"\0")
        for family, raw in addresses
    ]
    out = b""
    for cond in reversed(conds):
        size = _OP.size + len(cond)
        if not out:
            out = _OP.pack(INET_DIAG_BC_S_COND, size, size + 4) + cond
        else:
            jump = _OP.pack(INET_DIAG_BC_JMP, _OP.size, len(out) + 4)
            out = _OP.pack(INET_DIAG_BC_S_COND, size, size + 4) + cond + jump + out
    return out


def encode_request(
    family: int, port: int, seq: int, addresses: Sequence[tuple[int, bytes]] | None = None
) -> bytes:
    """A dump of ``family``'s UDP sockets, only those bound to local ``port`` unless 0, and
    to one of ``addresses`` when given (``encode_local_filter``)."""
    body = _REQUEST.pack(
        family,
        socket.IPPROTO_UDP,
        0,  # no extensions: the fixed row carries uid and inode
        0,
        ALL_STATES,
        port.to_bytes(2, "big"),
        b"\0\0",
        bytes(16),
        bytes(16),
        0,
        NO_COOKIE,
    )
    if addresses is not None:
        program = encode_local_filter(addresses)
        body += _ATTR.pack(_ATTR.size + len(program), INET_DIAG_REQ_BYTECODE) + program
    return _HEADER.pack(_HEADER.size + len(body), SOCK_DIAG_BY_FAMILY,
                        NLM_F_REQUEST | NLM_F_DUMP, seq, 0) + body  # fmt: skip


def encode_receiver_request(
    family: int,
    address: bytes,
    port: int,
    ifindex: int,
    seq: int,
    peer: tuple[bytes, int] = (b"", 0),
) -> bytes:
    """A non-dump request: the one socket that would receive a datagram sent from ``peer``
    (address octets, port) to ``address``:``port`` on interface ``ifindex`` (``udp_dump_one``,
    net/ipv4/udp_diag.c: the delivery's own ``__udp4_lib_lookup``/``__udp6_lib_lookup``,
    hashed by address and port). The request's "destination" is the socket's local end and
    its "source" the peer: swapped "for historical reasons" there. An unconnected socket
    matches any peer; a connected one only its own (the zero peer: none)."""
    body = _REQUEST.pack(
        family,
        socket.IPPROTO_UDP,
        0,
        0,
        ALL_STATES,
        peer[1].to_bytes(2, "big"),
        port.to_bytes(2, "big"),
        peer[0].ljust(16, b"\0"),
        address.ljust(16, b"\0"),
        ifindex,
        NO_COOKIE,
    )
    return _HEADER.pack(_HEADER.size + len(body), SOCK_DIAG_BY_FAMILY, NLM_F_REQUEST, seq, 0) + body


def parse_reply(data: bytes, seq: int) -> tuple[list[UdpRow], bool]:
    """The rows in one received buffer and whether the dump ended in it. Messages of
    another sequence number (a dump abandoned earlier) are skipped."""
    rows: list[UdpRow] = []
    offset = 0
    while offset < len(data):
        if len(data) - offset < _HEADER.size:
            raise SockDiagError("short netlink header")
        length, kind, _flags, msg_seq, _pid = _HEADER.unpack_from(data, offset)
        if length < _HEADER.size or offset + length > len(data):
            raise SockDiagError("netlink length out of the buffer")
        body = offset + _HEADER.size
        if msg_seq == seq:
            if kind == NLMSG_DONE:
                return rows, True
            if kind == NLMSG_ERROR:
                if length < _HEADER.size + 4:
                    raise SockDiagError("short NLMSG_ERROR")
                errno = -struct.unpack_from("=i", data, body)[0]
                raise SockDiagRefused(errno, "sock_diag refused the request")
            if kind != SOCK_DIAG_BY_FAMILY or length < _HEADER.size + _ROW_BYTES:
                raise SockDiagError("not a sock_diag row")
            family, port, raw, uid, inode = _ROW.unpack_from(data, body)
            if family == socket.AF_INET:
                raw = raw[:4]
            elif family != socket.AF_INET6:
                raise SockDiagError("a row of another family")
            v6only = family == socket.AF_INET6 and _v6only(data, body + _ROW_BYTES, offset + length)
            rows.append(UdpRow(family, raw, socket.ntohs(port), uid, inode, v6only))
        offset += (length + 3) & ~3  # NLMSG_ALIGN
    return rows, False


def _v6only(data: bytes, start: int, end: int) -> bool:
    """The ``INET_DIAG_SKV6ONLY`` attribute between ``start`` and ``end``; False when it is
    absent or the attributes do not parse (dual-stack: the caller's safe reading, where a
    ``::`` socket counts for IPv4 sources too and can only add an owner, never hide one)."""
    while end - start >= _ATTR.size:
        length, kind = _ATTR.unpack_from(data, start)
        if length < _ATTR.size or start + length > end:
            return False
        if kind & 0x3FFF == INET_DIAG_SKV6ONLY and length > _ATTR.size:
            return data[start + _ATTR.size] != 0
        start += (length + 3) & ~3  # NLA_ALIGN
    return False


class UdpDiag:
    """One netlink socket asking the kernel for UDP sockets. Non-blocking: the kernel
    fills a dump's chunks within send and recv, so a recv that would wait is an error,
    never a stall of the event loop. ``OSError`` from the constructor: netlink refused
    (``RestrictAddressFamilies=``, seccomp, no such protocol)."""

    def __init__(self) -> None:
        self._sock = self._open()
        self._seq = 0
        # a socket bound to the loopback device matches a lookup on it alone (the
        # kernel's udp_sk_bound_dev_eq); an unbound one matches any
        self._lo = socket.if_nametoindex("lo")

    @staticmethod
    def _open() -> socket.socket:
        sock = socket.socket(
            socket.AF_NETLINK, socket.SOCK_RAW | socket.SOCK_CLOEXEC, NETLINK_SOCK_DIAG
        )
        sock.setblocking(False)
        return sock

    def close(self) -> None:
        self._sock.close()

    def __del__(self) -> None:
        # the lookup lives as long as its owner, who never closes it: no ResourceWarning
        # (and no socket at all when the constructor was refused)
        sock = getattr(self, "_sock", None)
        if sock is not None:
            sock.close()

    def receiver(
        self, family: int, address: bytes, port: int, peer: tuple[bytes, int] = (b"", 0)
    ) -> UdpRow | None:
        """The socket a datagram from ``peer`` to ``address``:``port`` on the loopback would
        reach (``encode_receiver_request``), or None when none would (``ENOENT``). One hashed
        lookup in the kernel: its cost does not grow with the sockets on the computer.
        Raises OSError (another refusal) or SockDiagError."""
        self._seq = (self._seq + 1) & 0xFFFF_FFFF
        request = encode_receiver_request(family, address, port, self._lo, self._seq, peer)
        self._sock.send(request)
        try:
            rows, _done = parse_reply(self._sock.recv(RECV_BYTES), self._seq)
        except SockDiagRefused as refused:
            if refused.errno == errno.ENOENT:
                return None
            raise
        if len(rows) != 1:
            raise SockDiagError("a non-dump answer of other than one socket")
        return rows[0]

    def rows(
        self,
        family: int,
        port: int,
        max_rows: int,
        addresses: Sequence[tuple[int, bytes]] | None = None,
        enough: Callable[[list[UdpRow]], bool] | None = None,
    ) -> tuple[list[UdpRow], bool]:
        """``family``'s UDP sockets bound to ``port`` (every one when 0) and to one of
        ``addresses`` when given, at most ``max_rows`` and whether more were left unread.
        ``enough``: called with each received chunk's rows; True ends the dump there (the
        caller has its answer: more rows cannot change it), as if cut. Raises OSError or
        SockDiagError."""
        self._seq = (self._seq + 1) & 0xFFFF_FFFF
        self._sock.send(encode_request(family, port, self._seq, addresses))
        out: list[UdpRow] = []
        while True:
            rows, done = parse_reply(self._sock.recv(RECV_BYTES), self._seq)
            out.extend(rows)
            if done:
                return out, False
            if len(out) > max_rows or (enough is not None and enough(rows)):
                # the kernel runs one dump per socket: drop this one with its socket
                self._sock.close()
                self._sock = self._open()
                return out[:max_rows], True
