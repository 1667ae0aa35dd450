"""Helpers for the daemon tests: a dev bundle on disk, a config pointing at it."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest
import structlog
from swarmd_lab.netns import Lan, Namespace

from swarmd.bundle.build import build_dev_bundle
from swarmd.bundle.keys import dev_signing_key, public_pem, raw_public
from swarmd.bundle.mission import parse_mission
from swarmd.bundle.model import Bundle
from swarmd.cli.swarmctl import main as swarmctl
from swarmd.config import DaemonConfig, load_config
from swarmd.control import DaemonUnreachable, request
from swarmd.daemon import Daemon
from swarmd.link.static import StaticSource
from swarmd.sdnotify import Notifier

BIN = Path(sys.executable).parent  # the venv's console scripts (swarmd, swarmd-vehicle-sim)
SWARMD = str(BIN / "swarmd")
REPO = Path(__file__).resolve().parent.parent
SWARM3 = REPO / "firmware_bundle" / "missions" / "swarm3.yaml"  # the 3-node dev mission


NOBODY = 65534  # the local user the attack tests act as (root runs them)
SYSTEM_PYTHON = shutil.which("python3", path="/usr/bin:/bin") or sys.executable


def as_nobody(script: str, *args: str) -> None:
    """Run a Python ``script`` as user nobody (no groups): another local user's act."""
    subprocess.run(
        [SYSTEM_PYTHON, "-c", script, *args],
        user=NOBODY,
        group=NOBODY,
        extra_groups=[],
        timeout=60,
        check=True,
    )


