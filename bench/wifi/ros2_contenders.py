"""The ROS 2 contenders (issue 19): the paper's workload as real rclpy nodes on every drone.

Every drone runs one ``bench/wifi/peers/ros2_peer.py`` process (a ``talker`` on each member, the
``listener`` on the commander; rclpy 9.1 + rmw_fastrtps_cpp + Fast DDS 3.2.2 from the PyPI
wheels, docs/dependencies.md) in its own emulated host: a private mount namespace with its own
``/etc/machine-id`` and ``/dev/shm`` (``swarmd_lab.ros2_lab.host_argv``), because Fast DDS 3.2
otherwise takes the namespaces for one host and moves the data through shared memory, off the
channel. The contenders differ only in the environment the node starts with, which a *route*
gives per drone:

=============  =====================================================================
contender      route
=============  =====================================================================
ros2           stock defaults: SIMPLE discovery, SPDP to 239.255.0.1, SEDP (the
               paper's baseline; ROS 2 Kilted's default ``ROS_AUTOMATIC_DISCOVERY_RANGE``
               is SUBNET)
ros2-ds        Fast DDS Discovery Server: ``fast-discovery-server`` on the commander's
               host, every node a client through ``ROS_DISCOVERY_SERVER=IP:11811``
ros2-static    the files ``swarmctl ros2 profile`` writes from a bundle whose mission
               declares the graph: unicast-only SPDP to explicit peers, STATIC EDP
               (the paper's "Static discovery", Fig. 8; docs/ros2.md)
ros2-swarmd    swarmd on every drone (``ros2.relay: true``, the same bundle) serves its
               node's discovery on [::1]; the nodes get the ``swarmctl ros2 profile
               --via-swarmd`` files: 0 ROS 2 discovery datagrams on the air, only
               swarmd's own signed SPDP (docs/ros2.md, "The relay route")
=============  =====================================================================

In flight (``bench/wifi/flight_run.py``, ``--events 1``) ``ros2-swarmd``'s mission declares
one node ``drone<i>`` per drone (``ros2_mission_text``), since on the relay route the node
names of other drones come from the bundle (docs/testbed.md, "Flight scenarios"), and a
reboot kills and restarts the drone's node and its swarmd (``Ros2Contender.kill``,
``restart``).

A route is a function ``(contender) -> list of per-drone environments``; it may start
infrastructure on the drones first with ``contender.start_infrastructure`` (a process outside
the start barrier that runs until the teardown, as the discovery server and the swarmd
daemons of ``ros2-swarmd``).
"""

from __future__ import annotations

import contextlib
import io
import shutil
import signal
import subprocess
import sys
import sysconfig
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Final

from swarmd_lab.ros2_lab import own_host_argv

from bench.wifi.bundle import SWARM, mission_text
from bench.wifi.contenders import PEERS, PeerContender, _clean_env, daemon_config
from bench.wifi.peers.ros2_peer import NAMESPACE as GRAPH_NAMESPACE
from bench.wifi.peers.ros2_peer import TOPIC
from bench.wifi.topology import _sysctls as sysctls
from swarmd.bundle.build import build_dev_bundle
from swarmd.bundle.keys import dev_signing_key, public_pem, raw_public
from swarmd.bundle.mission import parse_mission
from swarmd.cli.swarmctl import main as swarmctl
from swarmd.control import DaemonUnreachable, RequestError, request

DISCOVERY_SERVER_PORT: Final = 11811  # Fast DDS's default server port (ROS 2 tutorial)
SERVER_HOST_ID: Final = 1000  # the server's machine id: not the commander node's (own /dev/shm)
# fast-discovery-server's "conventional server" command index: what `fastdds discovery`
# (tools/fastdds/discovery/parser.py in the ros-fastdds wheel) passes before the options
SERVER_COMMAND: Final = "42"
ROS2_ENV_PREFIXES: Final = ("ROS_", "RMW_", "FASTDDS_", "FASTRTPS_")
# ros2-swarmd: how long (real seconds) the daemons get to discover each other before the
# nodes start; the bundle's Tmin 8 s / Tmax 20 s are experiment seconds, dilated by k
SWARMD_CONVERGE_S: Final = 120.0

Route = Callable[["Ros2Contender"], list[dict[str, str]]]


def wheels_missing() -> str | None:
    """Why the ROS 2 contenders cannot run here (None: they can)."""
    try:
        import rclpy  # noqa: F401
        import std_msgs.msg  # noqa: F401
    except ImportError as exc:
        return f"ROS 2 wheels not installed ({exc.name}; scripts/setup.sh installs them)"
    if shutil.which("unshare") is None:
        return "unshare missing (util-linux): each emulated host needs its own mount namespace"
    if discovery_server_binary() is None:
        return "fast-discovery-server missing beside the venv's python (ros-fastdds wheel)"
    return None


