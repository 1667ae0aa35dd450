"""Issue 18: the production layout under attack by a local user.

swarmd is installed as ``docs/deploy.md`` says and started the way ``systemd/swarmd.service``
does (user ``swarmd``, its directories and modes, its hardening where a namespace allows,
the PX4 ports from ``swarmd-px4.socket`` and ``swarmd-xrce.socket`` as descriptors 3 on),
all inside namespaces of its own (``tests/layout``). The attacker is ``swarmd-attacker``, a
local user with a shell; the operator ``swarmd-operator`` is in group ``swarmd`` as the docs
allow. Every probe is bounded in count and time.
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, Final

import pytest
import yaml

from tests.layout.install import ProductionLayout, shipped_config, unavailable_reason

pytestmark = pytest.mark.skipif(unavailable_reason() is not None, reason=str(unavailable_reason()))

ATTACKER: Final = "swarmd-attacker"
OPERATOR: Final = "swarmd-operator"
PX4_PORT: Final = 540  # systemd/swarmd-px4.socket, config/swarmd.yaml
SITL_PORT: Final = 14540  # an unprivileged port: what the socket unit alone cannot protect
CONFIG: Final = "/etc/swarmd/swarmd.yaml"
STATE: Final = "/var/lib/swarmd"
NODE_KEY: Final = f"{STATE}/node.key"
WAIT_S: Final = 30.0

# A local user's probes: each op -> "ok" or the errno's name. Standard library only.
PROBE: Final = r"""
import errno, json, os, socket, sys
out = {}
for kind, arg in json.loads(sys.argv[1]):
    key = f"{kind} {arg}"
    try:
        if kind == "read":
            if os.path.isdir(arg):
                os.listdir(arg)
            else:
                with open(arg, "rb") as f:
                    f.read(1)
        elif kind == "write":
            with open(arg, "ab"):
                pass
        elif kind == "connect":
            s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
            s.settimeout(2)
            try:
                s.connect(arg)
            finally:
                s.close()
        elif kind in ("bind", "bind-reuse"):
            host, port = arg
            s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            if kind == "bind-reuse":
                s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            try:
                s.bind((host, port))
            finally:
                s.close()
        out[key] = "ok"
    except OSError as exc:
        out[key] = errno.errorcode.get(exc.errno or 0, str(exc.errno))
print(json.dumps(out))
"""

# A squatter that holds its port until stdin closes: binds, says where, counts datagrams.
SQUATTER: Final = r"""
import json, os, select, socket, sys
host, port, reuse = sys.argv[1], int(sys.argv[2]), sys.argv[3] == "1"
s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
if reuse:
    s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
try:
    s.bind((host, port))
except OSError as exc:
    print(json.dumps({"bound": False, "errno": exc.errno}), flush=True)
    raise SystemExit(0)
print(json.dumps({"bound": True, "pid": os.getpid()}), flush=True)
got = 0
while True:
    ready, _, _ = select.select([s, sys.stdin], [], [], 60)
    if not ready or sys.stdin in ready:
        break
    s.recv(65536)
    got += 1
