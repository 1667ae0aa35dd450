"""A flight-like swarm in network namespaces, for the attack tests and ``bench/flood.py``.

What issue 10 asks of the victim: three real ``swarmd`` daemons, each in its own namespace
on one LAN, with a real signed bundle made by ``swarmctl bundle keygen``/``build`` and put
on every drone by ``swarmctl bundle flash`` (never the dev helper), the shipped
``config/swarmd.yaml`` with only the per-host values changed (node name, interface, the
state and run directories), and per drone a ``swarmd-vehicle-sim`` (a MAVLink vehicle
SIMULATOR, not PX4) on the namespace's loopback, where PX4 SITL would be. The mission is
``firmware_bundle/missions/swarm3.yaml`` with faster discovery timings (so a test waits
seconds, not minutes) and the LAN's addresses.

The LAN's bridge does not learn MAC addresses, so it floods every frame to every port as a
radio channel does: the attacker host (the LAN's last namespace) hears the unicast traffic
too, as anyone on the swarm's Wi-Fi would.
"""

from __future__ import annotations

import contextlib
import json
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, Final

import yaml
from swarmd_lab.netns import Lan, Namespace

from swarmd.bundle.loader import read_bundle
from swarmd.bundle.model import Bundle, EndpointKind, Participant
from swarmd.control import DaemonUnreachable, RequestError, request
from swarmd.rtps.ports import spdp_multicast_port
from swarmd.rtps.types import EntityId
from tests.attacker.forge import entity

REPO: Final = Path(__file__).resolve().parents[2]
SHIPPED_CONFIG: Final = REPO / "config" / "swarmd.yaml"
MISSION: Final = REPO / "firmware_bundle" / "missions" / "swarm3.yaml"
# where the shipped config listens for PX4 (127.0.0.1:540, swarmd-px4.socket's port): the
# vehicle simulator sends there, as PX4 or mavlink-router would (docs/px4.md)
PX4_LISTEN: Final = str(yaml.safe_load(SHIPPED_CONFIG.read_text())["px4"]["connection"])
BIN: Final = Path(sys.executable).parent
SPDP_GROUP: Final = "239.255.0.1"
# Faster than the field mission's 8/20/20 s so a test converges in seconds; the lease stays
# long enough that a loaded CI box does not lose peers without an attacker.
DISCOVERY: Final = {"t_min_s": 0.5, "t_max_s": 1.5, "lease_s": 6.0}
WAIT_S: Final = 60.0
STOP_S: Final = 10.0


def _state_root_paths(value: Any, lib: Path, run: Path) -> Any:
    """Every shipped path under /var/lib/swarmd or /run/swarmd, moved to this drone's dirs."""
    if isinstance(value, dict):
        return {k: _state_root_paths(v, lib, run) for k, v in value.items()}
    if isinstance(value, str):
        if value.startswith("/var/lib/swarmd"):
            return str(lib) + value[len("/var/lib/swarmd") :]
        if value.startswith("/run/swarmd"):
            return str(run) + value[len("/run/swarmd") :]
    return value


def until(cond: Callable[[], bool], what: Callable[[], object], timeout_s: float = WAIT_S) -> None:
    """Wait for ``cond`` (errors from a daemon not up yet count as false), or fail."""
    deadline = time.monotonic() + timeout_s
    while True:
        with contextlib.suppress(DaemonUnreachable, RequestError, KeyError, TypeError):
            if cond():
                return
        if time.monotonic() > deadline:
            raise AssertionError(f"gave up waiting after {timeout_s:.0f} s: {what()}")
        time.sleep(0.2)


