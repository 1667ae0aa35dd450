"""The demo's sequence: set up, start N drones, discovery, take-off, IN_AIR, report, clean up.

Every process and namespace it starts is stopped in a ``finally`` (Ctrl-C and SIGTERM
included); the per-run directory (keys, bundle, configs, logs) is removed unless ``--keep``.
Each stage has a deadline, so the demo always ends by itself.
"""

from __future__ import annotations

import os
import queue
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import IO, Any, Final, NoReturn, TextIO

from swarmd_lab.demo import report
from swarmd_lab.demo.hosts import Hosts, NamespaceHosts
from swarmd_lab.demo.observe import NodeLog, Observer, milestones, read_log
from swarmd_lab.demo.ros2 import Ros2Demo, Ros2Result
from swarmd_lab.demo.ros2 import available as ros2_available
from swarmd_lab.demo.scenario import (
    LATE_GPS_S,
    TAKEOFF_ALT_M,
    Drone,
    Scenario,
    plan,
    write,
    xrce_port,
)
from swarmd_lab.demo.view import LiveView
from swarmd_lab.netns import MAX_HOSTS, unavailable_reason

MICRO_XRCE_AGENT: Final = "MicroXRCEAgent"  # eProsima's agent: third-party, never built here
STANDIN: Final = (
    "swarmd-px4-xrce (the PX4 stand-in over uXRCE-DDS: PX4's client session, the vehicle model"
    " the MAVLink simulator flies; a SIMULATOR, not PX4)"
)

POLL_S: Final = 0.5
DISCOVERY_DEADLINE_S: Final = 60.0
TAKEOFF_TIMEOUT_S: Final = 45.0
IN_AIR_WAIT_S: Final = 20.0


@dataclass(frozen=True, slots=True)
class Options:
    n: int = 10
    out: Path = Path("demo-out")
    loopback: bool = False
    keep: bool = False
    seed: int = 1
    late_gps_s: float = LATE_GPS_S
    vehicle: str = "mavlink"  # or "xrce": the PX4 stand-in with swarmd as its XRCE agent
    ros2: bool = False  # also a real rclpy node per drone through swarmd (demo/ros2.py)


def _tool(name: str, module: str) -> list[str]:
    script = Path(sys.executable).parent / name
    return [str(script)] if script.exists() else [sys.executable, "-m", module]


def _raise_interrupt(signum: int, frame: object) -> NoReturn:
    raise KeyboardInterrupt