print(json.dumps({"received": got}), flush=True)
"""


@pytest.fixture
def layout(tmp_path: Path) -> Iterator[ProductionLayout]:
    installed = ProductionLayout(tmp_path)
    try:
        yield installed
    finally:
        installed.close()


def probe(layout: ProductionLayout, user: str, *ops: tuple[str, Any]) -> dict[str, str]:
    result: dict[str, str] = layout.python(PROBE, json.dumps(ops), user=user)
    return result


class Squatter:
    """A local user's process holding a UDP port inside the layout's namespaces."""

    def __init__(self, layout: ProductionLayout, port: int, *, reuse: bool) -> None:
        self.proc = subprocess.Popen(  # noqa: S603 - argv list
            layout.command(
                [sys.executable, "-I", "-c", SQUATTER, "127.0.0.1", str(port), str(int(reuse))],
                ATTACKER,
            ),
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
        )
        assert self.proc.stdout is not None
        self.hello: dict[str, Any] = json.loads(self.proc.stdout.readline())

    def received(self) -> int:
        """Stop it; how many datagrams it was sent while it held the port."""
        assert self.proc.stdin is not None and self.proc.stdout is not None
        self.proc.stdin.close()
        line = self.proc.stdout.readline()
        self.proc.wait(timeout=WAIT_S)
        self.proc.stdout.close()
        return int(json.loads(line)["received"]) if line else 0

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(timeout=WAIT_S)
        for stream in (self.proc.stdin, self.proc.stdout):
            if stream is not None and not stream.closed:
                stream.close()


def use_port(layout: ProductionLayout, port: int) -> None:
    """Point the installed config's px4.connection at ``port`` (mode and owner kept)."""
    layout.python(
        "import json,sys,pathlib; p=pathlib.Path(sys.argv[1]); "
        "p.write_text(p.read_text().replace(sys.argv[2], sys.argv[3])); print('{}')",
        CONFIG, f"udpin:127.0.0.1:{PX4_PORT}", f"udpin:127.0.0.1:{port}",
    )  # fmt: skip


def last_error(layout: ProductionLayout) -> list[str]:
    """The daemon's stderr lines that are not JSON log lines (start-up failures)."""
    return [line for line in layout.log_lines() if line.startswith("swarmd: ")]


def wait_for(check: Callable[[], bool], what: str) -> None:
    deadline = time.monotonic() + WAIT_S
    while not check():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.2)


# ---- files ----------------------------------------------------------------------------------

FILES_CHECK: Final = r"""
import json, os, pwd, stat, sys
out = {}
for top in sys.argv[1:]:
    for path in [top] + [os.path.join(d, n) for d, ds, fs in os.walk(top) for n in ds + fs]:
        st = os.lstat(path)
        out[path] = [stat.S_IMODE(st.st_mode), pwd.getpwuid(st.st_uid).pw_name]
print(json.dumps(out))
"""


def test_config_state_and_secrets_are_not_readable_by_other_users(
    layout: ProductionLayout,
) -> None:
    assert layout.socket_unit(PX4_PORT)["ok"]
    assert layout.start()["ready"]  # the daemon wrote its epoch and state file
    modes: dict[str, list[Any]] = layout.python(FILES_CHECK, "/etc/swarmd", STATE, user=None)
    assert NODE_KEY in modes and f"{STATE}/bundle.swb" in modes and CONFIG in modes
    assert any("auth-epoch" in path for path in modes)  # written by the daemon, under umask
    # the anti-rollback floor (docs/security.md, "Bundle rollback"): the daemon's, 0640
    assert modes[f"{STATE}/bundle-floor-lead"] == [0o640, "swarmd"]
    # the state directory shuts everyone else out (what it holds besides node.key is public:
    # the bundle, swarm.pub, node.name, the boot epoch every SPDP announces); node.key is the
    # daemon's alone even without it; the config and its directory are root's and swarmd's
    for path in ("/etc/swarmd", CONFIG, STATE):
        assert modes[path][0] & 0o007 == 0, f"{path} is open to other users: {modes[path]}"
    assert modes[NODE_KEY] == [0o600, "swarmd"]
    assert modes[STATE] == [0o700, "swarmd"]
    assert modes[CONFIG] == [0o640, "root"]
    targets = [("read", path) for path in modes] + [("write", CONFIG), ("write", NODE_KEY)]
    for user in (ATTACKER, OPERATOR):
        seen = probe(layout, user, *targets)
        readable = {k for k, v in seen.items() if v == "ok"}
        if user == ATTACKER:
            assert readable == set(), readable
        else:  # the operator's group may read the config, nothing in the state directory
            assert readable == {f"read {CONFIG}", "read /etc/swarmd"}, readable
        assert all(v == "EACCES" for k, v in seen.items() if k not in readable), seen


