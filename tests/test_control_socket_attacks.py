"""Hostile local clients of the control socket (issue 10's trust boundaries, audit).

The socket (``/run/swarmd/swarmd.sock``) runs commands on the swarm, so only root and the
socket's group may connect (mode 0660), and whatever a permitted client sends is answered
with an error line, never a dead handler: malformed JSON, nesting deep enough to overflow
the decoder, bytes that are not UTF-8, more clients than the cap, clients that connect and
never finish a request line.
"""

from __future__ import annotations

import asyncio
import json
import os
import shutil
import socket
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from swarmd.control import (
    MAX_CLIENTS,
    MAX_LINE_BYTES,
    ControlClient,
    ControlServer,
    RequestInvalid,
)

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


def _serve_and(sock_path: str, fn: Callable[[ControlServer], Any], **server_kw: Any) -> Any:
    async def main() -> Any:
        server = ControlServer(sock_path, {"ping": lambda _req: "pong"}, **server_kw)
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


def test_idle_clients_are_closed_after_the_deadline_so_swarmctl_gets_in(sock_path: str) -> None:
    """MAX_CLIENTS connections that never complete a request line (half send nothing, half
    a line without its newline) fill the cap and lock a new client out; past the request
    deadline (tiny here, injected) each gets an error line and is closed, counted, and a new
    request is served. Without the deadline they held the slots forever."""

    def idle_then_ping(server: ControlServer) -> tuple[Any, Any, list[Any], int]:
        idle = []
        for i in range(MAX_CLIENTS):
            s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
            s.settimeout(30)
            s.connect(sock_path)
            if i % 2:
                s.sendall(b'{"cmd": "pi')  # a slow client: never the newline
            idle.append(s)
        locked_out = _first_line(sock_path)
        served = None
        give_up = time.monotonic() + 60.0  # eventually, within a generous bound
        while served != {"ok": True, "result": "pong"} and time.monotonic() < give_up:
            time.sleep(0.05)
            try:
                served = _exchange(sock_path, [b'{"cmd": "ping"}\n'])[0]
            except (BrokenPipeError, ConnectionResetError):
                served = None  # refused at the cap before the request was written
        told = []
        for s in idle:
            f = s.makefile("rb")
            told.append(json.loads(f.readline()))
            assert f.readline() == b""  # then closed
            s.close()
        return locked_out, served, told, server.idle_clients_closed

    locked_out, served, told, closed = _serve_and(sock_path, idle_then_ping, request_deadline_s=3.0)
    assert locked_out == {"ok": False, "error": "too many control clients"}
    assert served == {"ok": True, "result": "pong"}
    assert told == [{"ok": False, "error": "no complete request line within 3 s"}] * MAX_CLIENTS
    assert closed == MAX_CLIENTS


def test_a_client_idle_past_the_deadline_reconnects_on_its_next_request(sock_path: str) -> None:
    """``swarmctl watch`` keeps one connection: when the daemon closed it for idling (a
    refresh interval beyond the deadline), the next request goes out on a new one instead
    of failing on the closed one or reading the deadline line as its reply."""

    def idle_client(server: ControlServer) -> tuple[int, Any]:
        with ControlClient(sock_path) as client:
            assert client.request("ping") == "pong"
            give_up = time.monotonic() + 60.0
            while server.idle_clients_closed < 1 and time.monotonic() < give_up:
                time.sleep(0.05)
            return server.idle_clients_closed, client.request("ping")

    closed, again = _serve_and(sock_path, idle_client, request_deadline_s=0.2)
    assert (closed, again) == (1, "pong")


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


def test_clients_that_never_read_their_replies_are_closed_so_swarmctl_gets_in(
    sock_path: str,
) -> None:
    """Session 10 review: MAX_CLIENTS connections each send a burst of complete requests
    with large replies and never read one. The request deadline only covered reading a
    line, so each handler waited forever for its reply to drain (and its close for the
    unsent buffer to flush): the cap stayed full and swarmctl was locked out until the
    daemon restarted. Now a reply that cannot be delivered within the deadline closes the
    connection (counted), and a new request is served."""
    big_reply = "x" * 60_000
    burst = b'{"cmd": "big"}\n' * 64  # ~3.8 MB of replies: far past any socket buffer

    def stalled_then_ping(server: ControlServer) -> tuple[Any, Any, int]:
        stalled = []
        for _ in range(MAX_CLIENTS):
            s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
            s.settimeout(30)
            s.connect(sock_path)
            s.sendall(burst)  # complete lines, every one; then never a read
            stalled.append(s)
        locked_out = None
        give_up = time.monotonic() + 60.0  # eventually, within a generous bound
        while locked_out is None and time.monotonic() < give_up:
            try:
                locked_out = _first_line(sock_path)
            except (BrokenPipeError, ConnectionResetError):
                time.sleep(0.05)
        served = None
        give_up = time.monotonic() + 30.0  # 30x the injected deadline
        while served != {"ok": True, "result": "pong"} and time.monotonic() < give_up:
            time.sleep(0.05)
            try:
                served = _exchange(sock_path, [b'{"cmd": "ping"}\n'])[0]
            except (BrokenPipeError, ConnectionResetError, json.JSONDecodeError):
                served = None
        # one freed slot serves the ping; the others time out on their own clocks: wait for
        # them (a stalled socket closed first would count as a hang-up, not a slow reader)
        while server.slow_clients_closed < MAX_CLIENTS and time.monotonic() < give_up:
            time.sleep(0.05)
        for s in stalled:
            s.close()
        return locked_out, served, server.slow_clients_closed

    handlers = {"ping": lambda _req: "pong", "big": lambda _req: big_reply}

    async def main() -> tuple[Any, Any, int]:
        server = ControlServer(sock_path, handlers, request_deadline_s=1.0)
        await server.start()
        try:
            return await asyncio.to_thread(stalled_then_ping, server)
        finally:
            await asyncio.wait_for(server.close(), 30.0)

    locked_out, served, closed = asyncio.run(main())
    assert locked_out == {"ok": False, "error": "too many control clients"}
    assert served == {"ok": True, "result": "pong"}
    assert closed == MAX_CLIENTS