class Demo:
    def __init__(self, opts: Options, out: TextIO) -> None:
        self.opts = opts
        self.out = out
        self.t0 = time.monotonic()
        self.t0_epoch = time.time()
        reason = unavailable_reason()
        self.loopback = opts.loopback or reason is not None
        if opts.loopback:
            self.why_loopback: str | None = "--loopback"
        elif reason is not None:
            self.why_loopback = "not root" if os.geteuid() != 0 else reason
        else:
            self.why_loopback = None
        self.hosts: Hosts = Hosts(opts.n) if self.loopback else NamespaceHosts(opts.n)
        self.root = Path(tempfile.mkdtemp(prefix="swarmd-demo-", dir="/tmp"))
        tty = out.isatty()
        where = "on loopback" if self.loopback else "in network namespaces"
        self.view = LiveView(out, tty=tty, title=f"swarmd demo: {opts.n} drones {where}")
        self.logs: list[IO[bytes]] = []
        self.daemons: list[subprocess.Popen[bytes]] = []
        self.sims: list[subprocess.Popen[bytes]] = []
        self.ros2: Ros2Demo | None = None
        self.ros2_result: Ros2Result | None = None

    def t(self) -> float:
        return time.monotonic() - self.t0

    def say(self, line: str) -> None:
        print(line, file=self.out, flush=True)

    # ---- the sequence ---------------------------------------------------------------------

    def run(self) -> int:
        previous = signal.signal(signal.SIGTERM, _raise_interrupt)
        # Ctrl-C stops the demo even when it was started from a non-interactive shell's
        # background job, where SIGINT arrives ignored and Python keeps it ignored
        previous_int = signal.signal(signal.SIGINT, signal.default_int_handler)
        obs: Observer | None = None
        scenario: Scenario | None = None
        result: dict[str, Any] = {}
        failure: str | None = None
        try:
            scenario = self.setup()
            obs = Observer(
                [d.name for d in scenario.drones],
                [scenario.socket_path(d) for d in scenario.drones],
                self.t0,
            )
            self.start(scenario)
            self.discovery(obs)
            result = self.takeoff(scenario, obs)
            self.wait_in_air(obs, result)
            if self.ros2 is not None:
                self.view.set_stage(self.t(), "ROS 2: waiting for the rclpy nodes to finish")
                self.ros2_result = self.ros2.finish()
            obs.poll(time.monotonic())  # the last look before everything stops
            self.view.set_stage(self.t(), "stopping: SIGTERM to every daemon and simulator")
        except KeyboardInterrupt:
            self.say("\ninterrupted: stopping every drone and removing the namespaces")
            self.cleanup()
            shutil.rmtree(self.root, ignore_errors=True)
            return 130
        except (RuntimeError, OSError) as exc:  # a daemon died, a namespace could not be made
            failure = str(exc)
        finally:
            self.cleanup()
            signal.signal(signal.SIGTERM, previous)
            signal.signal(signal.SIGINT, previous_int)
        if failure is not None or scenario is None or obs is None:
            self.say(f"demo failed: {failure}; the run's files (logs/) stay in {self.root}")
            return 1
        code = self.report(scenario, obs, result)
        if not self.opts.keep:
            shutil.rmtree(self.root, ignore_errors=True)
        else:
            self.say(f"kept the run's files in {self.root}")
        return code

    def setup(self) -> Scenario:
        opts = self.opts
        if self.why_loopback is not None:
            self.say(
                f"no network namespaces ({self.why_loopback}): running every drone on "
                "loopback (127.0.0.1) with distinct ports instead"
            )
        else:
            self.say(f"{opts.n} drones, each a network namespace on one bridge")
        self.hosts.open()
        drones = self.hosts.place(plan(opts.n, seed=opts.seed))
        drones = [
            replace(d, gps_fix_after_s=opts.late_gps_s) if d.gps_fix_after_s >= LATE_GPS_S else d
            for d in drones
        ]
        # loopback: a per-process domain keeps two demos (or a test run) on one host apart
        domain = 1 + os.getpid() % 200 if self.loopback else 0
        if opts.vehicle == "xrce-client" and not self.loopback:
            domain = 1  # MicroXRCEAgent's own participants hold domain 0's ports (7410, ...)
        if opts.ros2:
            why = "needs network namespaces (root)" if self.loopback else ros2_available()
            if why is not None:
                raise RuntimeError(f"ROS2=1: {why}")
        scenario = write(
            self.root,
            drones,
            domain_id=domain,
            loopback=self.loopback,
            vehicle=opts.vehicle,
            ros2=opts.ros2,
        )
        if opts.ros2 and isinstance(self.hosts, NamespaceHosts):
            self.ros2 = Ros2Demo(scenario, self.hosts)
            self.ros2.write_profiles()
            self.say(
                "ROS 2: a real rclpy node per drone (talkers on the members, a listener and "
                "Trigger client on the commander), discovery served by each drone's swarmd on "
                "[::1] (swarmctl ros2 profile --via-swarmd, ros2.relay: true)"
            )
        if opts.vehicle == "xrce-client":
            self.say(
                f"vehicles: {STANDIN} per drone through eProsima's MicroXRCEAgent, swarmd a"
                " second client of that agent (px4.backend: xrce-client)"
            )
        elif opts.vehicle == "xrce":
            self.say(
                f"vehicles: {STANDIN} per drone, with swarmd as its XRCE agent"
                " (px4.backend: xrce-agent)"
            )
        else:
            self.say("vehicles: swarmd-vehicle-sim (a MAVLink vehicle SIMULATOR) per drone")
        self.say(
            f"set up in {self.root}: swarm signing key + {opts.n} node keys, mission, signed "
            f"bundle, per-drone configs and link files (SNR "
            f"{min(d.snr_db for d in drones):.0f}-{max(d.snr_db for d in drones):.0f} dB)"
        )
        if scenario.late is not None:
            self.say(
                f"{scenario.late} gets its GPS fix late ({opts.late_gps_s:g} s): watch the wait"
            )
        return scenario

    def start(self, s: Scenario) -> None:
        if self.ros2 is not None:  # the link from the first datagram on
            self.ros2.start_capture()
        swarmd = _tool("swarmd", "swarmd.cli.swarmd_main")
        sim = _tool("swarmd-vehicle-sim", "swarmd_lab.px4.vehicle_sim")
        if self.opts.vehicle == "xrce-client":  # each drone's agent first: swarmd connects to it
            for d in s.drones:
                log = s.log_path(d, "agent").open("wb")
                self.logs.append(log)
                self.sims.append(self.hosts.popen(d.index, self.agent_args(d), log))
        for d in s.drones:
            log = s.log_path(d).open("wb")
            self.logs.append(log)
            argv = [*swarmd, "run", "--config", str(s.config_path(d))]
            self.daemons.append(self.hosts.popen(d.index, argv, log))
        for d in s.drones:
            log = s.log_path(d, "sim").open("wb")
            self.logs.append(log)
            if self.opts.vehicle == "mavlink":
                argv = [*sim, *self.sim_args(s, d)]
            else:
                argv = self.xrce_args(d, localhost=self.opts.vehicle == "xrce-client")
            self.sims.append(self.hosts.popen(d.index, argv, log))
        self.view.event(self.t(), f"started {len(s.drones)} swarmd + {len(s.drones)} simulators")

    @staticmethod
    def xrce_args(d: Drone, *, localhost: bool = False) -> list[str]:
        """The PX4 stand-in: UXRCE_DDS_KEY and MAV_SYS_ID both the drone's system id (the
        key is what the drone's ``px4.xrce_key`` binds), PX4 1.16, the drone's GPS delay."""
        port, sysid = str(xrce_port(d)), str(d.sysid)
        argv = [*_tool("swarmd-px4-xrce", "swarmd_lab.px4.xrce_vehicle"), "-p", port,
                "-k", sysid, "-S", sysid, "-V", "1.16", "-q", "--seed", str(d.index),
                "--gps-fix-after", str(d.gps_fix_after_s)]  # fmt: skip
        # PX4's UXRCE_DDS_PTCFG=1 (a localhost-only participant); with swarmd as the agent
        # no participant exists at all, so it only matters through MicroXRCEAgent
        return [*argv, "-c", "1"] if localhost else argv

    @staticmethod
    def agent_args(d: Drone) -> list[str]:
        agent = shutil.which(MICRO_XRCE_AGENT)
        if agent is None:
            raise RuntimeError(missing_agent_line())
        return [agent, "udp4", "-p", str(xrce_port(d))]

    @staticmethod
    def sim_args(s: Scenario, d: Drone) -> list[str]:
        return [
            "--signing-key",
            str(s.px4_key_path(d)),
            "--connect",
            f"udpout:127.0.0.1:{d.mavlink_port}",
            "--sysid",
            str(d.sysid),
            "--seed",
            str(d.index),
            "--gps-fix-after",
            str(d.gps_fix_after_s),
            "--json-log",
        ]

    def tick(self, obs: Observer) -> None:
        obs.poll(time.monotonic())
        self.view.refresh(self.t(), obs)
        dead = [p for p in self.daemons if p.poll() is not None]
        if dead:
            raise RuntimeError(f"{len(dead)} swarmd process(es) exited; see the logs")

    def discovery(self, obs: Observer) -> None:
        self.view.set_stage(self.t(), "discovery: passive listening, then directed announcements")
        deadline = time.monotonic() + DISCOVERY_DEADLINE_S
        while len(obs.discovered_at) < len(obs.names) and time.monotonic() < deadline:
            self.tick(obs)
            time.sleep(POLL_S)
        self.tick(obs)
        if self.ros2 is not None:
            self.ros2.start_nodes()
            self.view.event(
                self.t(), f"started {len(obs.names)} rclpy nodes (ROS 2 through swarmd)"
            )

    def takeoff(self, s: Scenario, obs: Observer) -> dict[str, Any]:
        self.view.set_stage(self.t(), "take-off: swarmctl takeoff --require-all on the commander")
        commander = s.drones[0]
        argv = [
            *_tool("swarmctl", "swarmd.cli.swarmctl"),
            "takeoff",
            "--require-all",
            "--alt",
            str(TAKEOFF_ALT_M),
            "--timeout",
            str(TAKEOFF_TIMEOUT_S),
            "--socket",
            str(s.socket_path(commander)),
        ]
        proc = subprocess.Popen(  # noqa: S603 - argv list, no shell
            self.hosts.command(commander.index, argv),
            stdin=subprocess.DEVNULL,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
        )
        lines: queue.Queue[str] = queue.Queue()

        def pump() -> None:
            assert proc.stdout is not None  # noqa: S101 - PIPE above
            for line in proc.stdout:
                lines.put(line.rstrip())

        reader = threading.Thread(target=pump, name="swarmctl-output", daemon=True)
        reader.start()
        try:
            while proc.poll() is None or not lines.empty() or reader.is_alive():
                self.tick(obs)
                while not lines.empty():
                    self.view.event(self.t(), "swarmctl: " + lines.get())
                time.sleep(POLL_S / 2)
                if proc.poll() is not None and lines.empty():
                    reader.join(timeout=1.0)
                    if lines.empty():
                        break
        finally:
            if proc.poll() is None:
                proc.kill()
            proc.wait()
        self.view.event(self.t(), f"swarmctl takeoff exited with {proc.returncode}")
        return {"exit_code": proc.returncode}

    def wait_in_air(self, obs: Observer, result: dict[str, Any]) -> None:
        self.view.set_stage(self.t(), "climbing: waiting for every drone to report IN_AIR")
        deadline = time.monotonic() + IN_AIR_WAIT_S

        def flying() -> list[str]:
            # re-read at every poll: a row may turn "completed" after swarmctl has exited
            # (the commander's own drone's row, polled just before its completion)
            nodes = (_last_takeoff(obs) or {}).get("nodes") or {}
            return [n for n, v in nodes.items() if v["state"] == "completed"]

        while time.monotonic() < deadline and not all(n in obs.in_air_at for n in flying()):
            self.tick(obs)
            time.sleep(POLL_S)
        self.tick(obs)
        result["command"] = _last_takeoff(obs)

    def cleanup(self) -> None:
        try:
            if self.ros2 is not None:
                self.ros2.stop_capture()
            self.hosts.close()
        finally:
            for log in self.logs:
                log.close()
            self.logs.clear()

    # ---- the results ----------------------------------------------------------------------

    def report(self, s: Scenario, obs: Observer, result: dict[str, Any]) -> int:
        out_dir = self.opts.out
        out_dir.mkdir(parents=True, exist_ok=True)
        n = len(s.drones)
        logs: dict[str, NodeLog] = {
            d.name: milestones(read_log(s.log_path(d)), n - 1, self.t0_epoch) for d in s.drones
        }
        command = result.get("command") or _last_takeoff(obs) or {}
        outcome = command.get("nodes") or {}
        nodes: dict[str, dict[str, Any]] = {}
        for d in s.drones:
            log = logs[d.name]
            found = (
                None
                if log.discovered_all is None or log.started is None
                else round(log.discovered_all - log.started, 3)
            )
            o = outcome.get(d.name) or {}
            view = obs.views.get(d.name)
            nodes[d.name] = {
                "role": d.role,
                "snr_db": d.snr_db,
                "discovered_all_s": found,
                "frames_sent": None if view is None else view.frames_sent,
                "userdata_frames_sent": None if view is None else view.userdata_sent,
                "ready": bool(o) and o.get("state") != "refused",
                "airborne": o.get("state") == "completed" and d.name in obs.in_air_at,
                "command_latency_s": o.get("latency_s"),
                "takeoff_done_s": o.get("done_s"),
                "in_air_at_s": obs.in_air_at.get(d.name),
                "gps_fix_after_s": d.gps_fix_after_s,
            }
        airborne = sum(1 for v in nodes.values() if v["airborne"])
        found_times = [v["discovered_all_s"] for v in nodes.values() if v["discovered_all_s"]]
        latencies = [v["command_latency_s"] for v in nodes.values() if v["command_latency_s"]]
        duration = round(self.t(), 2)
        body = {
            "n": n,
            "mode": "loopback" if self.loopback else "namespaces",
            "duration_s": duration,
            "takeoff": {
                "command_id": command.get("command_id"),
                "altitude_m": command.get("altitude_m"),
                "swarmctl_exit_code": result.get("exit_code"),
                "airborne": airborne,
            },
            "nodes": nodes,
        }
        ros2_ok = True
        if self.ros2 is not None:
            r = self.ros2_result or Ros2Result(None, n - 1, None)
            body["ros2"] = r.as_json()
            ros2_ok = r.ok
        report.write_json(out_dir / "summary.json", body)
        png = out_dir / "timeline.png"
        try:
            report.write_timeline(
                png,
                [d.name for d in s.drones],
                logs,
                obs.in_air_at,
                duration,
                f"swarmd demo, {n} drones ({body['mode']}): discovery phases, readiness, take-off",
            )
        except ImportError:  # matplotlib comes with the dev extra (make demo installs it)
            self.say("timeline skipped: matplotlib is not installed (pip install -e '.[dev]')")
        self.say("")
        self.say("\n".join(report.summary_rows(nodes)))
        self.say("")
        self.say(
            f"{airborne}/{n} airborne; discovery done in "
            + (f"{max(found_times):.2f} s (slowest drone)" if found_times else "-")
            + "; take-off latency "
            + (
                f"median {sorted(latencies)[len(latencies) // 2] * 1000:.1f} ms, "
                f"max {max(latencies) * 1000:.1f} ms"
                if latencies
                else "-"
            )
            + f"; total {duration:.1f} s"
        )
        if self.ros2 is not None:
            r = self.ros2_result or Ros2Result(None, n - 1, None)
            for line in r.lines():
                self.say(line)
        self.say(f"wrote {out_dir / 'summary.json'} and {png}")
        return 0 if airborne == n and ros2_ok else 1


def _last_takeoff(obs: Observer) -> dict[str, Any] | None:
    takeoffs = [c for c in obs.commands if c.get("kind") == "takeoff"]
    return takeoffs[-1] if takeoffs else None


def missing_agent_line() -> str:
    return (
        f"swarmd_lab.demo: --vehicle xrce-client needs eProsima's {MICRO_XRCE_AGENT} on PATH"
        " (none found; it is third-party and never built here): install it, or use"
        " --vehicle xrce (swarmd as the agent, no MicroXRCEAgent)"
    )


def run(opts: Options, out: TextIO = sys.stdout) -> int:
    """Run the demo; the exit code (0: every drone airborne)."""
    if not 2 <= opts.n <= MAX_HOSTS:
        print(f"swarmd_lab.demo: --n {opts.n}: use 2..{MAX_HOSTS} drones", file=sys.stderr)
        return 2
    if opts.vehicle == "xrce-client" and shutil.which(MICRO_XRCE_AGENT) is None:
        print(missing_agent_line(), file=sys.stderr)
        return 69  # EX_UNAVAILABLE: a service the demo needs is missing
    return Demo(opts, out).run()
