"""The contenders: how each is started on every drone and how its commander is read.

swarmd and its ablations are real ``swarmd run`` daemons (one per drone namespace) with
a dev bundle of N members (uav1 commands, the paper's Tmin 8 s, Tmax 20 s, lease 20 s)
and the ns-3 link file as link source. Stock Cyclone DDS and zenoh run the workload
scripts in ``bench/wifi/peers/``.

=================  =========  ==========================  =================================
contender          mode       link quality (awareness)    timing
=================  =========  ==========================  =================================
swarmd             adaptive   ns-3 link file              bundle (Tmin 8, Tmax 20)
swarmd-paper       paper      ns-3 link file              bundle (Tmin 8, Tmax 20)
swarmd-noaware     adaptive   static Q = 0.5              bundle
swarmd-stock       paper      static Q = 0.5              Tmin = Tmax = 0: announce at once
=================  =========  ==========================  =================================

"Preloading off" cannot be expressed: swarmd has no SEDP at all, its endpoints always come
from the bundle. ``swarmd-stock`` (awareness off and stock-like immediate SPDP) is the
closest ablation; the stock stacks are the preloading-off reference.

Stock stacks: ``cyclonedds`` and ``zenoh`` (Python workload scripts), ``fastdds`` (Debian's
Fast DDS 2.9.1 under ``peers/fastdds_peer.cpp``: SPDP multicast + SEDP, its defaults) and
``fastdds-server`` (the same peer as a Discovery Server client; the server, ``fastdds
discovery`` from fastdds-tools, runs on the commander's node, as the ROS 2 tutorial "Using
Fast DDS Discovery Server as discovery protocol" sets it up: ``fastdds discovery -i 0 -l
IP -p 11811`` and ``ROS_DISCOVERY_SERVER=IP:11811`` for every participant).
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final

from swarmd_lab.netns import Namespace

from bench.wifi.barrier import LAUNCH_NICE
from bench.wifi.bundle import write_bundle
from bench.wifi.native import fastdds_discovery_server, fastdds_peer
from swarmd.config import _FIELDS as CONFIG_FIELDS
from swarmd.control import DaemonUnreachable, RequestError, request

REPO: Final = Path(__file__).resolve().parents[2]
PEERS: Final = Path(__file__).resolve().parent / "peers"


@dataclass(frozen=True)
class SwarmdVariant:
    mode: str
    aware: bool
    overrides: Mapping[str, float] = field(default_factory=dict)


SWARMD_VARIANTS: Final[dict[str, SwarmdVariant]] = {
    "swarmd": SwarmdVariant("adaptive", True),
    "swarmd-paper": SwarmdVariant("paper", True),
    "swarmd-noaware": SwarmdVariant("adaptive", False),
    "swarmd-stock": SwarmdVariant("paper", False, {"t_min_s": 0.0, "t_max_s": 0.0}),
}
PEER_SCRIPTS: Final = {"cyclonedds": "cyclone_peer.py", "zenoh": "zenoh_peer.py"}
FASTDDS: Final = ("fastdds", "fastdds-server")
# real rclpy nodes (bench/wifi/ros2_contenders.py; ros2-swarmd: swarmd relays their discovery)
ROS2: Final = ("ros2", "ros2-ds", "ros2-static", "ros2-swarmd")
CONTENDERS: Final = (*SWARMD_VARIANTS, *PEER_SCRIPTS, *FASTDDS, *ROS2)
DISCOVERY_SERVER_PORT: Final = 11811  # Fast DDS's default server port (ROS 2 tutorial)


def family(contender: str) -> str:
    """Which discovery frame class counts for this contender (metrics.DISCOVERY_CLASSES)."""
    return "zenoh" if contender == "zenoh" else "rtps"


def unavailable(name: str) -> str | None:
    """Why contender ``name`` cannot run on this machine, found before any run (None: it can)."""
    if name in ROS2:
        from bench.wifi.ros2_contenders import unavailable as ros2_unavailable

        return ros2_unavailable(name)
    return None


def dataplane_supported() -> bool:
    """Whether this swarmd's config has a ``dataplane`` section (the 1 Hz readiness stream)."""
    return "dataplane" in CONFIG_FIELDS.get("<top>", ())


