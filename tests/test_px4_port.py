"""Issue 18: the PX4 link's port. sd_listen_fds(3), adopting systemd's socket, and naming a
squatter (``swarmd/sdlisten.py``, ``swarmd/px4/transport.py``, ``swarmd/px4/portowner.py``).

The squatters here are sockets of this process or of a child under another uid (root can
``setpriv``); the installed layout's attacks are ``tests/test_production_layout.py``.
Each socket is on 127.0.0.1 with a port the kernel chose, so parallel runs never collide.
"""

from __future__ import annotations

import errno
import json
import os
import shutil
import socket
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from swarmd.px4.portowner import PortHolder, bound_sockets, holders
from swarmd.px4.transport import adopt_udpin, bind_udpin, parse_connection
from swarmd.sdlisten import ListenFdsError, listen_fds

NOBODY = 65534


@pytest.fixture
def systemd_socket() -> Iterator[socket.socket]:
    """A UDP socket bound as systemd binds a socket unit's (SO_REUSEADDR on)."""
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    s.bind(("127.0.0.1", 0))
    yield s
    s.close()


def endpoint_of(s: socket.socket) -> str:
    return f"udpin:127.0.0.1:{s.getsockname()[1]}"


# ---- sd_listen_fds(3) -----------------------------------------------------------------------


def test_listen_fds_for_another_process_are_ignored_and_the_variables_unset() -> None:
    env = {"LISTEN_PID": "1", "LISTEN_FDS": "1", "LISTEN_FDNAMES": "px4", "OTHER": "x"}
    assert listen_fds(env, pid=os.getpid() + 1) == {}
    assert env == {"OTHER": "x"}  # a child we start must not take them either
    assert listen_fds({}) == {}


@pytest.mark.parametrize(
    ("count", "names", "problem"),
    [("two", None, "LISTEN_FDS='two'"), ("1", "px4:extra", "names 2 descriptors but")],
)
def test_malformed_listen_variables_are_one_line_with_the_fix(
    count: str, names: str | None, problem: str
) -> None:
    env = {"LISTEN_PID": str(os.getpid()), "LISTEN_FDS": count}
    if names is not None:
        env["LISTEN_FDNAMES"] = names
    with pytest.raises(ListenFdsError) as info:
        listen_fds(env)
    assert problem in str(info.value) and "fix:" in str(info.value)
    assert "\n" not in str(info.value)


CHILD = r"""
import json, fcntl, os, socket, sys
from swarmd.sdlisten import listen_fds
fds = listen_fds()
s = socket.socket(fileno=fds["px4"][0])
print(json.dumps({"fds": fds, "cloexec": bool(fcntl.fcntl(3, fcntl.F_GETFD) & fcntl.FD_CLOEXEC),
                  "left": sorted(k for k in os.environ if k.startswith("LISTEN_")),
                  "port": s.getsockname()[1]}))
"""


def test_a_passed_socket_is_found_by_name_close_on_exec_and_the_env_cleared(
    systemd_socket: socket.socket,
) -> None:
    """As systemd passes it: descriptor 3, LISTEN_PID the pid that execs the daemon."""
    fd = systemd_socket.fileno()
    exec_like_systemd = (
        "import os, sys; os.dup2(int(sys.argv[1]), 3); "
        "os.environ.update(LISTEN_PID=str(os.getpid()), LISTEN_FDS='1', LISTEN_FDNAMES='px4'); "
        "os.execv(sys.executable, [sys.executable, '-c', sys.argv[2]])"
    )
    proc = subprocess.run(  # noqa: S603 - fixed argv
        [sys.executable, "-c", exec_like_systemd, str(fd), CHILD],
        pass_fds=(fd,),
        capture_output=True,
        text=True,
        timeout=30,
        check=True,
    )
    seen = json.loads(proc.stdout)
    assert seen == {
        "fds": {"px4": [3]},
        "cloexec": True,
        "left": [],
        "port": systemd_socket.getsockname()[1],
    }


# ---- adopting systemd's socket ----------------------------------------------------------------


def test_adopting_clears_so_reuseaddr_so_nobody_can_bind_beside_it(
    systemd_socket: socket.socket,
) -> None:
    adopted = adopt_udpin(parse_connection(endpoint_of(systemd_socket)), systemd_socket)
    assert adopted.getsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR) == 0
    beside = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    beside.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    with pytest.raises(OSError, match="in use") as info:
        beside.bind(systemd_socket.getsockname())
    beside.close()
    assert info.value.errno == errno.EADDRINUSE