def test_control_socket_serves_the_operator_and_refuses_a_local_user(
    layout: ProductionLayout,
) -> None:
    assert layout.socket_unit(PX4_PORT)["ok"]
    assert layout.start()["ready"]
    sock = "/run/swarmd/swarmd.sock"
    assert probe(layout, ATTACKER, ("connect", sock)) == {f"connect {sock}": "EACCES"}
    refused = layout.swarmctl("status", user=ATTACKER)
    assert refused.returncode == 2 and refused.stderr.count("\n") == 1, refused.stderr
    served = layout.swarmctl("status", "--json", user=OPERATOR)
    assert served.returncode == 0, served.stderr
    assert json.loads(served.stdout)["node"] == "lead"
    assert probe(layout, OPERATOR, ("connect", sock)) == {f"connect {sock}": "ok"}


def test_node_key_readable_by_others_stops_start_up_and_a_readable_config_warns(
    layout: ProductionLayout,
) -> None:
    assert layout.socket_unit(PX4_PORT)["ok"]
    assert layout.run(["chmod", "0640", NODE_KEY]).returncode == 0
    reply = layout.start()
    assert reply == {"ready": False, "exit": 78}
    assert last_error(layout) == [
        f"swarmd: node key rejected: {NODE_KEY}: mode 0640 lets other users read this node's "
        f"private keys; fix: chmod 600 {NODE_KEY} (owner swarmd)"
    ]
    assert layout.run(["chmod", "0600", NODE_KEY]).returncode == 0
    assert layout.run(["chmod", "0644", CONFIG]).returncode == 0
    assert layout.start()["ready"]  # a warning, not a refusal
    # logged right after READY=1 (the "started" line's neighbour)
    wait_for(lambda: any('"config_mode"' in x for x in layout.log_lines()), "config_mode")
    warnings = [json.loads(x) for x in layout.log_lines() if '"config_mode"' in x]
    assert len(warnings) == 1 and "chmod 640" in warnings[0]["problem"]


def test_check_config_as_root_judges_the_state_folder_for_the_units_user(tmp_path: Path) -> None:
    """An operator points ``dataplane.state_dir`` at a folder root made (0755 root): root
    could write it, the daemon's user ``swarmd`` cannot. ``swarmd check-config`` run as root
    judges for ``swarmd`` (the unit's ``User=``) and refuses with the line and exit code the
    daemon's start gives (73). Judged for root (``--user root``) the folder passes, and
    since session 15 the installed unit's sandbox refuses it: ``ProtectSystem=strict``
    leaves /var/lib/swarmd-state read-only, as the start then finds (before, the check
    said ok and only the start stopped)."""
    state = "/var/lib/swarmd-state"  # /var/lib is the namespace's overlay: never the host's
    config = yaml.safe_load(shipped_config())
    config["dataplane"]["state_dir"] = state
    installed = ProductionLayout(tmp_path, config=yaml.safe_dump(config, sort_keys=False))
    try:
        assert installed.run(["install", "-d", "-m", "0755", state]).returncode == 0
        assert installed.socket_unit(PX4_PORT)["ok"]
        check = installed.run(["/opt/swarmd/venv/bin/swarmd", "check-config", "--config", CONFIG])
        assert check.returncode == 73, check
        assert check.stderr.count("\n") == 1, check.stderr
        assert "user swarmd" in check.stderr and state in check.stderr
        assert installed.start() == {"ready": False, "exit": 73}
        assert last_error(installed) == [check.stderr.rstrip("\n")]
        judged_as_root = installed.run(
            ["/opt/swarmd/venv/bin/swarmd", "check-config", "--config", CONFIG, "--user", "root"]
        )
        assert judged_as_root.returncode == 73, judged_as_root
        assert "ProtectSystem=strict" in judged_as_root.stderr
        assert "/etc/systemd/system/swarmd.service" in judged_as_root.stderr
        # a folder swarmd owns passes the folder check, made outside the unit's sandbox;
        # the unit's reading refuses it, and inside, the start stops on the mount
        assert installed.run(["chown", "swarmd:swarmd", state]).returncode == 0
        again = installed.run(["/opt/swarmd/venv/bin/swarmd", "check-config", "--config", CONFIG])
        assert again.returncode == 73, again
        assert (
            "field dataplane.state_dir" in again.stderr and "ProtectSystem=strict" in again.stderr
        )
        assert installed.start() == {"ready": False, "exit": 73}
        assert "read-only mount for user swarmd" in last_error(installed)[-1]
    finally:
        installed.close()