def bundle_cli(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    """``swarmctl bundle *argv`` in this process: (exit code, stdout, stderr)."""
    code = swarmctl(["bundle", *argv])
    out = capsys.readouterr()
    return code, out.out, out.err


def run_domain() -> int:
    """A domain id unlikely to collide with a parallel test run on the same host."""
    return 100 + os.getpid() % 100


@dataclass(frozen=True)
class BundleFiles:
    bundle: Bundle
    path: Path
    trusted_key: Path


def write_bundle(
    directory: Path,
    n: int,
    *,
    domain_id: int,
    lease_s: float = 20.0,
    t_min_s: float = 0.2,
    t_max_s: float = 0.5,
    ipv4: list[str] | None = None,
    swarm: str = "testswarm",
) -> BundleFiles:
    """A dev-signed bundle of ``n`` members uav1..uavN (uav1 commands) and its trust key.

    Its topics are the data plane's three (docs/dataplane.md): a commander-member pair
    matches three endpoint pairs (ready, command, outcome)."""
    parts = []
    for i in range(n):
        role = "commander" if i == 0 else "member"
        addr = f"\n    ipv4: {ipv4[i]}" if ipv4 else ""
        parts.append(
            f"  - name: uav{i + 1}\n    index: {i}\n    role: {role}\n"
            f"    mavlink_sysid: {i + 1}{addr}"
        )
    mission = f"""\
swarm: {swarm}
domain_id: {domain_id}
discovery:
  t_min_s: {t_min_s}
  t_max_s: {t_max_s}
  lease_s: {lease_s}
participants:
{chr(10).join(parts)}
topics:
  - name: swarm/ready
    type: swarmd::Readiness
    reliability: best_effort
    history_depth: 1
    writers: [member]
    readers: [commander]
  - name: swarm/command
    type: swarmd::Command
    reliability: reliable
    history_depth: 8
    writers: [commander]
    readers: [member]
  - name: swarm/outcome
    type: swarmd::CommandOutcome
    reliability: reliable
    history_depth: 16
    writers: [member]
    readers: [commander]
"""
    return write_mission_bundle(directory, mission, swarm, "test-mission.yaml")


def write_mission_bundle(directory: Path, mission: str, swarm: str, name: str) -> BundleFiles:
    """Build and dev-sign ``mission`` (the text of a mission whose swarm is ``swarm``; ``name``
    its file name in errors) and write the bundle and its trust key under ``directory``."""
    built = build_dev_bundle(parse_mission(mission, name))
    directory.mkdir(parents=True, exist_ok=True)
    path = directory / "bundle.swb"
    path.write_bytes(built.data)
    key = directory / "swarm.pub"
    key.write_bytes(public_pem(raw_public(dev_signing_key(swarm))))
    return BundleFiles(built.bundle, path, key)


def ros2_profiles(files: BundleFiles, out: Path, *options: str) -> int:
    """``swarmctl ros2 profile`` for the dev-signed bundle ``files`` into ``out`` (``options``:
    e.g. ``--via-swarmd``); its exit code."""
    argv = ["ros2", "profile", str(files.path), "--trusted-key", str(files.trusted_key)]
    return swarmctl([*argv, "--allow-dev", "--out", str(out), *options])


def relay_config(lease_s: int | None = None) -> str:
    """The ``ros2:`` section of a daemon on the relay route (docs/ros2.md); ``lease_s``: the
    relay's lease, None: its default."""
    return "ros2:\n  relay: true\n" + ("" if lease_s is None else f"  lease_s: {lease_s}\n")


def matched_counts(log: Path) -> list[int]:
    """A ROS 2 subscriber's matched publisher counts, in order (``ros2_node --matched-log``)."""
    if not log.exists():
        return []
    return [json.loads(line)["matched"] for line in log.read_text().splitlines() if line]


def swarm_sections(state_dir: Path, px4: str | None, *, period_s: float = 1.0) -> str:
    """``dataplane:`` (state in ``state_dir``) and ``px4:`` (``px4`` = connection, None: off)."""
    text = (
        f"dataplane:\n  enabled: true\n  readiness_period_s: {period_s}\n  state_dir: {state_dir}\n"
    )
    if px4 is None:
        return text + "px4:\n  enabled: false\n"
    return text + f"px4:\n  enabled: true\n  connection: {px4}\n  takeoff_alt_m: 5\n"


def write_config(
    path: Path,
    files: BundleFiles,
    *,
    node: str,
    interface: str,
    socket_path: str,
    ipv4: str | None = None,
    link_file: Path | None = None,
    static_q: float = 0.8,
    poll_s: float = 0.2,
    level: str = "info",
    extra: str = "",
) -> Path:
    """A daemon config; ``extra`` is appended as is (e.g. ``px4:``/``dataplane:`` sections)."""
    sources = "[nl80211, file, static]" if link_file else "[nl80211, static]"
    text = f"""\
node: {node}
bundle:
  path: {files.path}
  trusted_key: {files.trusted_key}
  allow_dev: true
network:
  interface: {interface}
  ipv4: {ipv4 if ipv4 else "null"}
control:
  socket: {socket_path}
link:
  sources: {sources}
  poll_interval_s: {poll_s}
  file: {link_file if link_file else "/nonexistent"}
  static_q: {static_q}
logging:
  level: {level}
  format: json
{extra}"""
    path.write_text(text)
    return path


def loopback_config(
    workdir: Path, files: BundleFiles, node: str = "uav1", *, extra: str = ""
) -> Path:
    """A daemon config for ``node`` on loopback, its control socket ``workdir/ctl.sock``;
    ``extra`` as in ``write_config``."""
    return write_config(
        workdir / "swarmd.yaml",
        files,
        node=node,
        interface="lo",
        ipv4="127.0.0.1",
        socket_path=str(workdir / "ctl.sock"),
        extra=extra,
    )


def in_process_daemon(config: DaemonConfig, bundle: Bundle, node: str | None = None) -> Daemon:
    """A daemon in this process, not started: logs through structlog (bound to ``node``),
    no systemd (no notify socket; an empty environment, so no socket unit either: it binds
    its ports itself) and a static link quality of 0.8."""
    return Daemon(
        config,
        bundle,
        log=structlog.get_logger() if node is None else structlog.get_logger(node=node),
        notifier=Notifier({}),
        sources=[StaticSource(0.8)],
        env={},
    )


def loopback_daemon(workdir: Path, files: BundleFiles, node: str, *, extra: str = "") -> Daemon:
    """``node``'s daemon on the host loopback, in this process, not started: its config
    ``workdir/<node>.yaml``, its control socket ``workdir/<node>.sock``; ``extra`` as in
    ``write_config``."""
    cfg = write_config(
        workdir / f"{node}.yaml",
        files,
        node=node,
        interface="lo",
        ipv4="127.0.0.1",
        socket_path=str(workdir / f"{node}.sock"),
        extra=extra,
    )
    return in_process_daemon(load_config(cfg), files.bundle, node)


def clean_env(**extra: str) -> dict[str, str]:
    """This process's environment without what would make a child daemon talk to systemd
    or wait on a testbed start barrier, plus ``extra``."""
    drop = ("NOTIFY_SOCKET", "JOURNAL_STREAM", "SWARMD_START_BARRIER")
    env = {k: v for k, v in os.environ.items() if k not in drop}
    env.update(extra)
    return env


def run_swarmd(*args: str, timeout_s: float = 20.0) -> subprocess.CompletedProcess[str]:
    """``swarmd *args`` as a process (``clean_env``), to its end: text out and err, its code."""
    return subprocess.run(
        [SWARMD, *args],
        capture_output=True,
        text=True,
        timeout=timeout_s,
        env=clean_env(),
        check=False,
    )


def until(
    cond: Callable[[], bool],
    what: Callable[[], object],
    wait_s: float,
    *,
    not_yet: tuple[type[Exception], ...] = (DaemonUnreachable,),
) -> None:
    """Poll ``cond`` every 0.1 s for up to ``wait_s`` (one of ``not_yet`` raised, by default a
    daemon not answering yet, counts as not yet); AssertionError with ``what()`` when it never
    holds."""
    deadline = time.monotonic() + wait_s
    while True:
        try:
            if cond():
                return
        except not_yet:
            pass
        if time.monotonic() > deadline:
            raise AssertionError(f"gave up waiting: {what()}")
        time.sleep(0.1)


def daemon_status(sock: Path) -> dict[str, Any]:
    """``swarmctl status --json``'s document, straight from the control socket."""
    result: dict[str, Any] = request(str(sock), "status")
    return result


@dataclass
class Daemons:
    """One ``swarmd run`` per host: ``names[i]`` on ``hosts[i]``, its config, control socket
    and log (appended to across restarts) under ``workdir``. ``command``: how swarmd is run
    (the console script; a bench runs the module so that ``PYTHONPATH`` picks the checkout)."""

    hosts: Lan | Sequence[Namespace]
    workdir: Path
    files: BundleFiles
    names: Sequence[str]
    extra: str = ""  # appended to every config (``write_config``)
    command: Sequence[str] = (str(BIN / "swarmd"),)
    env: Mapping[str, str] | None = None
    procs: list[subprocess.Popen[bytes]] = field(default_factory=list)

    @property
    def socks(self) -> list[Path]:
        return [self.workdir / f"{name}.sock" for name in self.names]

    @property
    def logs(self) -> list[Path]:
        return [self.workdir / f"{name}.log" for name in self.names]

    def start(self, i: int) -> subprocess.Popen[bytes]:
        """Write drone ``i``'s config and start (or restart) its daemon."""
        config = write_config(
            self.workdir / f"{self.names[i]}.yaml",
            self.files,
            node=self.names[i],
            interface=self.hosts[i].ifname,
            socket_path=str(self.socks[i]),
            extra=self.extra,
        )
        with self.logs[i].open("ab") as err:
            proc = self.hosts[i].popen(
                [*self.command, "run", "--config", str(config)], env=self.env, stderr=err
            )
        if i < len(self.procs):
            self.procs[i] = proc
        else:
            self.procs.append(proc)
        return proc

    def start_all(self, wait_s: float) -> list[subprocess.Popen[bytes]]:
        """Start every daemon and wait (up to ``wait_s``) until each has discovered all others."""
        for i in range(len(self.names)):
            self.start(i)
        until(
            self.all_discovered,
            lambda: str([daemon_status(s)["peers"] for s in self.socks if s.exists()]),
            wait_s,
        )
        return self.procs

    def all_discovered(self) -> bool:
        others = len(self.names) - 1
        return all(
            sum(p["state"] == "discovered" for p in daemon_status(s)["peers"]) == others
            for s in self.socks
        )


def start_vehicle_sim(
    host: Namespace, sysid: int, log: Path, *extra: str
) -> subprocess.Popen[bytes]:
    """A MAVLink vehicle simulator (not PX4) for drone ``sysid`` (1-based; its seed
    ``sysid - 1``) on ``host``'s loopback, where the daemon's ``px4:`` section listens
    (``swarm_sections(..., "udpin:127.0.0.1:14540")``); JSON events to ``log``."""
    with log.open("wb") as err:
        return host.popen(
            [
                str(BIN / "swarmd-vehicle-sim"),
                "--connect",
                "udpout:127.0.0.1:14540",
                "--sysid",
                str(sysid),
                "--seed",
                str(sysid - 1),
                "--gps-fix-after",
                "0.5",
                "--json-log",
                *extra,
            ],
            stderr=err,
        )
