"""Who sent it: the control socket records the client's kernel credentials (``SO_PEERCRED``)
with every state-changing request (docs/operations.md, "Who sent a command"; docs/security.md,
"Control socket").

A real Unix socket and real processes: a client as root (this process) and one as another
user (``setpriv``: uid 65534, in the socket's group so the file mode lets it in). The uid
logged and kept with the command is the kernel's, whatever the request says about itself.
It is a record, not a gate: the same uid outside the group is refused by the kernel at
``connect`` as before, and a read-only request carries no credentials.
"""

from __future__ import annotations

import asyncio
import json
import os
import shutil
import subprocess
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

import pytest
from structlog.testing import capture_logs

from swarmd.config import load_config
from swarmd.control import ControlClient, ControlServer, PeerCredentials
from swarmd.swarm.events import SentBy
from tests.daemon_support import (
    in_process_daemon,
    loopback_config,
    run_domain,
    swarm_sections,
    write_bundle,
)

OTHER_UID = 65534  # nobody
SYSTEM_PYTHON = "/usr/bin/python3"  # readable by every user (the venv may not be)
# A client that is not swarmctl: one raw request line, the reply line printed, and its pid
CLIENT = """
import json, os, socket, sys
s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
s.settimeout(10)
try:
    s.connect(sys.argv[1])
except PermissionError:
    print(json.dumps({"connect": "EACCES", "pid": os.getpid()}))
    raise SystemExit(0)
s.sendall(sys.argv[2].encode() + b"\\n")
line = b""
while not line.endswith(b"\\n"):
    chunk = s.recv(65536)
    if not chunk:
        break
    line += chunk
print(json.dumps({"reply": json.loads(line), "pid": os.getpid()}))
"""

needs_setpriv = pytest.mark.skipif(
    os.geteuid() != 0 or shutil.which("setpriv") is None or not Path(SYSTEM_PYTHON).exists(),
    reason="needs root, setpriv and /usr/bin/python3 to run a client as another user",
)


def as_other_user(sock: str, request: Mapping[str, Any], *, in_group: bool) -> dict[str, Any]:
    """Send ``request`` from a process with uid 65534 (group: the socket's, or its own)."""
    gid = os.stat(sock).st_gid if in_group else OTHER_UID
    proc = subprocess.run(  # noqa: S603 - fixed argv
        [
            "setpriv",
            f"--reuid={OTHER_UID}",
            f"--regid={gid}",
            "--clear-groups",
            SYSTEM_PYTHON,
            "-I",
            "-c",
            CLIENT,
            sock,
            json.dumps(request),
        ],  # fmt: skip
        capture_output=True,
        text=True,
        timeout=30,
        check=False,
        env={"PATH": "/usr/bin:/bin"},
    )
    assert proc.returncode == 0, proc.stderr
    out: dict[str, Any] = json.loads(proc.stdout)
    return out


@pytest.fixture
def sock_dir(tmp_path: Path) -> Iterator[Path]:
    # short (AF_UNIX paths), and traversable by the other user: 0755, root's alone to write
    short = Path(f"/tmp/swpc-{os.getpid()}-{tmp_path.name[-20:]}")
    short.mkdir(mode=0o755)
    os.chmod(short, 0o755)  # noqa: S103 - the other user must traverse it, not write
    try:
        yield short
    finally:
        shutil.rmtree(short, ignore_errors=True)


@needs_setpriv
def test_server_hands_the_kernels_credentials_to_sender_handlers(sock_dir: Path) -> None:
    sock = str(sock_dir / "ctl.sock")
    seen: list[tuple[str, PeerCredentials | None]] = []

    def takeoff(request: Mapping[str, Any], peer: PeerCredentials | None) -> str:
        seen.append(("takeoff", peer))
        return "sent"

    def status(_request: Mapping[str, Any]) -> str:
        seen.append(("status", None))
        return "fine"

    async def main() -> list[dict[str, Any]]:
        server = ControlServer(sock, {"status": status}, sender_handlers={"takeoff": takeoff})
        await server.start()
        try:

            def clients() -> list[dict[str, Any]]:
                with ControlClient(sock) as root_client:
                    assert root_client.request("takeoff") == "sent"
                # the request's claims about its sender are ignored
                forged = {"cmd": "takeoff", "peer_uid": 0, "sent_by": {"uid": 0, "user": "root"}}
                return [
                    as_other_user(sock, forged, in_group=True),
                    as_other_user(sock, {"cmd": "status"}, in_group=True),
                    as_other_user(sock, {"cmd": "takeoff"}, in_group=False),
                ]

            return await asyncio.to_thread(clients)
        finally:
            await server.close()

    other, read_only, outsider = asyncio.run(main())
    assert other["reply"] == {"ok": True, "result": "sent"}
    assert read_only["reply"] == {"ok": True, "result": "fine"}
    assert outsider == {"connect": "EACCES", "pid": outsider["pid"]}  # the kernel's gate
    assert [cmd for cmd, _ in seen] == ["takeoff", "takeoff", "status"]
    root_peer, other_peer = seen[0][1], seen[1][1]
    assert root_peer is not None and other_peer is not None
    assert (root_peer.uid, root_peer.pid, root_peer.user) == (0, os.getpid(), "root")
    assert other_peer.uid == OTHER_UID and other_peer.pid == other["pid"]
    assert other_peer.gid == os.stat(sock_dir).st_gid  # the socket's group, as set
    assert other_peer.log_fields()["peer_uid"] == OTHER_UID