def test_check_config_says_it_judged_as_the_installed_units_user(layout: ProductionLayout) -> None:
    """The install of docs/deploy.md: ``check-config`` reads ``User=swarmd``,
    ``Group=swarmd`` and ``SupplementaryGroups=dialout`` from the installed unit and names
    whose view it judged the state folders from, and where that came from (session 15)."""
    check = layout.run(["/opt/swarmd/venv/bin/swarmd", "check-config", "--config", CONFIG])
    assert check.returncode == 0, check
    assert "judged as swarmd (User= of /etc/systemd/system/swarmd.service)" in check.stdout


# ---- the PX4 link's port ------------------------------------------------------------------


def test_the_px4_port_cannot_be_taken_at_boot_during_a_restart_or_while_swarmd_runs(
    layout: ProductionLayout,
) -> None:
    grabs = [
        ("bind", ["127.0.0.1", PX4_PORT]),
        ("bind-reuse", ["127.0.0.1", PX4_PORT]),
        ("bind-reuse", ["0.0.0.0", PX4_PORT]),  # noqa: S104 - the attacker's wildcard
    ]
    # at boot, even before systemd binds it: below 1024, no user may bind it
    assert set(probe(layout, ATTACKER, *grabs).values()) == {"EACCES"}
    assert layout.socket_unit(PX4_PORT)["ok"]  # sockets.target
    assert set(probe(layout, ATTACKER, *grabs).values()) == {"EACCES"}
    assert layout.start()["ready"]
    assert set(probe(layout, ATTACKER, *grabs).values()) == {"EACCES"}
    assert layout.stop()["exit"] == 0  # the restart's window
    assert set(probe(layout, ATTACKER, *grabs).values()) == {"EACCES"}
    assert layout.start()["ready"]  # the same socket, passed again
    assert not last_error(layout)


def test_an_unprivileged_port_squatter_is_named_and_the_socket_unit_alone_is_not_enough(
    layout: ProductionLayout,
) -> None:
    """Port 14540 (PX4 SITL's): what the privileged port avoids, and the start-up line."""
    use_port(layout, SITL_PORT)
    squatter = Squatter(layout, SITL_PORT, reuse=False)
    try:
        assert squatter.hello["bound"]
        # without the socket unit: swarmd (user swarmd) cannot start and names the user
        assert layout.start() == {"ready": False, "exit": 71}
        (line,) = last_error(layout)
        assert f"port {SITL_PORT} is held by user {ATTACKER} (uid " in line
        assert "fix: stop it, and let systemd hold the port" in line
        # started by hand as root: the pid and the command too
        manual = layout.run(
            ["/opt/swarmd/venv/bin/swarmd", "run", "--config", CONFIG], timeout=WAIT_S
        )
        assert manual.returncode == 71
        (line,) = [x for x in manual.stderr.splitlines() if x.startswith("swarmd: ")]
        assert f"pid {squatter.hello['pid']} user {ATTACKER}" in line
        assert "python" in line  # its command line
    finally:
        squatter.close()
    # the socket unit on an unprivileged port: systemd binds it with SO_REUSEADDR, so a
    # user can bind beside it before swarmd first starts and would get every datagram
    assert layout.socket_unit(SITL_PORT)["ok"]
    beside = Squatter(layout, SITL_PORT, reuse=True)
    try:
        assert beside.hello["bound"]
        assert layout.start() == {"ready": False, "exit": 71}
        assert f"port {SITL_PORT} is also bound by pid" not in last_error(layout)[-1]
        assert f"is also bound by user {ATTACKER}" in last_error(layout)[-1]
    finally:
        beside.close()
    # once swarmd has cleared the flag, binding beside it fails, also across a restart
    assert layout.start()["ready"]
    grab = ("bind-reuse", ["127.0.0.1", SITL_PORT])
    assert set(probe(layout, ATTACKER, grab).values()) == {"EADDRINUSE"}
    assert layout.stop()["exit"] == 0
    assert set(probe(layout, ATTACKER, grab).values()) == {"EADDRINUSE"}
    assert layout.start()["ready"]