def discovery_server_binary() -> Path | None:
    path = Path(sys.executable).parent / "fast-discovery-server"
    return path if path.exists() else None


def _wheel_library_path() -> str:
    """The wheels' shared libraries: the binary has no RPATH to them (rclpy loads them itself)."""
    site = Path(sysconfig.get_paths()["purelib"])
    return f"{Path(sys.prefix) / 'lib'}:{site / 'ros_fastdds.libs'}"


def ros2_env(extra: Mapping[str, str]) -> dict[str, str]:
    """A node's environment: nothing of the caller's ROS 2 settings, Fast DDS as the rmw."""
    env = {k: v for k, v in _clean_env(extra).items() if not k.startswith(ROS2_ENV_PREFIXES)}
    env["RMW_IMPLEMENTATION"] = "rmw_fastrtps_cpp"
    env["ROS_DOMAIN_ID"] = "0"
    return env


def stock_route(c: Ros2Contender) -> list[dict[str, str]]:
    """ROS 2's defaults: nothing but the rmw and the domain."""
    return [ros2_env(c.extra_env) for _ in c.drones]


def discovery_server_route(c: Ros2Contender) -> list[dict[str, str]]:
    """``fast-discovery-server`` on the commander's host, every node a client of it.

    As the ROS 2 tutorial "Using Fast DDS Discovery Server as discovery protocol" and the
    Fast DDS 2.9 ``fastdds-server`` contender: the server listens on the commander's address
    and starts before the nodes. It runs with its own machine id (and so its own /dev/shm
    could not be shared anyway): it reaches the commander's node over the namespace's own
    IP stack, never over the channel.
    """
    binary = discovery_server_binary()
    if binary is None:
        raise RuntimeError("fast-discovery-server missing beside the venv's python")
    address = c.drones[0].address
    argv = [str(binary), SERVER_COMMAND, "-i", "0", "-l", address]
    argv += ["-p", str(DISCOVERY_SERVER_PORT)]
    env = ros2_env(c.extra_env)
    env["LD_LIBRARY_PATH"] = _wheel_library_path()
    c.start_infrastructure(0, argv, env, "discovery-server", host_id=SERVER_HOST_ID)
    envs = []
    for _ in c.drones:
        e = ros2_env(c.extra_env)
        e["ROS_DISCOVERY_SERVER"] = f"{address}:{DISCOVERY_SERVER_PORT}"
        envs.append(e)
    return envs


def ros2_mission_text(addresses: list[str], *, per_drone: bool = False) -> str:
    """The testbed's mission (bench/wifi/bundle.py) plus the ROS 2 graph of the workload:
    a ``talker`` on every member and the ``listener`` on the commander, or with
    ``per_drone`` one node per drone named ``flight_node_name(i)`` (the flight observer of
    the relay route: module ``bench/wifi/peers/ros2_peer.py``), the same endpoints."""
    if per_drone:
        nodes = [
            f"    - {{name: {flight_node_name(i)}, drones: [uav{i + 1}], "
            + (f"subscribes: [{TOPIC}]}}" if i == 0 else f"publishes: [{TOPIC}]}}")
            for i in range(len(addresses))
        ]
    else:
        nodes = [
            f"    - {{name: talker, drones: member, publishes: [{TOPIC}]}}",
            f"    - {{name: listener, drones: commander, subscribes: [{TOPIC}]}}",
        ]
    return (
        mission_text(addresses, t_min_s=8.0, t_max_s=20.0, lease_s=20.0)
        + f"""\
ros2:
  domain_id: 0
  topics:
    - {{name: {TOPIC}, type: std_msgs/msg/String, reliability: reliable,
       durability: volatile, history_depth: 10}}
  nodes:
"""
        + "".join(line + "\n" for line in nodes)
    )


def flight_node_name(i: int) -> str:
    """Drone ``i``'s node on the relay route in flight: its fully qualified name
    ``/drone<i>`` is what the flight observer reads a drone from (``graph_drones``)."""
    return f"{GRAPH_NAMESPACE.removeprefix('/')}{i}"


def read_env_file(path: Path) -> dict[str, str]:
    """``KEY=VALUE`` lines of a generated ``<node>.env`` (``#`` comments skipped)."""
    out = {}
    for line in path.read_text().splitlines():
        if line and not line.startswith("#"):
            key, _, value = line.partition("=")
            out[key] = value
    return out


def _write_ros2_bundle(c: Ros2Contender) -> tuple[Path, Path]:
    """The testbed's bundle with the workload's ROS 2 graph, and its dev trust key."""
    directory = c.work / "ros2-bundle"
    directory.mkdir(parents=True, exist_ok=True)
    text = ros2_mission_text([d.address for d in c.drones], per_drone=c.per_drone_nodes)
    bundle = directory / "bundle.swb"
    bundle.write_bytes(build_dev_bundle(parse_mission(text, "wifibench-ros2.yaml")).data)
    key = directory / "swarm.pub"
    key.write_bytes(public_pem(raw_public(dev_signing_key(SWARM))))
    return bundle, key