class FlashedSwarm:
    """Drones 0..n-1 on ``lan[0..n-1]`` (drone 0 commands); see the module docstring."""

    def __init__(self, lan: Lan, root: Path, n: int = 3) -> None:
        self.lan = lan
        self.root = root
        self.n = n
        for i in range(len(lan)):
            # a radio channel, not a switch: every frame reaches every host (module docstring)
            subprocess.run(  # noqa: S603 - fixed argv
                [
                    "ip",
                    "-n",
                    lan.hub,
                    "link",
                    "set",
                    f"v{i}",
                    "type",
                    "bridge_slave",
                    "learning",
                    "off",
                ],  # noqa: S607, E501
                check=True,
                capture_output=True,
                timeout=10,
            )
        self._flush_fdb()
        self.bundle = self._provision()
        self.names = [p.name for p in self.bundle.participants][:n]
        self.daemons: list[subprocess.Popen[bytes] | None] = [None] * n
        self.sims: list[subprocess.Popen[bytes] | None] = [None] * n
        self.configs = [self._config(i) for i in range(n)]

    def _flush_fdb(self) -> None:
        """Forget the addresses the bridge learned before learning was turned off."""
        hub = ["bridge", "-n", self.lan.hub]
        shown = subprocess.run(  # noqa: S603 - fixed argv
            [*hub, "fdb", "show"], capture_output=True, text=True, check=True, timeout=10
        ).stdout
        for line in shown.splitlines():
            words = line.split()
            if len(words) >= 3 and "master" in words and "permanent" not in words:
                subprocess.run(  # noqa: S603 - fixed argv
                    [*hub, "fdb", "del", words[0], "dev", words[2], "master"],
                    capture_output=True,
                    timeout=10,
                    check=False,
                )

    # -- provisioning ----------------------------------------------------------------------

    def swarmctl_local(self, *args: str) -> str:
        proc = subprocess.run(  # noqa: S603 - our own console script
            [str(BIN / "swarmctl"), *args], capture_output=True, text=True, timeout=60, check=False
        )
        if proc.returncode != 0:
            raise RuntimeError(f"swarmctl {' '.join(args)}: {proc.stdout}{proc.stderr}")
        return proc.stdout

    def _provision(self) -> Bundle:
        mission = yaml.safe_load(MISSION.read_text())
        mission["discovery"] = dict(DISCOVERY)
        for i, p in enumerate(mission["participants"]):
            p["ipv4"] = self.lan[i].address
        mission_path = self.root / "mission.yaml"
        mission_path.write_text(yaml.safe_dump(mission, sort_keys=False))
        keys = self.root / "keys"
        self.swarmctl_local("bundle", "keygen", "--out", str(keys), "--mission", str(mission_path))
        swb = self.root / "mission.swb"
        self.swarmctl_local(
            *("bundle", "build", str(mission_path), "-o", str(swb)),
            *("--sign-key", str(keys / "swarm-signing.key")),
        )
        bundle = read_bundle(swb.read_bytes(), require_anchor=False)
        for p in bundle.participants:
            self.swarmctl_local(
                "bundle", "flash", str(swb), "--node", p.name,
                "--target", str(self.lib(p.index)), "--keys", str(keys),
            )  # fmt: skip
        for p in bundle.participants:
            # the drone's MAVLink signing key, as PX4's key file: what 'swarmctl px4 key'
            # gives the autopilot at commissioning (docs/px4.md "Message signing")
            self.swarmctl_local(
                *("px4", "key", "--keys", str(keys), "--swarm", bundle.swarm),
                *("--node", p.name, "--out", str(self.px4_key(p.index))),
            )
        return bundle

    def px4_key(self, i: int) -> Path:
        """Drone i's autopilot signing key file (on PX4's SD card in the field)."""
        return self.root / f"d{i}" / "px4-signing-key.bin"

    def lib(self, i: int) -> Path:
        """Drone i's /var/lib/swarmd: the flashed bundle, its key, its state file."""
        return self.root / f"d{i}" / "lib"

    def run_dir(self, i: int) -> Path:
        return self.root / f"d{i}" / "run"

    def _config(self, i: int) -> Path:
        cfg = yaml.safe_load(SHIPPED_CONFIG.read_text())
        cfg = _state_root_paths(cfg, self.lib(i), self.run_dir(i))
        cfg["node"] = self.names[i]
        cfg["network"]["interface"] = self.lan[i].ifname
        cfg["logging"]["format"] = "json"  # the test reads the log lines
        self.run_dir(i).mkdir(parents=True, exist_ok=True)
        path = self.root / f"d{i}" / "swarmd.yaml"
        path.write_text(yaml.safe_dump(cfg, sort_keys=False))
        return path

    # -- processes -------------------------------------------------------------------------

    def log(self, i: int) -> Path:
        return self.root / f"d{i}" / "swarmd.log"

    def sim_log(self, i: int) -> Path:
        return self.root / f"d{i}" / "vehicle-sim.log"

    def start(self, i: int) -> None:
        host = self.lan[i]
        with self.log(i).open("ab") as err:
            self.daemons[i] = host.popen(
                [str(BIN / "swarmd"), "run", "--config", str(self.configs[i])], stderr=err
            )
        self.start_sim(i)

    def start_sim(self, i: int) -> None:
        sysid = self.bundle.participants[i].mavlink_sysid
        with self.sim_log(i).open("ab") as err:
            self.sims[i] = self.lan[i].popen(
                [
                    str(BIN / "swarmd-vehicle-sim"),
                    *("--connect", PX4_LISTEN.replace("udpin:", "udpout:"), "--sysid", str(sysid)),
                    *("--seed", str(i), "--gps-fix-after", "0.5", "--json-log"),
                    *("--signing-key", str(self.px4_key(i))),
                ],
                stderr=err,
            )

    def stop(self, i: int, *, sim: bool = True) -> None:
        procs = [self.daemons[i], *([self.sims[i]] if sim else [])]
        for proc in procs:
            if proc is not None and proc.poll() is None:
                proc.send_signal(signal.SIGTERM)
        for proc in procs:
            if proc is None:
                continue
            try:
                proc.wait(timeout=STOP_S)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(timeout=STOP_S)
        self.daemons[i] = None
        if sim:
            self.sims[i] = None

    def wipe_state(self, i: int) -> None:
        """Lose drone i's state file (boot counter, executed ids): a fresh SD card."""
        for path in self.lib(i).glob("dataplane-*"):
            path.unlink()

    def start_all(self) -> None:
        for i in range(self.n):
            self.start(i)

    def stop_all(self) -> None:
        for i in range(self.n):
            self.stop(i)

    def reset(self) -> None:
        """Everything restarted from the flashed files with no state: a clean swarm."""
        self.stop_all()
        for i in range(self.n):
            self.wipe_state(i)
            shutil.rmtree(self.run_dir(i), ignore_errors=True)
            self.run_dir(i).mkdir(parents=True)
        self.start_all()
        self.wait_ready()

    # -- observation -----------------------------------------------------------------------

    def sock(self, i: int) -> str:
        return str(self.run_dir(i) / "swarmd.sock")

    def status(self, i: int = 0) -> dict[str, Any]:
        result: dict[str, Any] = request(self.sock(i), "status")
        return result

    def swarmctl(
        self, i: int, *args: str, timeout: float = 90.0
    ) -> subprocess.CompletedProcess[str]:
        """``swarmctl ARGS --socket <drone i's>`` inside drone i's namespace."""
        return self.lan[i].run(
            [str(BIN / "swarmctl"), *args, "--socket", self.sock(i)], timeout=timeout, check=False
        )

    def peer_states(self, i: int) -> dict[str, str]:
        return {p["name"]: p["state"] for p in self.status(i)["peers"]}

    def converged(self) -> bool:
        for i in range(self.n):
            states = self.peer_states(i)
            if sum(s == "discovered" for s in states.values()) != self.n - 1:
                return False
        table = self.status(0)["readiness"]
        return len(table) == self.n and all(
            r["ready"] and (r["local"] or r["count"] >= 2) for r in table.values()
        )

    def wait_ready(self) -> None:
        until(self.converged, lambda: self._picture())

    def _picture(self) -> str:
        out = []
        for i in range(self.n):
            try:
                st = self.status(i)
                out.append(f"{self.names[i]}: {self.peer_states(i)} {st.get('readiness')}")
            except (DaemonUnreachable, RequestError) as exc:
                out.append(f"{self.names[i]}: {exc}")
        return "; ".join(out)

    def sim_events(self, i: int, event: str) -> list[dict[str, Any]]:
        lines = self.sim_log(i).read_text().splitlines()
        parsed = [json.loads(x) for x in lines if x.startswith("{")]
        return [e for e in parsed if e.get("event") == event]

    def log_events(self, i: int, event: str) -> list[dict[str, Any]]:
        lines = self.log(i).read_text(errors="replace").splitlines()
        parsed = []
        for line in lines:
            with contextlib.suppress(json.JSONDecodeError):
                if line.startswith("{"):
                    parsed.append(json.loads(line))
        return [e for e in parsed if e.get("event") == event]

    def commands_all(self, kind: str = "hold", timeout_s: float = 30.0) -> dict[str, Any]:
        """The real commander sends ``kind`` to every drone (``swarmctl KIND --json``)."""
        proc = self.swarmctl(0, kind, "--timeout", str(timeout_s), "--json", timeout=timeout_s + 30)
        try:
            body: dict[str, Any] = json.loads(proc.stdout)
        except json.JSONDecodeError:
            body = {"stdout": proc.stdout}
        body["rc"] = proc.returncode
        body["stderr"] = proc.stderr
        return body

    # -- identities (public: on the air, and a function of the mission's topic order) -------

    def participant(self, i: int) -> Participant:
        return self.bundle.participants[i]

    def endpoint(self, topic: str, kind: EndpointKind) -> EntityId:
        return entity(self.bundle.topic(topic).index, kind)

    def user_addr(self, i: int) -> tuple[str, int]:
        return (self.lan[i].address, self.bundle.user_port(self.participant(i)))

    def meta_addr(self, i: int) -> tuple[str, int]:
        return (self.lan[i].address, self.bundle.metatraffic_port(self.participant(i)))

    @property
    def spdp_group(self) -> tuple[str, int]:
        return (SPDP_GROUP, spdp_multicast_port(self.bundle.domain_id))

    @property
    def attacker_ns(self) -> Namespace:
        return self.lan[self.n]

    def pids(self) -> list[int]:
        return [p.pid for p in self.daemons if p is not None]

    def daemon_pid(self, i: int) -> int:
        """The daemon's own pid (``ip netns exec`` execs it, so the Popen pid is it)."""
        pid: int = self.status(i)["daemon"]["pid"]
        return pid