def test_the_autopilots_frames_reach_swarmd_and_no_local_user(layout: ProductionLayout) -> None:
    assert layout.socket_unit(PX4_PORT)["ok"]
    assert layout.start()["ready"]
    sim = layout.popen(
        [
            str(Path(sys.executable).parent / "swarmd-vehicle-sim"),
            *("--connect", f"udpout:127.0.0.1:{PX4_PORT}", "--sysid", "1"),
            *("--signing-key", str(layout.px4_key), "--gps-fix-after", "0.5"),
            *("--duration", str(int(WAIT_S * 3))),
        ]
    )
    try:

        def signed_frames() -> int:
            done = layout.swarmctl("status", "--json", user=OPERATOR)
            if done.returncode != 0:
                return 0
            backend = json.loads(done.stdout)["px4"]["backend"]
            return int(backend["signing"]["ok"])

        wait_for(lambda: signed_frames() > 5, "signed frames from the simulator")
        # the attacker can bind neither the port nor anything that hears it
        grab = ("bind-reuse", ["127.0.0.1", PX4_PORT])
        assert set(probe(layout, ATTACKER, grab).values()) == {"EACCES"}
        before = signed_frames()
        assert layout.stop()["exit"] == 0
        assert set(probe(layout, ATTACKER, grab).values()) == {"EACCES"}
        assert layout.start()["ready"]
        wait_for(lambda: signed_frames() > 5, "signed frames after the restart")
        assert before > 5
    finally:
        sim.kill()
        sim.wait(timeout=WAIT_S)


def test_shipped_config_for_the_layout_is_the_documented_one() -> None:
    """The layout runs the shipped config: only node, interface, link and log format set."""
    text = shipped_config()
    assert f"connection: udpin:127.0.0.1:{PX4_PORT}" in text
    assert "signing: true" in text


def test_the_install_leaves_nothing_on_the_host(tmp_path: Path) -> None:
    """Users, /etc/swarmd, /opt/swarmd and the daemon exist only while the layout does."""
    host_passwd = Path("/etc/passwd").read_text()
    paths = [Path(p) for p in ("/etc/swarmd", "/opt/swarmd", STATE, "/run/swarmd")]
    existed = [p.exists() for p in paths]
    installed = ProductionLayout(tmp_path)
    try:
        assert installed.socket_unit(PX4_PORT)["ok"]
        daemon = installed.start()
        assert daemon["ready"]
        inside = installed.run(["getent", "passwd", ATTACKER])
        assert inside.returncode == 0  # the user exists in there
    finally:
        installed.close()
    assert Path("/etc/passwd").read_text() == host_passwd
    assert [p.exists() for p in paths] == existed
    assert not Path(f"/proc/{daemon['pid']}").exists()
    assert not Path(f"/proc/{installed.pid}").exists()


# ---- the uXRCE-DDS agent's port -----------------------------------------------------------

XRCE_PORT: Final = 888  # systemd/swarmd-xrce.socket, px4.backend: xrce-agent's default
XRCE_KEY: Final = 7  # PX4's UXRCE_DDS_KEY in these runs

# PX4's uxrce_dds_client, played by swarmd's own client engine (tests/xrce_vehicle.py) from
# inside the layout's namespaces: it opens its session and starts over after missed pings.
XRCE_VEHICLE: Final = r"""
import asyncio, sys
sys.path.insert(0, sys.argv[1])
from tests.xrce_vehicle import XrceVehicle

async def main() -> None:
    vehicle = XrceVehicle(int(sys.argv[2]), 1, ("127.0.0.1", int(sys.argv[3])))
    await vehicle.start()
    await asyncio.sleep(float(sys.argv[4]))
    vehicle.kill()

asyncio.run(main())
"""


