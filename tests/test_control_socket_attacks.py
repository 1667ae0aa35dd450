"""Hostile local clients of the control socket (issue 10's trust boundaries, audit).

The socket (``/run/swarmd/swarmd.sock``) runs commands on the swarm, so only root and the
socket's group may connect (mode 0660), and whatever a permitted client sends is answered
with an error line, never a dead handler: malformed JSON, nesting deep enough to overflow
the decoder, bytes that are not UTF-8, more clients than the cap.
"""

from __future__ import annotations

import asyncio
import json
import os
import shutil
import socket
import subprocess
import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from swarmd.control import MAX_CLIENTS, MAX_LINE_BYTES, ControlClient, ControlServer

NOBODY = 65534
SYSTEM_PYTHON = shutil.which("python3", path="/usr/bin:/bin") or sys.executable


@pytest.fixture
def sock_path(tmp_path: Path) -> Iterator[str]:
    # AF_UNIX paths are limited to 108 bytes; the folder is traversable by others so the
    # permission test reaches the socket's own mode bits
    short = Path(f"/tmp/swa-{os.getpid()}-{tmp_path.name[-20:]}")
    short.mkdir(mode=0o755, parents=True, exist_ok=True)
    os.chmod(short, 0o755)  # noqa: S103  (others must reach the socket to be refused by it)
    yield str(short / "s.sock")
    for child in short.iterdir():
        child.unlink()
    short.rmdir()


def _serve_and(sock_path: str, fn: Callable[[ControlServer], Any]) -> Any:
    async def main() -> Any:
        server = ControlServer(sock_path, {"ping": lambda _req: "pong"})
        await server.start()
        try:
            return await asyncio.to_thread(fn, server)
        finally:
            await server.close()

    return asyncio.run(main())


def _exchange(sock_path: str, lines: list[bytes]) -> list[Any]:
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as s:
        s.settimeout(10)
        s.connect(sock_path)
        f = s.makefile("rwb")
        replies = []
        for line in lines:
            f.write(line)
            f.flush()
            reply = f.readline()
            replies.append(json.loads(reply) if reply else None)
        return replies


def _first_line(sock_path: str, send: bytes = b"") -> Any:
    """Connect, send ``send`` (the server may close before it is all written), read a line."""
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as s:
        s.settimeout(10)
        s.connect(sock_path)
        try:
            s.sendall(send)
        except (BrokenPipeError, ConnectionResetError):
            pass  # refused mid-request: the reply is already queued
        return json.loads(s.makefile("rb").readline())


def test_deeply_nested_json_is_answered_and_the_connection_lives(sock_path: str) -> None:
    # json.loads raises RecursionError (not ValueError) from about 1,000 levels: unhandled,
    # it killed the client's handler without a reply
    lines = [b"[" * 5000 + b"\n", b'{"cmd": ' * 3000 + b"\n", b'{"cmd": "ping"}\n']
    replies = _serve_and(sock_path, lambda _s: _exchange(sock_path, lines))
    assert replies[0] == {"ok": False, "error": "request is not JSON"}
    assert replies[1] == {"ok": False, "error": "request is not JSON"}
    assert replies[2] == {"ok": True, "result": "pong"}


def test_bytes_that_are_not_utf8_are_answered(sock_path: str) -> None:
    lines = [b'{"cmd": "\xff\xfe"}\n', b"\x00\x01\x02\n", b'{"cmd": "ping"}\n']
    replies = _serve_and(sock_path, lambda _s: _exchange(sock_path, lines))
    assert [r["ok"] for r in replies] == [False, False, True]


def test_clients_beyond_the_cap_are_refused_then_served_again(sock_path: str) -> None:
    def clients(server: ControlServer) -> tuple[list[Any], Any, int]:
        held = []
        for _ in range(MAX_CLIENTS):
            c = ControlClient(sock_path)
            c.connect()
            assert c.request("ping") == "pong"  # each is being served: it holds a slot
            held.append(c)
        extra = _first_line(sock_path)
        for c in held:
            c.close()
        # the slots are freed when the server sees each close; wait on that, not a sleep
        for _ in range(200):
            again = _exchange(sock_path, [b'{"cmd": "ping"}\n'])[0]
            if again == {"ok": True, "result": "pong"}:
                break
        return extra, again, server.rejected_clients

    extra, again, rejected = _serve_and(sock_path, clients)
    assert extra == {"ok": False, "error": "too many control clients"}
    assert again == {"ok": True, "result": "pong"}
    assert rejected >= 1


def test_an_oversized_request_is_refused_without_buffering_it(sock_path: str) -> None:
    big = b'{"cmd": "ping", "pad": "' + b"a" * (4 * MAX_LINE_BYTES) + b'"}\n'
    reply = _serve_and(sock_path, lambda _s: _first_line(sock_path, big))
    assert reply == {"ok": False, "error": "request line too long"}


@pytest.mark.skipif(os.geteuid() != 0, reason="needs root to act as another local user")
def test_a_local_non_root_user_cannot_connect(sock_path: str) -> None:
    probe = (
        "import socket, sys\n"
        "s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)\n"
        "try:\n"
        "    s.connect(sys.argv[1])\n"
        "except PermissionError:\n"
        "    print('refused')\n"
        "else:\n"
        "    print('connected')\n"
    )

    def as_nobody(_server: ControlServer) -> str:
        done = subprocess.run(
            # the system interpreter: the test's venv may not be readable by nobody
            [SYSTEM_PYTHON, "-c", probe, sock_path],
            user=NOBODY,
            group=NOBODY,
            extra_groups=[],
            capture_output=True,
            text=True,
            timeout=60,
            check=True,
        )
        return done.stdout.strip()

    assert _serve_and(sock_path, as_nobody) == "refused"