def test_a_socket_bound_beside_systemds_before_swarmd_started_is_named_and_refused(
    systemd_socket: socket.socket,
) -> None:
    # the hole the privileged port closes: while SO_REUSEADDR is on, any user can bind the
    # same address with it too, and Linux hands the newest socket every datagram
    beside = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    beside.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    beside.bind(systemd_socket.getsockname())
    try:
        with pytest.raises(OSError, match="also bound by") as info:
            adopt_udpin(parse_connection(endpoint_of(systemd_socket)), systemd_socket)
    finally:
        beside.close()
    line = str(info.value.strerror)
    assert info.value.errno == errno.EADDRINUSE
    assert f"is also bound by pid {os.getpid()} user root (uid 0)" in line
    assert "fix: stop it, and let systemd hold the port" in line and "\n" not in line


def test_a_passed_socket_on_another_address_is_refused(systemd_socket: socket.socket) -> None:
    other = parse_connection("udpin:127.0.0.1:9")
    with pytest.raises(OSError, match="is bound to") as info:
        adopt_udpin(other, systemd_socket)
    assert info.value.errno == errno.EINVAL
    assert "not 127.0.0.1:9" in str(info.value.strerror)
    assert "fix: make ListenDatagram= and px4.connection name the same address" in str(
        info.value.strerror
    )


# ---- binding it ourselves ---------------------------------------------------------------------


def test_our_own_bind_never_sets_so_reuseaddr() -> None:
    s = bind_udpin(parse_connection("udpin:127.0.0.1:0"))
    try:
        assert s.getsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR) == 0
    finally:
        s.close()


@pytest.mark.skipif(
    os.geteuid() != 0 or shutil.which("setpriv") is None, reason="needs root and setpriv"
)
def test_a_squatter_of_another_user_is_named_with_pid_user_and_command() -> None:
    squatter = subprocess.Popen(  # noqa: S603 - fixed argv
        [
            "setpriv", f"--reuid={NOBODY}", f"--regid={NOBODY}", "--clear-groups",  # noqa: S607
            sys.executable, "-I", "-c",
            "import socket,sys; s=socket.socket(socket.AF_INET,socket.SOCK_DGRAM); "
            "s.bind(('127.0.0.1',0)); print(s.getsockname()[1],flush=True); sys.stdin.read()",
        ],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
    )  # fmt: skip
    assert squatter.stdout is not None and squatter.stdin is not None
    try:
        port = int(squatter.stdout.readline())
        with pytest.raises(OSError, match="is held by") as info:
            bind_udpin(parse_connection(f"udpin:127.0.0.1:{port}"))
        line = str(info.value.strerror)
        assert info.value.errno == errno.EADDRINUSE
        assert line.startswith(f"port {port} is held by pid {squatter.pid} user ")
        assert f"(uid {NOBODY}): " in line and "import socket" in line
        assert line.count("\n") == 0
    finally:
        squatter.stdin.close()
        squatter.wait(timeout=30)
        squatter.stdout.close()


def test_holders_reads_proc_net_udp_and_skips_what_it_cannot_parse(tmp_path: Path) -> None:
    """A recorded /proc (little-endian words): 127.0.0.1:540 uid 1001, a wildcard, junk."""
    (tmp_path / "net").mkdir()
    head = "  sl  local_address rem_address   st tx_queue rx_queue tr tm->when retrnsmt   uid  timeout inode\n"  # noqa: E501
    (tmp_path / "net" / "udp").write_text(
        head
        + "  1: 0100007F:021C 00000000:0000 07 00000000:00000000 00:00000000 00000000  1001        0 4242 2 0 0\n"  # noqa: E501
        + "  2: 00000000:3AB4 00000000:0000 07 00000000:00000000 00:00000000 00000000     0        0 77 2 0 0\n"  # noqa: E501
        + "  3: garbage\n"
    )
    (tmp_path / "net" / "udp6").write_text(
        head
        + "  4: 00000000000000000000000000000000:021C 00000000000000000000000000000000:0000 07 00000000:00000000 00:00000000 00000000     0        0 99 2 0 0\n"  # noqa: E501
    )
    if sys.byteorder != "little":
        pytest.skip("the recorded table is a little-endian host's")
    assert bound_sockets(tmp_path) == [
        PortHolder("127.0.0.1", 540, 1001, 4242),
        PortHolder("0.0.0.0", 15028, 0, 77),
        PortHolder("::", 540, 0, 99),
    ]
    found = holders("127.0.0.1", 540, exclude_inode=99, proc=tmp_path)
    assert found == [PortHolder("127.0.0.1", 540, 1001, 4242)]  # no process dir: not visible
    assert "process not visible to us" in found[0].describe()
