"""Issue 18 for the uXRCE-DDS agent's port: systemd's socket (``swarmd-xrce.socket``, passed as
``xrce``) adopted with ``SO_REUSEADDR`` cleared, the descriptor picked by backend, and a
squatter of another uid named in the one start-up line (``swarmd/px4/xrce_backend.py``,
``swarmd/px4/transport.py``, ``swarmd/daemon.py``).

The squatters run under another uid (root can ``setpriv``); the installed layout's attacks are
``tests/test_production_layout.py``. Every socket is on 127.0.0.1 with a port the kernel chose.
Waiting for a session with a generous cap is not a timing assertion.
"""

from __future__ import annotations

import asyncio
import errno
import os
import shutil
import socket
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
import structlog
import structlog.testing
from swarmd_lab.configs import MINIMAL_CONFIG

from swarmd.config import load_config, parse_config
from swarmd.daemon import Daemon
from swarmd.daemon_setup import listen_socket_name
from swarmd.exitcodes import EX_OSERR, StartupError
from swarmd.px4.xrce_backend import XrceBackend
from tests.daemon_support import in_process_daemon, run_domain, write_bundle, write_config
from tests.xrce_vehicle import XrceVehicle

KEY = 0x0BAD_CAFE
SYSID = 1
NOBODY = 65534
WAIT_S = 30.0
ROOT_AND_SETPRIV = pytest.mark.skipif(
    os.geteuid() != 0 or shutil.which("setpriv") is None, reason="needs root and setpriv"
)
MINIMAL = MINIMAL_CONFIG

# A squatter of another user: binds HOST:PORT (SO_REUSEADDR if asked), says so, holds it
# until its stdin closes.
SQUAT = (
    "import socket,sys; s=socket.socket(socket.AF_INET,socket.SOCK_DGRAM); "
    "s.setsockopt(socket.SOL_SOCKET,socket.SO_REUSEADDR,int(sys.argv[2])); "
    "s.bind(('127.0.0.1',int(sys.argv[1]))); print(s.getsockname()[1],flush=True); "
    "sys.stdin.read()"
)


@pytest.fixture
def systemd_socket() -> Iterator[socket.socket]:
    """A UDP socket bound as systemd binds a socket unit's (SO_REUSEADDR on)."""
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    s.bind(("127.0.0.1", 0))
    yield s
    s.close()


class Squatter:
    """A process of user ``nobody`` holding a UDP port on 127.0.0.1."""

    def __init__(self, port: int, *, reuse: bool) -> None:
        self.proc = subprocess.Popen(  # noqa: S603 - fixed argv
            ["setpriv", f"--reuid={NOBODY}", f"--regid={NOBODY}", "--clear-groups",  # noqa: S607
             sys.executable, "-I", "-c", SQUAT, str(port), str(int(reuse))],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
        )  # fmt: skip
        assert self.proc.stdout is not None
        self.port = int(self.proc.stdout.readline())

    def close(self) -> None:
        assert self.proc.stdin is not None and self.proc.stdout is not None
        self.proc.stdin.close()
        self.proc.wait(timeout=WAIT_S)
        self.proc.stdout.close()


# ---- which descriptor the daemon takes ------------------------------------------------------


@pytest.mark.parametrize(
    ("px4", "name"),
    [
        ("connection: udpin:127.0.0.1:540", "px4"),
        ("connection: serial:/dev/ttyTHS1:921600", None),
        ("connection: udpout:127.0.0.1:14580", None),
        ("backend: xrce-agent", "xrce"),  # its default, udp:127.0.0.1:888
        ("backend: xrce-agent\n  connection: udp:127.0.0.1:8888", "xrce"),
        ("backend: xrce-agent\n  connection: serial:/dev/ttyTHS1:921600", None),
        ("backend: xrce-client", None),  # a client: the port is its MicroXRCEAgent's
        ("enabled: false\n  backend: xrce-agent", None),
    ],
)
def test_the_daemon_takes_the_descriptor_of_its_backend(px4: str, name: str | None) -> None:
    cfg = parse_config(MINIMAL + f"px4:\n  {px4}\n", "s.yaml")
    assert listen_socket_name(cfg.px4) == name


# ---- the XRCE backend on systemd's socket -----------------------------------------------------


def test_the_agent_adopts_systemds_socket_clears_so_reuseaddr_and_serves_px4(
    systemd_socket: socket.socket,
) -> None:
    port = systemd_socket.getsockname()[1]
    inode = os.fstat(systemd_socket.fileno()).st_ino

    async def main() -> None:
        backend = XrceBackend(
            "xrce-agent", f"udp:127.0.0.1:{port}", sysid=SYSID, expected_key=KEY,
            inherited=socket.socket(fileno=os.dup(systemd_socket.fileno())),
        )  # fmt: skip
        await backend.start(lambda _obs, _now: None)
        vehicle = XrceVehicle(KEY, SYSID, ("127.0.0.1", port))
        try:
            assert backend._transport is not None
            used: socket.socket = backend._transport.get_extra_info("socket")
            assert os.fstat(used.fileno()).st_ino == inode  # systemd's socket, not a new one
            assert used.getsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR) == 0
            beside = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            beside.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            with pytest.raises(OSError, match="in use") as info:
                beside.bind(("127.0.0.1", port))
            beside.close()
            assert info.value.errno == errno.EADDRINUSE
            await vehicle.start()
            deadline = asyncio.get_running_loop().time() + WAIT_S
            while backend.session != "established":
                assert asyncio.get_running_loop().time() < deadline, backend.stats()
                await asyncio.sleep(0.05)
            assert backend.stats()["sessions"] == 1
        finally:
            vehicle.kill()
            await backend.close()

    asyncio.run(main())