@pytest.mark.parametrize("dir_mode", [0o777, 0o1777, 0o770])
def test_a_socket_folder_another_user_can_write_is_refused(dir_mode: int) -> None:
    """Session 10 review: ``control.socket`` in a folder others can write (``/tmp``, a shared
    folder). In one without the sticky bit any local user unlinks swarmd's socket and binds
    their own in its place: swarmctl then talks to them (a made-up status, the operator's
    take-off request captured); with it they squat the path before swarmd starts and swarmd
    refuses to start. The server refuses such a folder before binding, naming it."""
    folder = Path(f"/tmp/swa-{os.getpid()}-{dir_mode:o}")
    folder.mkdir()
    try:
        os.chmod(folder, dir_mode)
        path = str(folder / "s.sock")

        async def start() -> None:
            server = ControlServer(path, {"ping": lambda _req: "pong"})
            try:
                await server.start()
            finally:
                await server.close()

        with pytest.raises(RuntimeError) as caught:
            asyncio.run(start())
        assert str(folder) in str(caught.value)
        assert "\n" not in str(caught.value)
        assert not os.path.exists(path)  # refused before binding
    finally:
        for child in folder.iterdir():
            child.unlink()
        folder.rmdir()


HOSTILE_ERROR = "uav2 \x1b]0;owned\x07 \x1b[2J \x9b31m \u202e"


@pytest.mark.parametrize(
    "argv",
    [["status"], ["peers"], ["takeoff"], ["hold"], ["outcomes"]],
)
def test_swarmctl_prints_a_daemon_error_as_data(sock_path: str, argv: list[str]) -> None:
    """Session 10 review: swarmctl made the daemon's *results* safe for a terminal but
    printed its *error* lines raw on stderr. An error can carry text that is not the
    operator's (a handler's exception message); with escapes in it, it cleared and
    retitled the operator's terminal. Real swarmctl process, real socket."""

    def refuse(_req: Any) -> Any:
        raise RequestInvalid(HOSTILE_ERROR)

    handlers = {name: refuse for name in ("status", "peers", "takeoff", "command", "outcomes")}

    def run_swarmctl(_server: ControlServer) -> subprocess.CompletedProcess[str]:
        return subprocess.run(
            [str(Path(sys.executable).parent / "swarmctl"), *argv, "--socket", sock_path],
            capture_output=True,
            text=True,
            timeout=60,
            check=False,
        )

    async def main() -> subprocess.CompletedProcess[str]:
        server = ControlServer(sock_path, handlers)
        await server.start()
        try:
            return await asyncio.to_thread(run_swarmctl, server)
        finally:
            await server.close()

    proc = asyncio.run(main())
    assert proc.returncode != 0
    assert "uav2" in proc.stderr, proc.stderr  # the error was shown ...
    shown = proc.stdout + proc.stderr
    assert "\x1b" not in shown and "\x9b" not in shown and "\u202e" not in shown  # ... as data


def test_the_socket_is_never_open_to_others_between_bind_and_chmod(
    sock_path: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Session 10 review: bind(2) creates the socket file with 0777 less the umask, and the
    chmod to ``control.mode`` came after. Under a umask without the "other" bits (0000:
    a hand-started daemon from some shells and init scripts) any local user who connected
    in between kept that connection. Checked at the instant before the chmod."""
    seen: list[int] = []
    real_chmod = os.chmod

    def spying_chmod(path: Any, mode: int, *args: Any, **kwargs: Any) -> None:
        if str(path) == sock_path:
            seen.append(os.stat(path).st_mode & 0o777)
        real_chmod(path, mode, *args, **kwargs)

    monkeypatch.setattr(os, "chmod", spying_chmod)
    old = os.umask(0)
    try:
        _serve_and(sock_path, lambda _s: None)
    finally:
        os.umask(old)
    assert seen, "the server no longer chmods its socket: check this test still applies"
    assert all(mode & 0o077 == 0 for mode in seen), [f"{m:04o}" for m in seen]