def daemon_config(
    i: int,
    bundle: Path,
    key: Path,
    socket: Path,
    *,
    aware: bool,
    link_file: Path | None,
    mode: str,
    overrides: Mapping[str, object] | None = None,
    state_dir: Path,
    sections: str = "",
) -> str:
    """Drone ``i``'s ``swarmd run`` config on the testbed: the bundle, the control socket, the
    link quality from the ns-3 link file (``aware``; else a static Q of 0.5), the discovery
    mode and overrides, swarmd's data plane (state in ``state_dir``) when this swarmd has
    one, then ``sections`` (e.g. ``ros2:``). Shared by the swarmd and ros2-swarmd contenders."""
    sources = "[file, static]" if aware and link_file is not None else "[static]"
    file_line = f"  file: {link_file}\n" if link_file is not None else ""
    over = (
        "{" + ", ".join(f"{k}: {val}" for k, val in overrides.items()) + "}" if overrides else "{}"
    )
    dataplane = (
        f"dataplane:\n  enabled: true\n  state_dir: {state_dir}\n" if dataplane_supported() else ""
    )
    return f"""\
node: uav{i + 1}
bundle:
  path: {bundle}
  trusted_key: {key}
  allow_dev: true
network:
  interface: eth0
control:
  socket: {socket}
link:
  sources: {sources}
  poll_interval_s: 1.0
{file_line}  static_q: 0.5
discovery:
  mode: {mode}
  overrides: {over}
{dataplane}{sections}logging:
  level: info
  format: json
"""


def _clean_env(extra: Mapping[str, str] | None = None) -> dict[str, str]:
    drop = (
        "CYCLONEDDS_URI",
        "ZENOH_CONFIG",
        "RUST_LOG",
        "SWARMD_SOCKET",
        "ROS_DISCOVERY_SERVER",
        "FASTRTPS_DEFAULT_PROFILES_FILE",
        "FASTDDS_DEFAULT_PROFILES_FILE",
        "LD_PRELOAD",
        "BENCH_DILATION",
    )
    env = {k: v for k, v in os.environ.items() if k not in drop}
    env["PYTHONPATH"] = str(REPO)
    env.update(extra or {})
    return env


@dataclass
class Observation:
    """What the harness learnt about discovery and delivery during one run (wall times)."""

    started: dict[int, float] = field(default_factory=dict)  # per drone: stack up
    all_discovered: float | None = None
    received: dict[str, dict[str, Any]] = field(default_factory=dict)
    note: str = ""
    success_pending: bool = False
    # swarmd: the daemons' own send counters summed at the window's end (engine tx_kind:
    # announce/reply/renewal/dispose datagrams; tx_multicast/tx_unicast)
    tx_counters: dict[str, int] = field(default_factory=dict)


def _niced(argv: list[str]) -> list[str]:
    # start-up (imports, bundle check) at low priority; run.py restores it before release
    return ["nice", "-n", str(LAUNCH_NICE), *argv]


