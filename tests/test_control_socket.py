"""Control socket protocol, swarmctl status/peers/watch and their exit codes."""

from __future__ import annotations

import asyncio
import json
import os
import socket
import stat
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

import pytest

from swarmd.cli import swarmctl
from swarmd.cli.status_cmd import render_status
from swarmd.control import (
    MAX_LINE_BYTES,
    ControlClient,
    ControlServer,
    ControlSocketBusy,
    DaemonUnreachable,
    RequestError,
)

STATUS: dict[str, Any] = {
    "node": "uav1",
    "swarm": "alpha",
    "phase": "passive",
    "mode": "adaptive",
    "link": {"q": 0.8, "snr_db": 37.0, "source": "file"},
    "passive_timer_s": 3.2,
    "peers_discovered": 1,
    "peers_total": 2,
    "peers": [
        {
            "name": "uav2",
            "index": 2,
            "state": "discovered",
            "guid": "5357aabbccddeeff00000002:1c1",
            "last_heard_s": 0.4,
            "link_q": 0.42,
            "locator": "udp/10.0.0.2:7414",
            "matched_endpoints": 2,
            "lists_me": True,
        },
        {
            "name": "uav3",
            "index": 3,
            "state": "undiscovered",
            "guid": "5357aabbccddeeff00000003:1c1",
            "last_heard_s": None,
            "locator": None,
            "matched_endpoints": 0,
            "lists_me": False,
        },
    ],
    "foreign": [{"guid": "0110aabb:1c1", "vendor": "Eclipse Cyclone DDS", "name": None}],
    "counters": {
        "rx_datagrams": 12,
        "tx_datagrams": 3,
        "tx_multicast": 1,
        "tx_unicast": 2,
        "dropped": {"decode_error": 2, "wrong_domain": 0, "own": 1},
    },
}


def _handlers() -> dict[str, Any]:
    def boom(_req: Mapping[str, Any]) -> Any:
        raise ZeroDivisionError("bug")

    return {"status": lambda _req: STATUS, "ping": lambda _req: "pong", "boom": boom}


@pytest.fixture
def sock_path(tmp_path: Path) -> Iterator[str]:
    # AF_UNIX paths are limited to 108 bytes; pytest's tmp_path can be long
    short = Path(f"/tmp/swt-{os.getpid()}-{tmp_path.name[-20:]}")
    short.mkdir(parents=True, exist_ok=True)
    yield str(short / "s.sock")
    for child in short.iterdir():
        child.unlink()
    short.rmdir()


def _serve_and(sock_path: str, fn: Any, *args: Any) -> Any:
    """Run ``fn(*args)`` in a thread while a ControlServer serves on ``sock_path``."""

    async def main() -> Any:
        server = ControlServer(sock_path, _handlers())
        await server.start()
        try:
            return await asyncio.to_thread(fn, *args)
        finally:
            await server.close()

    return asyncio.run(main())


def test_roundtrip_errors_and_permissions(sock_path: str) -> None:
    def client() -> list[Any]:
        mode = stat.S_IMODE(os.stat(sock_path).st_mode)
        with ControlClient(sock_path) as c:
            out: list[Any] = [mode, c.request("ping"), c.request("status")["node"]]
            for cmd in ("nope", "boom"):
                with pytest.raises(RequestError) as info:
                    c.request(cmd)
                out.append(str(info.value))
            return out

    mode, pong, node, unknown, boom = _serve_and(sock_path, client)
    assert (mode, pong, node) == (0o660, "pong", "uav1")
    assert unknown == "unknown command 'nope'; known: boom, ping, status"
    assert boom == "internal error: ZeroDivisionError: bug"
    assert not os.path.exists(sock_path)  # removed on close


def test_garbage_requests_get_error_replies(sock_path: str) -> None:
    def client() -> list[Any]:
        s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        s.settimeout(5)
        s.connect(sock_path)
        f = s.makefile("rwb")
        replies = []
        for line in (b"not json\n", b"[1]\n", b'{"cmd": 3}\n'):
            f.write(line)
            f.flush()
            replies.append(json.loads(f.readline()))
        f.write(b"x" * (MAX_LINE_BYTES + 10) + b"\n")
        f.flush()
        replies.append(json.loads(f.readline()))
        s.close()
        return replies

    replies = _serve_and(sock_path, client)
    assert [r["ok"] for r in replies] == [False] * 4
    assert replies[0]["error"] == "request is not JSON"
    assert "cmd" in replies[1]["error"] and "cmd" in replies[2]["error"]
    assert replies[3]["error"] == "request line too long"