def test_a_socketpair_without_credentials_still_dispatches() -> None:
    """The kernel gives SO_PEERCRED for any connected Unix socket; a handler must cope
    with None all the same (dispatch called directly, as the fuzz tests do)."""
    got: list[PeerCredentials | None] = []
    server = ControlServer(
        "/nonexistent/ctl.sock", {}, sender_handlers={"command": lambda _r, p: got.append(p)}
    )
    assert server.dispatch(b'{"cmd": "command"}')["ok"]
    assert got == [None]
    unknown = server.dispatch(b'{"cmd": "nope"}')
    assert unknown == {"ok": False, "error": "unknown command 'nope'; known: command"}


@needs_setpriv
def test_daemon_logs_and_keeps_who_sent_each_command(workdir: Path) -> None:
    """A commander daemon (no vehicle, its one member not running): a land from another
    user and a hold from root are each logged as ``command_requested`` with the kernel's
    uid, user and pid, and kept with the command (``sent_by``) in its outcomes and in
    ``status``; a refused request is logged with its sender too."""
    os.chmod(workdir, 0o755)  # noqa: S103 - the other user must traverse it, not write
    files = write_bundle(workdir, 2, domain_id=run_domain() + 13)
    sock = str(workdir / "ctl.sock")  # loopback_config's
    cfg = loopback_config(workdir, files, extra=swarm_sections(workdir / "state", None))
    daemon = in_process_daemon(load_config(cfg), files.bundle, "uav1")

    async def main() -> tuple[list[Any], dict[str, Any], Any, dict[str, Any]]:
        await daemon.start()
        try:
            app = daemon.app
            assert app is not None and app.is_commander

            def clients() -> tuple[dict[str, Any], dict[str, Any], dict[str, Any], Any]:
                land = as_other_user(
                    sock, {"cmd": "command", "kind": "land", "sent_by": {"uid": 0}}, in_group=True
                )
                bad = as_other_user(sock, {"cmd": "command", "kind": "loop"}, in_group=True)
                with ControlClient(sock) as c:
                    hold = c.request("command", kind="hold")
                    outcomes = c.request(
                        "outcomes", command_id=land["reply"]["result"]["command_id"]
                    )
                return land, bad, hold, outcomes

            with capture_logs() as logs:
                land, bad, hold, outcomes = await asyncio.to_thread(clients)
            status = daemon.status()
            return logs, {"land": land, "bad": bad, "hold": hold}, outcomes, status
        finally:
            await daemon.stop("test")

    logs, replies, outcomes, status = asyncio.run(main())
    land, bad, hold = replies["land"], replies["bad"], replies["hold"]
    assert land["reply"]["ok"] and not bad["reply"]["ok"]
    requested = [e for e in logs if e["event"] == "command_requested"]
    assert [(e["kind"], e["peer_uid"], e["sent"]) for e in requested] == [
        ("land", OTHER_UID, True),
        ("loop", OTHER_UID, False),
        ("hold", 0, True),
    ]
    assert [e["peer_pid"] for e in requested] == [land["pid"], bad["pid"], os.getpid()]
    assert requested[2]["peer_user"] == "root" and "kind must be one of" in requested[1]["error"]
    land_id = land["reply"]["result"]["command_id"]
    assert requested[0]["command_id"] == land_id
    sent = [e for e in logs if e["event"] == "command_sent"]
    assert [e["sent_by"]["uid"] for e in sent] == [OTHER_UID, 0]

    assert (
        outcomes["sent_by"] == SentBy(OTHER_UID, requested[0]["peer_user"], land["pid"]).as_json()
    )
    by_id = {c["command_id"]: c["sent_by"] for c in status["commands"]}
    assert by_id[land_id]["uid"] == OTHER_UID
    assert by_id[hold["command_id"]] == {"uid": 0, "user": "root", "pid": os.getpid()}


def test_follow_output_names_the_sender_as_data() -> None:
    from swarmd.cli.takeoff_cmd import sent_by_text

    assert sent_by_text({"sent_by": None, "nodes": {}}) is None
    shown = sent_by_text({"sent_by": {"uid": 1001, "user": "ops\x1b[2J", "pid": 42}, "nodes": {}})
    assert shown is not None and "\x1b" not in shown and "uid 1001, pid 42" in shown
    nameless = sent_by_text({"sent_by": {"uid": 4242, "user": None, "pid": 7}, "nodes": {}})
    assert nameless == "sent by uid without a name (uid 4242, pid 7)"