class Contender:
    """Start a contender on every drone, then ``poll`` during the run and ``finish``.

    ``start(barrier)`` launches every process; each blocks on the UNIX socket ``barrier``
    after its start-up (bench/wifi/barrier.py) until the harness releases them all. Every
    contender is built with this one signature (``make``); a subclass sets its own fields
    in ``_own_state``.
    """

    def __init__(
        self,
        name: str,
        drones: list[Namespace],
        work: Path,
        *,
        window_s: float,
        messages: int,
        env: Mapping[str, str] | None = None,
        link_dir: Path | None = None,
    ) -> None:
        self.name = name
        self.extra_env = dict(env or {})  # e.g. the run's time dilation (bench/wifi/dilation.py)
        self.drones = drones
        self.work = work
        self.window_s = window_s
        self.messages = messages
        # the ns-3 link files (link-<i>.json): swarmd's daemons (the swarmd and ros2-swarmd
        # contenders) read their link quality there; None: a static quality
        self.link_dir = link_dir
        self.n = len(drones)
        self.obs = Observation()
        self.procs: list[subprocess.Popen[bytes]] = []
        self._logs: list[Any] = []
        self._own_state()

    def _own_state(self) -> None:
        """A subclass's own fields, set at the end of ``__init__``."""

    def link_file(self, i: int) -> Path | None:
        """Drone ``i``'s ns-3 link file (None: the contender has none)."""
        return None if self.link_dir is None else self.link_dir / f"link-{i}.json"

    def start(self, barrier: Path) -> None:
        raise NotImplementedError

    def poll(self, now: float) -> None:
        """Called about every 0.25 s while the window runs."""

    def window_end(self) -> None:
        """Called once when the window closes, before the channel stops."""

    def finish(self) -> Observation:
        raise NotImplementedError

    def _log(self, name: str) -> Any:
        f = (self.work / name).open("wb")
        self._logs.append(f)
        return f

    def close(self) -> None:
        for f in self._logs:
            f.close()


class PeerContender(Contender):
    """Cyclone DDS or zenoh: one workload script per drone, results from their files."""

    def _program(self) -> list[str]:
        return [sys.executable, str(PEERS / PEER_SCRIPTS[self.name])]

    def _env(self) -> dict[str, str]:
        return _clean_env(self.extra_env)

    def _drone_env(self, i: int, env: dict[str, str]) -> dict[str, str]:
        """Drone ``i``'s environment (the ROS 2 contenders set it per drone)."""
        return env

    def _host(self, i: int, argv: list[str]) -> list[str]:
        """How drone ``i`` runs ``argv`` (the ROS 2 contenders wrap it in its own host)."""
        return argv

    # flight runs (bench/wifi/flight_run.py): every peer reports its stack's discovery
    # events on its stdout (bench/wifi/peers/common.py, FlightEvents)
    flight_events = False

    def _argv(self, i: int, barrier: Path | None, duration_s: float) -> list[str]:
        argv = [
            *self._program(),
            "--index",
            str(i),
            "--n",
            str(self.n),
            "--duration",
            str(duration_s),
            "--messages",
            str(self.messages),
            "--out",
            str(self.work / f"peer-{i}.json"),
        ]
        if barrier is not None:
            argv += ["--barrier", str(barrier)]
        if self.flight_events:
            argv += ["--events", "1"]
        return argv

    def start(self, barrier: Path) -> None:
        env = self._env()
        for i, drone in enumerate(self.drones):
            self.procs.append(
                drone.popen(
                    _niced(self._host(i, self._argv(i, barrier, self.window_s))),
                    env=self._drone_env(i, env),
                    stdout=self._log(f"peer-{i}.log"),
                    stderr=subprocess.STDOUT,
                )
            )

    def kill(self, i: int) -> None:
        """A reboot in the air: drone ``i``'s peer killed at once (SIGKILL: no goodbye)."""
        self.procs[i].send_signal(signal.SIGKILL)
        self.procs[i].wait(timeout=10)

    def restart(self, i: int, duration_s: float, state: str = "kept") -> None:
        """Start drone ``i``'s peer again (a reboot in the air: no barrier, the rest of the
        window), its log appended to (a flight event ``hello`` opens the new life). A stock
        peer keeps no state dir: ``state`` ``kept`` and ``lost`` are alike."""
        log = (self.work / f"peer-{i}.log").open("ab")
        self._logs.append(log)
        self.procs[i] = self.drones[i].popen(
            self._host(i, self._argv(i, None, duration_s)),
            env=self._drone_env(i, self._env()),
            stdout=log,
            stderr=subprocess.STDOUT,
        )

    def finish(self) -> Observation:
        deadline = time.monotonic() + 15.0
        results: dict[int, dict[str, Any]] = {}
        while time.monotonic() < deadline and len(results) < self.n:
            for i in range(self.n):
                path = self.work / f"peer-{i}.json"
                if i not in results and path.exists():
                    results[i] = json.loads(path.read_text())
            time.sleep(0.2)
        for i, r in results.items():
            self.obs.started[i] = float(r["started"])
        commander = results.get(0, {})
        self.obs.received = dict(commander.get("received") or {})
        ad = commander.get("all_discovered")
        self.obs.all_discovered = float(ad) if isinstance(ad, int | float) else None
        missing = sorted(set(range(self.n)) - set(results))
        if missing:
            self.obs.note = f"no result from drones {missing} (crashed or hung; see peer-*.log)"
        return self.obs


