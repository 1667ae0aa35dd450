"""UDP sockets inside a test namespace: the SPDP group listener and a bounded receive loop."""

from __future__ import annotations

import socket
import time
from collections.abc import Callable
from typing import TypeVar

from swarmd_lab.netns import Namespace

from swarmd.rtps.ports import SPDP_MULTICAST_GROUP, spdp_multicast_port

T = TypeVar("T")


def group_listener(ns: Namespace, domain_id: int = 0) -> socket.socket:
    """A socket in ``ns`` bound to the SPDP port and joined to 239.255.0.1 on its eth0."""
    sock = ns.socket()
    try:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        sock.bind(("", spdp_multicast_port(domain_id)))
        mreq = socket.inet_aton(SPDP_MULTICAST_GROUP) + socket.inet_aton(ns.address)
        sock.setsockopt(socket.IPPROTO_IP, socket.IP_ADD_MEMBERSHIP, mreq)
    except BaseException:
        sock.close()
        raise
    return sock


def unicast_socket(ns: Namespace, port: int) -> socket.socket:
    """A socket bound to ``ns``'s address and ``port``; multicast sends leave via eth0."""
    sock = ns.socket()
    try:
        sock.bind((ns.address, port))
        sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_IF, socket.inet_aton(ns.address))
    except BaseException:
        sock.close()
        raise
    return sock


def receive_until(
    sock: socket.socket,
    accept: Callable[[bytes, tuple[str, int]], T | None],
    timeout: float,
) -> T | None:
    """Receive until ``accept(data, source)`` returns non-None; None after ``timeout`` s."""
    deadline = time.monotonic() + timeout
    while True:
        remaining = deadline - time.monotonic()
        if remaining <= 0:
            return None
        sock.settimeout(remaining)
        try:
            data, source = sock.recvfrom(65536)
        except TimeoutError:
            return None
        result = accept(data, source)
        if result is not None:
            return result