def test_stale_socket_is_replaced_and_live_one_refused(sock_path: str) -> None:
    stale = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    stale.bind(sock_path)
    stale.close()  # the file stays, nobody listens: what a SIGKILLed daemon leaves

    async def main() -> None:
        first = ControlServer(sock_path, _handlers())
        await first.start()
        try:
            with pytest.raises(ControlSocketBusy, match="another swarmd"):
                await ControlServer(sock_path, _handlers()).start()
        finally:
            await first.close()

    asyncio.run(main())


def test_unreachable_daemon_messages(sock_path: str) -> None:
    with pytest.raises(DaemonUnreachable, match="swarmd is not running \\(no control socket"):
        ControlClient(sock_path).connect()
    stale = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    stale.bind(sock_path)
    stale.close()
    with pytest.raises(DaemonUnreachable, match="stale control socket"):
        ControlClient(sock_path).connect()


@pytest.mark.parametrize("command", ["status", "peers", "watch"])
def test_swarmctl_without_daemon_prints_one_line_and_exits_2(
    command: str, sock_path: str, capsys: pytest.CaptureFixture[str]
) -> None:
    assert swarmctl.main([command, "--socket", sock_path]) == 2
    out, err = capsys.readouterr()
    assert out == ""
    assert err.count("\n") == 1
    assert err.startswith("swarmctl: swarmd is not running")


def test_swarmctl_status_json_and_table(sock_path: str, capsys: pytest.CaptureFixture[str]) -> None:
    assert _serve_and(sock_path, swarmctl.main, ["status", "--json", "--socket", sock_path]) == 0
    assert json.loads(capsys.readouterr().out) == STATUS
    assert _serve_and(sock_path, swarmctl.main, ["status", "--socket", sock_path]) == 0
    table = capsys.readouterr().out
    assert table.splitlines() == render_status(STATUS)


def test_swarmctl_peers_and_watch(sock_path: str, capsys: pytest.CaptureFixture[str]) -> None:
    assert _serve_and(sock_path, swarmctl.main, ["peers", "--json", "--socket", sock_path]) == 0
    assert json.loads(capsys.readouterr().out) == STATUS["peers"]
    argv = ["watch", "--json", "--count", "3", "--interval", "0", "--socket", sock_path]
    assert _serve_and(sock_path, swarmctl.main, argv) == 0
    frames = capsys.readouterr().out.splitlines()
    assert [json.loads(f) for f in frames] == [STATUS] * 3


def test_socket_env_var_sets_the_default(
    sock_path: str, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setenv("SWARMD_SOCKET", sock_path)
    assert _serve_and(sock_path, swarmctl.main, ["peers"]) == 0
    assert "uav2" in capsys.readouterr().out


def test_render_status_table() -> None:
    lines = render_status(STATUS)
    assert lines[0] == "node uav1  swarm alpha  phase passive  mode adaptive"
    assert lines[1] == "link Q 0.80  SNR 37.0 dB  source file"
    assert lines[2] == "passive timer: 3.2 s remaining"
    assert lines[3] == "peers discovered 1/2"
    assert lines[4].split() == [
        "PEER",
        "STATE",
        "LAST",
        "HEARD",
        "Q",
        "LOCATOR",
        "ENDPOINTS",
        "HEARS",
        "ME",
    ]
    assert lines[5].split() == [
        "uav2",
        "discovered",
        "0.4",
        "s",
        "ago",
        "0.42",
        "udp/10.0.0.2:7414",
        "2",
        "yes",
    ]
    assert lines[6].split() == ["uav3", "undiscovered", "-", "-", "-", "0", "no"]
    assert lines[7] == "foreign participants 1"
    assert lines[9].split() == ["0110aabb:1c1", "Eclipse", "Cyclone", "DDS", "-"]
    assert lines[10] == (
        "packets in 12  out 3 (multicast 1, unicast 2)  dropped 3 (decode_error 2, own 1)"
    )


def test_render_status_tolerates_a_sparse_status() -> None:
    lines = render_status({"node": "uav1"})
    assert lines[0].startswith("node uav1")
    assert "passive timer: -" in lines
    assert lines[-1] == "packets in 0  out 0 (multicast 0, unicast 0)  dropped 0"


def test_render_status_counts_the_data_planes_refusals() -> None:
    dp = {
        "enabled": True,
        "incarnation": 4,
        "peers_up": ["m1"],
        "counters": {
            "rx_datagrams": 20,
            "tx_datagrams": 9,
            "dropped_auth_failed": 3,
            "dropped_auth_receiver_epoch": 1,
            "dropped_peer_not_up": 2,
        },
    }
    quiet = {**dp, "counters": {"rx_datagrams": 20, "tx_datagrams": 9}}
    line = next(x for x in render_status({"node": "lead", "dataplane": dp}) if "data plane" in x)
    assert line.endswith("refused 6 (4 unauthenticated)")
    line = next(x for x in render_status({"node": "l", "dataplane": quiet}) if "data plane" in x)
    assert "refused" not in line