def _profiles(c: Ros2Contender, bundle: Path, *extra: str) -> list[dict[str, str]]:
    """``swarmctl ros2 profile`` on ``bundle``; each drone's node environment from its files."""
    out = c.work / "ros2-profiles"
    said = io.StringIO()
    with contextlib.redirect_stdout(said), contextlib.redirect_stderr(said):
        argv = ["ros2", "profile", str(bundle), "--allow-dev", "--out", str(out), *extra]
        code = swarmctl(argv)
    if code != 0:
        raise RuntimeError(f"swarmctl ros2 profile exited with {code}: {said.getvalue()[-400:]}")
    envs = []
    for i in range(len(c.drones)):
        e = ros2_env(c.extra_env)
        e.update(read_env_file(out / f"uav{i + 1}" / f"{c.node_name(i)}.env"))
        envs.append(e)
    return envs


def static_route(c: Ros2Contender) -> list[dict[str, str]]:
    """The generated profiles: ``swarmctl ros2 profile`` on a bundle declaring the workload."""
    bundle, _key = _write_ros2_bundle(c)
    return _profiles(c, bundle)


def swarmd_config(c: Ros2Contender, i: int, bundle: Path, key: Path) -> Path:
    """Drone ``i``'s daemon config: the testbed's (``contenders.SwarmdContender``), adaptive
    mode with the link quality from the ns-3 link file as the swarmd contender's (a static
    quality when the contender has no link files), swarmd's data plane on as on a drone (its
    1 Hz readiness to the commander is also what the commander vouches on: without it every
    member renews on its own, docs/discovery.md "Vouching"), and the relay on
    (docs/ros2.md). The rclpy nodes carry the benchmark's workload."""
    text = daemon_config(
        i, bundle, key, swarmd_socket(c, i),
        aware=True, link_file=c.link_file(i), mode="adaptive",
        state_dir=c.work / f"state-uav{i + 1}", sections="ros2:\n  relay: true\n",
    )  # fmt: skip
    path = c.work / f"swarmd-uav{i + 1}.yaml"
    path.write_text(text)
    return path


def swarmd_socket(c: Ros2Contender, i: int) -> Path:
    return c.work / f"swarmd-uav{i + 1}.sock"


def _discovered(c: Ros2Contender, i: int) -> bool:
    try:
        st = request(str(swarmd_socket(c, i)), "status")
    except (DaemonUnreachable, RequestError, OSError, ValueError):
        return False
    return isinstance(st, dict) and st.get("peers_discovered") == c.n - 1


def swarmd_route(c: Ros2Contender) -> list[dict[str, str]]:
    """swarmd with ``ros2.relay: true`` on every drone, the nodes on ``--via-swarmd`` profiles.

    The daemons start outside the barrier and the nodes only once every daemon has
    discovered every other drone: swarmd is the drone's service already up when ROS 2 starts
    (as the discovery server of ``ros2-ds``). Its discovery before the window is therefore
    not in the window's counters; its periodic SPDP in the window is. What the window
    measures is the nodes' own discovery, which the relays answer on ``[::1]``.
    """
    bundle, key = _write_ros2_bundle(c)
    for drone in c.drones:
        # the testbed turns IPv6 off in every drone (bench/wifi/topology.py, pitfall 4); the
        # relay and the nodes' discovery need it on lo only, which never reaches the channel
        sysctls(drone.name, [("net.ipv6.conf.lo.disable_ipv6", "0")])
    for i in range(c.n):
        swarmd_config(c, i, bundle, key)
        c.start_daemon(i)
    deadline = time.monotonic() + SWARMD_CONVERGE_S
    waiting = set(range(c.n))
    while waiting:
        waiting = {i for i in waiting if not _discovered(c, i)}
        dead = [i for i, p in c.daemons.items() if p.poll() is not None]
        if dead:
            log = c.work / f"swarmd-uav{dead[0] + 1}.log"
            said = log.read_text(errors="replace")[-400:] if log.exists() else ""
            raise RuntimeError(f"ros2-swarmd: swarmd exited on drones {dead}: {said}")
        if waiting and time.monotonic() > deadline:
            raise RuntimeError(
                f"ros2-swarmd: drones {sorted(waiting)} discovered not every other drone "
                f"in {SWARMD_CONVERGE_S:g} s (swarmd-uav*.log)"
            )
        time.sleep(0.25)
    return _profiles(c, bundle, "--via-swarmd")