def cpu_seconds(pid: int) -> float:
    """utime + stime of ``pid`` from /proc (clock ticks -> seconds)."""
    import os

    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    ticks = int(fields[11]) + int(fields[12])
    return ticks / os.sysconf("SC_CLK_TCK")


def counters(status: dict[str, Any]) -> dict[str, int]:
    """Every integer counter of a status snapshot under a dotted path."""
    out: dict[str, int] = {}

    def walk(prefix: str, value: Any) -> None:
        if isinstance(value, dict):
            for k, v in value.items():
                walk(f"{prefix}.{k}" if prefix else str(k), v)
        elif isinstance(value, int) and not isinstance(value, bool):
            out[prefix] = value

    for key in ("counters", "dataplane", "px4", "executor"):
        walk(key, status.get(key))
    return out


REFUSAL_WORDS: Final = ("dropped", "refused", "rejected_", "forged", "unauth", "stale_counter")


def refusals(status: dict[str, Any]) -> dict[str, int]:
    """The counters that say "a datagram was refused" (drops by reason, auth failures)."""
    return {
        k: v
        for k, v in counters(status).items()
        if any(w in k.lower() for w in REFUSAL_WORDS)
        and "outcome_" not in k
        and not k.endswith(".own")  # a daemon hearing its own multicast: not a refusal
    }


def delta(after: dict[str, int], before: dict[str, int]) -> dict[str, int]:
    return {k: v - before.get(k, 0) for k, v in after.items() if v != before.get(k, 0)}


@contextlib.contextmanager
def flashed_swarm(
    lan: Lan,
    root: Path,
    n: int = 3,
    *,
    before_start: Callable[[FlashedSwarm], None] | None = None,
) -> Iterator[FlashedSwarm]:
    """``before_start`` runs once the bundle is flashed and before any daemon starts: an
    attacker that must hear every member's SPDP listens from here (vouched members stop
    renewing once the commander vouches for them, docs/discovery.md, so an attacker that
    starts listening later hears only the commander)."""
    swarm = FlashedSwarm(lan, root, n)
    try:
        if before_start is not None:
            before_start(swarm)
        swarm.start_all()
        swarm.wait_ready()
        yield swarm
    finally:
        swarm.stop_all()
