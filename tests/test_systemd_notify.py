"""sd_notify: datagrams to a NOTIFY_SOCKET the test binds (path and abstract), watchdog maths."""

from __future__ import annotations

import os
import socket
from collections.abc import Iterator

import pytest

from swarmd.sdnotify import Notifier, watchdog_interval_s


@pytest.fixture
def notify_socket() -> Iterator[tuple[socket.socket, str]]:
    path = f"/tmp/swt-{os.getpid()}-notify.sock"
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(path)
    sock.settimeout(5)
    try:
        yield sock, path
    finally:
        sock.close()
        os.unlink(path)


def test_ready_status_watchdog_stopping(notify_socket: tuple[socket.socket, str]) -> None:
    sock, path = notify_socket
    n = Notifier({"NOTIFY_SOCKET": path})
    assert n.enabled
    assert n.ready("phase passive, peers 0/4")
    assert sock.recv(4096) == b"READY=1\nSTATUS=phase passive, peers 0/4"
    assert n.status("two\nlines")
    assert sock.recv(4096) == b"STATUS=two lines"
    assert n.watchdog()
    assert sock.recv(4096) == b"WATCHDOG=1"
    assert n.stopping()
    assert sock.recv(4096) == b"STOPPING=1"
    n.close()


def test_abstract_namespace_socket() -> None:
    name = f"swt-{os.getpid()}-abstract"
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(b"\0" + name.encode())
    sock.settimeout(5)
    try:
        n = Notifier({"NOTIFY_SOCKET": "@" + name})
        assert n.ready()
        assert sock.recv(4096) == b"READY=1"
        n.close()
    finally:
        sock.close()


def test_without_socket_is_a_no_op_and_errors_are_counted() -> None:
    assert not Notifier({}).enabled
    assert not Notifier({}).ready()
    gone = Notifier({"NOTIFY_SOCKET": f"/tmp/swt-{os.getpid()}-absent.sock"})
    assert not gone.watchdog()
    assert gone.errors == 1
    assert gone.last_error is not None
    gone.close()


def test_watchdog_interval_is_half_and_respects_pid() -> None:
    assert watchdog_interval_s({}) is None
    assert watchdog_interval_s({"WATCHDOG_USEC": "0"}) is None
    assert watchdog_interval_s({"WATCHDOG_USEC": "10000000"}) == 5.0
    env = {"WATCHDOG_USEC": "4000000", "WATCHDOG_PID": "42"}
    assert watchdog_interval_s(env, pid=42) == 2.0
    assert watchdog_interval_s(env, pid=43) is None