# contender -> route; None: named but not built here
ROUTES: Final[dict[str, Route | None]] = {
    "ros2": stock_route,
    "ros2-ds": discovery_server_route,
    "ros2-static": static_route,
    "ros2-swarmd": swarmd_route,
}


def unavailable(name: str) -> str | None:
    """Why contender ``name`` cannot run (None: it can)."""
    if ROUTES.get(name) is None:
        return f"{name}: no launch yet; set bench.wifi.ros2_contenders.ROUTES[{name!r}]"
    return wheels_missing()


class Ros2Contender(PeerContender):
    """rclpy workload nodes, one per drone in its own emulated host; the route sets discovery."""

    def _own_state(self) -> None:
        route = ROUTES.get(self.name)
        if route is None:
            raise ValueError(unavailable(self.name) or f"unknown ROS 2 contender {self.name!r}")
        self.route: Route = route
        self.infrastructure: list[subprocess.Popen[bytes]] = []
        self.daemons: dict[int, subprocess.Popen[bytes]] = {}  # ros2-swarmd: drone -> swarmd
        self._envs: list[dict[str, str]] = []

    @property
    def per_drone_nodes(self) -> bool:
        """One node per drone named ``flight_node_name(i)`` (the relay route in flight: the
        node's graph names the other drones as the bundle does, ``ros2_mission_text``)."""
        return self.flight_events and self.route is swarmd_route

    def node_name(self, i: int) -> str:
        """Drone ``i``'s node as the bundle declares it."""
        if self.per_drone_nodes:
            return flight_node_name(i)
        return "listener" if i == 0 else "talker"

    def _argv(self, i: int, barrier: Path | None, duration_s: float) -> list[str]:
        argv = super()._argv(i, barrier, duration_s)
        return [*argv, "--node", self.node_name(i)] if self.per_drone_nodes else argv

    def _program(self) -> list[str]:
        return [sys.executable, str(PEERS / "ros2_peer.py")]

    def _host(self, i: int, argv: list[str]) -> list[str]:
        return own_host_argv(argv, self.work, i)

    def _drone_env(self, i: int, env: dict[str, str]) -> dict[str, str]:
        return self._envs[i]

    def start_infrastructure(
        self,
        i: int,
        argv: list[str],
        env: dict[str, str],
        name: str,
        *,
        host_id: int,
        append: bool = False,
    ) -> subprocess.Popen[bytes]:
        """Start ``argv`` on drone ``i`` outside the barrier (it is not a contender process:
        it runs from now until the teardown, like a service already up on the drone);
        ``append``: to the log of an earlier life (a reboot)."""
        if append:
            log = (self.work / f"{name}.log").open("ab")
            self._logs.append(log)
        else:
            log = self._log(f"{name}.log")
        proc = self.drones[i].popen(
            own_host_argv(argv, self.work, host_id),
            env=env,
            stdout=log,
            stderr=subprocess.STDOUT,
        )
        self.infrastructure.append(proc)
        return proc

    def start_daemon(self, i: int, *, append: bool = False) -> subprocess.Popen[bytes]:
        """Drone ``i``'s ``swarmd run`` on its config (``swarmd_config``), in the drone's
        host (its machine id, as its node's)."""
        argv = [sys.executable, "-m", "swarmd.cli.swarmd_main", "run"]
        argv += ["--config", str(self.work / f"swarmd-uav{i + 1}.yaml")]
        name = f"swarmd-uav{i + 1}"
        env = _clean_env(self.extra_env)
        self.daemons[i] = self.start_infrastructure(i, argv, env, name, host_id=i, append=append)
        return self.daemons[i]

    def kill(self, i: int) -> None:
        """A reboot's power cut (docs/testbed.md, "Flight"): the node and, on the relay
        route, the drone's swarmd too: both run on its companion computer."""
        super().kill(i)
        daemon = self.daemons.get(i)
        if daemon is not None and daemon.poll() is None:
            daemon.send_signal(signal.SIGKILL)
            daemon.wait(timeout=10)

    def restart(self, i: int, duration_s: float, state: str = "kept") -> None:
        """The reboot's start: on the relay route swarmd first (its state dir deleted for
        ``lost``), then at once the node, as a companion computer starts its services in
        parallel at boot, not after swarmd has found anyone (which the route's first start
        waits for). The node's SPDP to a relay not yet listening is lost; its next
        announcement, or the relay's DATA(p) once swarmd finds a drone, makes up for it."""
        if i in self.daemons:
            if state == "lost":
                shutil.rmtree(self.work / f"state-uav{i + 1}", ignore_errors=True)
            self.start_daemon(i, append=True)
        super().restart(i, duration_s, state)

    def start(self, barrier: Path) -> None:
        self._envs = self.route(self)
        if len(self._envs) != self.n:
            raise RuntimeError(f"{self.name}: the route gave {len(self._envs)} environments")
        super().start(barrier)