@pytest.fixture
def xrce_layout(tmp_path: Path) -> Iterator[ProductionLayout]:
    """The shipped config with swarmd as PX4's uXRCE-DDS agent on its default port."""
    config = shipped_config(backend="xrce-agent", connection=f"udp:127.0.0.1:{XRCE_PORT}")
    installed = ProductionLayout(tmp_path, config=config)
    try:
        yield installed
    finally:
        installed.close()


def xrce_backend(layout: ProductionLayout) -> dict[str, Any]:
    done = layout.swarmctl("status", "--json", user=OPERATOR)
    if done.returncode != 0:
        return {}
    backend: dict[str, Any] = json.loads(done.stdout)["px4"]["backend"]
    return backend


def test_the_xrce_agent_port_cannot_be_taken_at_boot_during_a_restart_or_while_swarmd_runs(
    xrce_layout: ProductionLayout,
) -> None:
    layout = xrce_layout
    grabs = [
        ("bind", ["127.0.0.1", XRCE_PORT]),
        ("bind-reuse", ["127.0.0.1", XRCE_PORT]),
        ("bind-reuse", ["0.0.0.0", XRCE_PORT]),  # noqa: S104 - the attacker's wildcard
    ]
    # at boot, before systemd binds it: below 1024, no user may bind it
    assert set(probe(layout, ATTACKER, *grabs).values()) == {"EACCES"}
    # sockets.target: both units, as the service's Sockets= lists them
    assert layout.socket_unit(PX4_PORT, "px4")["ok"]
    assert layout.socket_unit(XRCE_PORT, "xrce")["ok"]
    assert set(probe(layout, ATTACKER, *grabs).values()) == {"EACCES"}
    assert layout.start()["ready"]
    assert set(probe(layout, ATTACKER, *grabs).values()) == {"EACCES"}
    backend = xrce_backend(layout)
    assert (backend["backend"], backend["connection"]) == ("xrce-agent", "udp:127.0.0.1:888")
    # the MAVLink unit's descriptor is closed unused (info, not a warning); no port warning
    events = [json.loads(x) for x in layout.log_lines() if x.startswith("{")]
    (unused,) = [e for e in events if e["event"] == "listen_fd_unused"]
    assert (unused["name"], unused["level"]) == ("px4", "info")
    assert not [e for e in events if e["event"] == "px4_port_unprivileged"]
    assert layout.stop()["exit"] == 0  # the restart's window
    assert set(probe(layout, ATTACKER, *grabs).values()) == {"EACCES"}
    assert layout.start()["ready"]  # the same socket, passed again
    assert set(probe(layout, ATTACKER, *grabs).values()) == {"EACCES"}
    assert not last_error(layout)


def test_pxs_xrce_session_reaches_swarmd_across_a_restart_and_no_local_user(
    tmp_path: Path,
) -> None:
    config = shipped_config(
        backend="xrce-agent", connection=f"udp:127.0.0.1:{XRCE_PORT}", xrce_key=XRCE_KEY
    )
    layout = ProductionLayout(tmp_path, config=config)
    try:
        assert layout.socket_unit(XRCE_PORT, "xrce")["ok"]
        assert layout.start()["ready"]
        vehicle = layout.popen(
            [sys.executable, "-I", "-c", XRCE_VEHICLE, str(Path(__file__).parents[1]),
             str(XRCE_KEY), str(XRCE_PORT), str(WAIT_S * 3)],
            user=None,  # root, as PX4 SITL would run
        )  # fmt: skip
        try:

            def established() -> bool:
                backend = xrce_backend(layout)
                return backend.get("session") == "established" and backend.get("samples", 0) > 5

            wait_for(established, "PX4's session at swarmd's agent")
            grab = ("bind-reuse", ["127.0.0.1", XRCE_PORT])
            assert set(probe(layout, ATTACKER, grab).values()) == {"EACCES"}
            assert layout.stop()["exit"] == 0
            assert set(probe(layout, ATTACKER, grab).values()) == {"EACCES"}
            assert layout.start()["ready"]
            # the client starts over after missed pings, on the same port: served again
            wait_for(established, "PX4's session after the restart")
        finally:
            vehicle.kill()
            vehicle.wait(timeout=WAIT_S)
    finally:
        layout.close()