class FastddsContender(PeerContender):
    """Fast DDS 2.9.1 peers (``fastdds_peer``); ``fastdds-server``: Discovery Server clients.

    For ``fastdds-server`` the server starts on the commander's node before the peers (a
    ROS 2 deployment starts it first) and runs until the teardown; every peer, the
    commander's included, is a client of it through ``ROS_DISCOVERY_SERVER``.
    """

    server: subprocess.Popen[bytes] | None = None

    def _program(self) -> list[str]:
        return [str(fastdds_peer())]

    def _env(self) -> dict[str, str]:
        env = _clean_env(self.extra_env)
        if self.name == "fastdds-server":
            env["ROS_DISCOVERY_SERVER"] = f"{self.drones[0].address}:{DISCOVERY_SERVER_PORT}"
        return env

    def start(self, barrier: Path) -> None:
        if self.name == "fastdds-server":
            cli = fastdds_discovery_server()
            if cli is None:
                raise RuntimeError("fastdds CLI missing: apt-get install fastdds-tools")
            argv = [*cli, "-i", "0", "-l", self.drones[0].address]
            argv += ["-p", str(DISCOVERY_SERVER_PORT)]
            # the server is infrastructure, not a contender process: not behind the barrier
            self.server = self.drones[0].popen(
                argv,
                env=_clean_env(self.extra_env),
                stdout=self._log("discovery-server.log"),
                stderr=subprocess.STDOUT,
            )
        super().start(barrier)