@ROOT_AND_SETPRIV
def test_a_socket_another_user_bound_beside_systemds_is_named_and_refused(
    systemd_socket: socket.socket,
) -> None:
    """The hole the privileged port closes: while systemd's SO_REUSEADDR is on, any user can
    bind the same address with it too and would get PX4's datagrams instead of swarmd."""
    port = systemd_socket.getsockname()[1]
    squatter = Squatter(port, reuse=True)
    try:

        async def main() -> None:
            backend = XrceBackend(
                "xrce-agent", f"udp:127.0.0.1:{port}", sysid=SYSID, expected_key=KEY,
                inherited=socket.socket(fileno=os.dup(systemd_socket.fileno())),
            )  # fmt: skip
            try:
                with pytest.raises(OSError, match="also bound by") as info:
                    await backend.start(lambda _obs, _now: None)
            finally:
                await backend.close()
            line = str(info.value.strerror)
            assert info.value.errno == errno.EADDRINUSE
            assert f"port {port} is also bound by pid {squatter.proc.pid} user " in line
            assert f"(uid {NOBODY}): " in line and "import socket" in line
            assert "which receives PX4's uXRCE-DDS traffic" in line
            assert "(swarmd-xrce.socket, docs/px4.md)" in line and "\n" not in line

        asyncio.run(main())
    finally:
        squatter.close()


# ---- a squatter at start-up, through the daemon ---------------------------------------------


def _daemon(workdir: Path, port: int, backend: str = "xrce-agent") -> Daemon:
    files = write_bundle(workdir, 2, domain_id=run_domain())
    key = f"  xrce_key: {KEY}\n" if backend == "xrce-agent" else ""
    px4 = (
        f"px4:\n  enabled: true\n  backend: {backend}\n"
        f"  connection: udp:127.0.0.1:{port}\n{key}  require_home: false\n"
    )
    cfg = write_config(
        workdir / "uav1.yaml", files, node="uav1", interface="lo", ipv4="127.0.0.1",
        socket_path=str(workdir / "uav1.sock"), extra=px4,
    )  # fmt: skip
    # no socket unit (an empty environment): swarmd binds the agent's port itself
    return in_process_daemon(load_config(cfg), files.bundle, "uav1")


@ROOT_AND_SETPRIV
def test_a_squatter_of_another_user_on_the_agent_port_is_named_at_start_up(
    workdir: Path,
) -> None:
    squatter = Squatter(0, reuse=False)
    port = squatter.port
    try:

        async def main() -> None:
            daemon = _daemon(workdir, port)
            try:
                with pytest.raises(StartupError) as info:
                    await daemon.start()
            finally:
                await daemon.stop("test")
            line = str(info.value)
            assert info.value.exit_code == EX_OSERR
            assert line.startswith(
                f"px4.connection udp:127.0.0.1:{port}: port {port} is held by "
                f"pid {squatter.proc.pid} user "
            ), line
            assert f"(uid {NOBODY}): " in line and "import socket" in line
            assert "fix: stop it, and let systemd hold the port from boot (swarmd-xrce.socket" in (
                line
            )
            assert "\n" not in line

        asyncio.run(main())
    finally:
        squatter.close()


@ROOT_AND_SETPRIV
def test_the_default_agent_port_is_refused_to_a_user_and_the_line_names_the_socket_unit() -> None:
    """Port 888 (the default) as user nobody, as swarmd started by hand without the socket
    unit: the bind is refused by the kernel, and the line says how to start it instead."""
    code = (
        "import sys; sys.path[:0] = sys.argv[1:]\n"
        "from swarmd.px4.transport import XRCE_SOCKET, bind_udpin\n"
        "from swarmd.px4.xrce_backend import DEFAULT_XRCE_CONNECTION, parse_xrce_connection\n"
        "try:\n"
        "    bind_udpin(parse_xrce_connection(DEFAULT_XRCE_CONNECTION), unit=XRCE_SOCKET)\n"
        "except OSError as exc:\n"
        "    print(exc.errno, exc.strerror)\n"
    )
    paths = [p for p in sys.path if p and Path(p).is_dir()]
    done = subprocess.run(  # noqa: S603 - fixed argv
        ["setpriv", f"--reuid={NOBODY}", f"--regid={NOBODY}", "--clear-groups",  # noqa: S607
         sys.executable, "-I", "-c", code, *paths],
        capture_output=True, text=True, timeout=WAIT_S, check=False,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    number, _, line = done.stdout.strip().partition(" ")
    assert int(number) == errno.EACCES
    assert line.startswith("port 888 is below "), line
    assert "systemctl start swarmd-xrce.socket swarmd" in line and "\n" not in line


@pytest.mark.parametrize(
    ("backend", "fix"),
    [
        ("xrce-agent", "a port below 1024 held by swarmd-xrce.socket"),
        ("xrce-client", "run MicroXRCEAgent on a port below 1024"),
    ],
)
def test_an_unprivileged_xrce_port_is_warned_at_every_start(
    workdir: Path, backend: str, fix: str
) -> None:
    """PX4 SITL's 8888 (here a free port of the kernel's choosing, also >= 1024): any user
    may take it while swarmd (or, for a client, its MicroXRCEAgent) is down."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]

    async def main() -> None:
        daemon = _daemon(workdir, port, backend)
        with structlog.testing.capture_logs() as logs:
            try:
                await daemon.start()
            finally:
                await daemon.stop("test")
        (warning,) = [e for e in logs if e["event"] == "px4_port_unprivileged"]
        assert (warning["backend"], warning["port"]) == (backend, port)
        assert warning["socket_activated"] is False and fix in warning["fix"]

    asyncio.run(main())
