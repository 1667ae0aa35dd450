"""swarmctl never says "not reachable" for a command its daemon took (session 16 command
review).

``swarmctl takeoff | land | hold | abort`` hands the commander's daemon one request that
sends the command. When the answer to that request never came (the daemon restarted or
crashed after reading it; or it answered after swarmctl's 2 s wait, its loop held up by a
state-file fsync on a slow SD card), swarmctl said ``swarmd did not answer`` or ``lost the
connection to swarmd`` and exited 2, "the daemon is not running / not reachable"
(docs/operations.md, "Exit codes"), with nothing on stdout under ``--json``. The daemon
may have sent the command all the same: the operator, or a script retrying on 2, was told
it had not gone out while the drones took off. The same held when the connection was lost
while swarmctl followed a command it had announced as sent.

A played commander (a thread on a real Unix socket) takes the request, records it as
carried out, and closes without an answer, or stays silent past swarmctl's wait.
"""

from __future__ import annotations

import contextlib
import functools
import json
import socket
import threading
from pathlib import Path
from typing import Any

import pytest

from swarmd.cli import swarmctl, takeoff_cmd
from swarmd.control import ControlClient, encode_line
from swarmd.exitcodes import EX_FAILED, EX_UNREACHABLE

SERVE_S = 5.0  # the played daemon's bound on any one wait: it never outlives a test
COMMAND_ID = 0x6B09A20700000001
READINESS = {"uav2": {"ready": True, "reason": None}}
STATUS = {
    "node": "lead",
    "role": "commander",
    "dataplane": {"enabled": True},
    "readiness": READINESS,
}


class PlayedCommander:
    """A commander's control socket. ``dies_on``: the request it takes and never answers
    (``closed``: the connection closes; ``silent``: it stays open and mute until the
    client hangs up). ``outcomes`` answers with one pending row, or (``follow_dies``)
    closes the connection: the daemon restarted while swarmctl followed, or
    (``follow_forgets``) no longer knows the command, or (``follow_stopping``) is stopping."""

    def __init__(
        self,
        path: Path,
        dies_on: str,
        how: str,
        *,
        follow_dies: bool = False,
        follow_forgets: bool = False,
        follow_stopping: bool = False,
    ):
        self.path = path
        self.dies_on = dies_on
        self.how = how
        self.follow_dies = follow_dies
        self.follow_forgets = follow_forgets
        self.follow_stopping = follow_stopping
        self.taken: list[dict[str, Any]] = []  # the state-changing requests it carried out
        self._stopping = False
        self._listener = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        self._listener.bind(str(path))
        self._listener.listen(4)
        self._listener.settimeout(SERVE_S)
        self._thread = threading.Thread(target=self._serve, daemon=True)
        self._thread.start()

    def close(self) -> None:
        self._stopping = True
        with contextlib.suppress(OSError), socket.socket(socket.AF_UNIX) as poke:
            poke.connect(str(self.path))  # wakes a thread waiting in accept
        self._thread.join(SERVE_S)
        self._listener.close()
        assert not self._thread.is_alive()

    def _serve(self) -> None:
        try:
            while True:
                conn, _ = self._listener.accept()
                if self._stopping:
                    conn.close()
                    return
                with conn:
                    conn.settimeout(SERVE_S)
                    if not self._connection(conn):
                        return
        except OSError:
            return  # the listener closed, or a bounded wait ran out

    def _connection(self, conn: socket.socket) -> bool:
        """Serve one connection; False once the played daemon is done."""
        buffer = b""
        while True:
            while b"\n" not in buffer:
                chunk = conn.recv(65536)
                if not chunk:
                    return True
                buffer += chunk
            line, _, buffer = buffer.partition(b"\n")
            request = json.loads(line)
            cmd = request.pop("cmd")
            if cmd == self.dies_on:
                self.taken.append(request)  # the command goes out to the drones ...
                if self.how == "silent":  # ... and the answer is late: the client gives up
                    assert conn.recv(65536) == b""
                return False  # ... or never comes: the daemon is gone
            if cmd == "outcomes" and self.follow_dies:
                return False
            if cmd == "outcomes" and self.follow_stopping:
                # the daemon stopping while swarmctl follows (tests/test_cmd_daemon_stopping)
                stopping = {"ok": False, "error": "the daemon is stopping", "code": "stopping"}
                conn.sendall(encode_line(stopping))
                continue
            if cmd == "outcomes" and self.follow_forgets:
                # a new life of the daemon, or the command pushed out of its 64
                error = f"unknown command id {COMMAND_ID}"
                conn.sendall(encode_line({"ok": False, "error": error}))
                continue
            conn.sendall(encode_line({"ok": True, "result": self._answer(cmd, request)}))

    def _answer(self, cmd: str, request: dict[str, Any]) -> Any:
        if cmd == "status":
            return STATUS
        if cmd == "readiness":
            return READINESS
        if cmd in ("takeoff", "command"):
            self.taken.append(request)
            return {"sent": True, "command_id": COMMAND_ID, "ready": ["uav2"], "refused": {}}
        assert cmd == "outcomes", cmd
        row = {"state": "pending", "reason": None, "latency_s": None, "done_s": None}
        return {"command_id": COMMAND_ID, "valid_for_s": 10.0, "valid_left_s": 9.0,
                "done": False, "nodes": {"uav2": row}}  # fmt: skip