class SwarmdContender(Contender):
    """Real ``swarmd run`` daemons; discovery and readiness from their control sockets."""

    def _own_state(self) -> None:
        self.variant = SWARMD_VARIANTS[self.name]
        self.socks = [self.work / f"uav{i + 1}.sock" for i in range(self.n)]
        self._nth: dict[str, float] = {}
        self._first: dict[str, float] = {}
        self._counts: dict[str, int] = {}
        self._last_full_poll = 0.0
        # appended to every daemon's config (the flight runs' px4: section for a vehicle)
        self.extra_config = ""

    def _config(self, i: int, bundle: Path, key: Path) -> Path:
        v = self.variant
        text = daemon_config(
            i, bundle, key, self.socks[i],
            aware=v.aware, link_file=self.link_file(i), mode=v.mode,
            overrides=v.overrides, state_dir=self.work / f"state-uav{i + 1}",
        ) + self.extra_config  # fmt: skip
        path = self.work / f"uav{i + 1}.yaml"
        path.write_text(text)
        return path

    def start(self, barrier: Path) -> None:
        files = write_bundle(self.work / "bundle", [d.address for d in self.drones])
        # `swarmd run` behind the testbed's fair-start hook (swarmd_lab.start_barrier)
        swarmd = [sys.executable, "-m", "swarmd_lab.start_barrier"]
        env = _clean_env(self.extra_env)
        env["SWARMD_START_BARRIER"] = str(barrier)
        for i, drone in enumerate(self.drones):
            cfg = self._config(i, files.path, files.trusted_key)
            self.procs.append(
                drone.popen(
                    _niced([*swarmd, "run", "--config", str(cfg)]),
                    env=env,
                    stdout=self._log(f"uav{i + 1}.log"),
                    stderr=subprocess.STDOUT,
                )
            )
        if not dataplane_supported():
            self.obs.success_pending = True
            self.obs.note = (
                "success pending workload: this swarmd has no dataplane config section yet"
            )

    def _status(self, i: int) -> dict[str, Any] | None:
        try:
            st: Any = request(str(self.socks[i]), "status")
        except (DaemonUnreachable, RequestError, OSError, ValueError):
            return None
        return st if isinstance(st, dict) else None

    def _readiness(self, st: Mapping[str, Any]) -> Mapping[str, Any]:
        try:  # the commander's own table (swarmctl readiness); older daemons: in status
            table: Any = request(str(self.socks[0]), "readiness")
        except (DaemonUnreachable, RequestError, OSError, ValueError):
            table = None
        if isinstance(table, Mapping):
            return table
        for holder in (st.get("dataplane"), st):
            if isinstance(holder, Mapping) and isinstance(holder.get("readiness"), Mapping):
                found: Mapping[str, Any] = holder["readiness"]
                return found
        return {}

    def poll(self, now: float) -> None:
        full = self.obs.all_discovered is None or now - self._last_full_poll >= 5.0
        indices = range(self.n) if full else range(1)
        discovered = 0
        for i in indices:
            st = self._status(i)
            if st is None:
                continue
            daemon = st.get("daemon") or {}
            if i not in self.obs.started and isinstance(daemon.get("uptime_s"), int | float):
                self.obs.started[i] = now - float(daemon["uptime_s"])
            if st.get("peers_discovered") == self.n - 1:
                discovered += 1
            if i == 0:
                self._read_commander(st, now)
        if full:
            self._last_full_poll = now
            if self.obs.all_discovered is None and discovered == self.n:
                self.obs.all_discovered = now

    def window_end(self) -> None:
        totals: dict[str, int] = {}
        for i in range(self.n):
            st = self._status(i)
            counters = st.get("counters") if st else None
            if not isinstance(counters, Mapping):
                continue
            kinds = counters.get("tx_kind")
            flat = {
                **(kinds if isinstance(kinds, Mapping) else {}),
                **{k: counters.get(k) for k in ("tx_multicast", "tx_unicast", "tx_datagrams")},
            }
            for key, value in flat.items():
                if isinstance(value, int):
                    totals[key] = totals.get(key, 0) + value
            totals["daemons_counted"] = totals.get("daemons_counted", 0) + 1
        self.obs.tx_counters = totals

    def _read_commander(self, st: Mapping[str, Any], now: float) -> None:
        for node, entry in self._readiness(st).items():
            count = entry.get("count") if isinstance(entry, Mapping) else None
            if not isinstance(count, int):
                continue
            self._counts[node] = count
            if count >= 1:
                self._first.setdefault(node, now)
            if count >= self.messages:
                self._nth.setdefault(node, now)

    def finish(self) -> Observation:
        if not self._counts and not self.obs.success_pending:
            self.obs.success_pending = True
            self.obs.note = "success pending workload: the commander reported no readiness table"
        for node, count in self._counts.items():
            index = node[3:] if node.startswith("uav") else node
            key = str(int(index) - 1) if index.isdigit() else node
            self.obs.received[key] = {
                "count": count,
                "first": self._first.get(node),
                "nth": self._nth.get(node),
            }
        return self.obs


def make(
    name: str,
    drones: list[Namespace],
    work: Path,
    *,
    window_s: float,
    messages: int,
    link_dir: Path,
    env: Mapping[str, str] | None = None,
) -> Contender:
    """The contender called ``name`` (one of ``CONTENDERS``); ``env`` added to its processes."""
    kind: type[Contender]
    if name in SWARMD_VARIANTS:
        kind = SwarmdContender
    elif name in PEER_SCRIPTS:
        kind = PeerContender
    elif name in FASTDDS:
        kind = FastddsContender
    elif name in ROS2:
        from bench.wifi.ros2_contenders import Ros2Contender  # imports this module

        kind = Ros2Contender
    else:
        raise ValueError(f"unknown contender {name!r}; use one of: {', '.join(CONTENDERS)}")
    return kind(
        name, drones, work, window_s=window_s, messages=messages, env=env, link_dir=link_dir
    )