@pytest.fixture
def quick_client(monkeypatch: pytest.MonkeyPatch) -> None:
    """swarmctl's wait for one answer, 2 s, made 0.2 s: the silent daemon outlasts it
    whatever it is (it answers nothing until the client hangs up)."""
    monkeypatch.setattr(takeoff_cmd, "ControlClient", functools.partial(ControlClient, timeout=0.2))


@pytest.fixture
def sock(workdir: Path) -> Path:
    return workdir / "c.sock"


ARGS = {"takeoff": ["takeoff", "--alt", "5"], "command": ["land"]}


@pytest.mark.parametrize("how", ["closed", "silent"])
@pytest.mark.parametrize("request_name", ["takeoff", "command"])
@pytest.mark.parametrize("as_json", [False, True])
@pytest.mark.usefixtures("quick_client")
def test_a_command_request_left_unanswered_is_not_called_unreachable(
    sock: Path, how: str, request_name: str, as_json: bool, capsys: pytest.CaptureFixture[str]
) -> None:
    """[fails on main: exit 2 'lost the connection to swarmd' / 'did not answer', the
    daemon having taken the command; nothing on stdout with --json]"""
    daemon = PlayedCommander(sock, request_name, how)
    try:
        argv = [*ARGS[request_name], "--socket", str(sock), "--timeout", "1"]
        code = swarmctl.main([*argv, "--json"] if as_json else argv)
    finally:
        daemon.close()
    out, err = capsys.readouterr()
    assert len(daemon.taken) == 1  # the daemon took it: it may have gone out
    assert code != EX_UNREACHABLE, err
    assert code == EX_FAILED
    said = out + err
    assert "may have sent" in said and "swarmctl outcomes" in said, said
    if as_json:
        final = json.loads(out)
        assert final["exit_code"] == EX_FAILED and final["command_id"] is None
        assert final["sent"] is None  # not known
        assert final["error"]


@pytest.mark.parametrize("as_json", [False, True])
@pytest.mark.parametrize("lost", ["connection", "command"])
@pytest.mark.usefixtures("quick_client")
def test_a_connection_lost_while_following_a_sent_command_says_it_was_sent(
    sock: Path, lost: str, as_json: bool, capsys: pytest.CaptureFixture[str]
) -> None:
    """The daemon goes while swarmctl follows (``connection``), or answers that it does
    not know the command (``command``: a new life of it, or the command pushed out of the
    64 it keeps). [fails on main: exit 2 after 'LAND command ... sent'; a traceback]"""
    daemon = PlayedCommander(
        sock, "none", "closed", follow_dies=lost == "connection", follow_forgets=lost == "command"
    )
    try:
        argv = ["land", "--socket", str(sock), "--timeout", "1"]
        code = swarmctl.main([*argv, "--json"] if as_json else argv)
    finally:
        daemon.close()
    out, err = capsys.readouterr()
    assert len(daemon.taken) == 1
    assert code == EX_FAILED, err
    assert f"swarmctl outcomes {COMMAND_ID:#x}" in out + err
    if as_json:
        final = json.loads(out)
        assert final["exit_code"] == EX_FAILED and final["command_id"] == COMMAND_ID
        assert final["sent"] is True
        assert final["error"]


@pytest.mark.usefixtures("quick_client")
def test_a_daemon_that_is_not_there_is_still_unreachable(
    sock: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Guard: no socket, or a daemon that dies on the first read-only request: nothing
    was sent, exit 2 as before."""
    assert swarmctl.main(["land", "--socket", str(sock)]) == EX_UNREACHABLE
    daemon = PlayedCommander(sock, "status", "closed")
    try:
        assert swarmctl.main(["land", "--socket", str(sock)]) == EX_UNREACHABLE
    finally:
        daemon.close()
    assert daemon.taken == [{}]  # the status request, which changes nothing
    assert "may have sent" not in "".join(capsys.readouterr())
