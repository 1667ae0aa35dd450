"""Everything one demo run needs on disk: keys, mission, signed bundle, link files, configs.

The run goes through the operator's real pre-flight path (``docs/preflight.md``): a fresh
swarm signing key and one announcement key per drone (``generate_keys``, what ``swarmctl
bundle keygen`` does), a mission for N drones, a bundle signed with that key
(``build_from_files``, what ``swarmctl bundle build`` does), and per drone a daemon config
that trusts only that key. Nothing is a dev bundle.

Link quality differs per drone (SNR spread over the paper's 25-40 dB range, eq. 2), so the
passive timers differ too (paper section 4.1). One member gets its GPS fix late, so the
commander visibly waits for it before the take-off (``--require-all``).
"""

from __future__ import annotations

import json
import random
from dataclasses import dataclass, field
from pathlib import Path
from typing import Final

from swarmd.bundle.build import build_from_files
from swarmd.bundle.keys import (
    PRIVATE_MODE,
    SIGNING_KEY_FILE,
    SIGNING_PUB_FILE,
    generate_keys,
    node_key_path,
    write_file_atomic,
)
from swarmd.bundle.mission import parse_mission
from swarmd.px4.provision import node_secret
from swarmd.px4.signing import derive_key, px4_key_file

COMMANDER: Final = "lead"
T_MIN_S: Final = 2.0  # a shorter passive window than the paper's 8-20 s keeps the demo short
T_MAX_S: Final = 6.0
LEASE_S: Final = 10.0
SNR_RANGE_DB: Final = (26.0, 40.0)  # paper eq. 2: Q = (SNR - 25) / 15
GPS_FIX_S: Final = (1.5, 4.0)
LATE_GPS_S: Final = 14.0  # the late member: after discovery, so the wait is visible
TAKEOFF_ALT_M: Final = 5.0
PX4_PORT: Final = 14540  # PX4 SITL's onboard link (instance i: 14540 + i)
XRCE_PORT: Final = 8888  # PX4 SITL's uXRCE-DDS agent port (loopback: 8888 + i)
VEHICLES: Final = ("mavlink", "xrce", "xrce-client")


@dataclass(frozen=True, slots=True)
class Drone:
    """One drone of the run and how its host and simulator are set up."""

    index: int
    name: str
    role: str
    snr_db: float
    gps_fix_after_s: float
    address: str = "127.0.0.1"  # set by the host placement
    interface: str = "lo"
    mavlink_port: int = PX4_PORT

    @property
    def sysid(self) -> int:
        return self.index % 254 + 1


@dataclass(slots=True)
class Scenario:
    """The files of one run under ``root``."""

    root: Path
    drones: list[Drone]
    domain_id: int
    late: str | None
    bundle_path: Path = field(init=False)
    trusted_key: Path = field(init=False)

    def __post_init__(self) -> None:
        self.bundle_path = self.root / "bundle.swb"
        self.trusted_key = self.root / "keys" / SIGNING_PUB_FILE

    def config_path(self, d: Drone) -> Path:
        return self.root / "nodes" / f"{d.name}.yaml"

    def socket_path(self, d: Drone) -> Path:
        return self.root / "run" / f"{d.name}.sock"

    def px4_key_path(self, d: Drone) -> Path:
        """The drone's MAVLink signing key in PX4's format: swarmd and its simulator share it."""
        return self.root / "keys" / "px4" / f"{d.name}.key"

    def link_path(self, d: Drone) -> Path:
        return self.root / "link" / f"{d.name}.json"

    def log_path(self, d: Drone, what: str = "swarmd") -> Path:
        return self.root / "logs" / f"{d.name}.{what}.log"


def plan(n: int, *, seed: int = 1) -> list[Drone]:
    """N drones: the commander first, members ``drone-01``...; varied SNR and GPS fix time."""
    if n < 2:
        raise ValueError(f"--n {n}: a swarm needs a commander and at least one member; fix: 2+")
    rng = random.Random(seed)  # noqa: S311 - reproducible scenario, not cryptography
    low, high = SNR_RANGE_DB
    drones = []
    for i in range(n):
        name = COMMANDER if i == 0 else f"drone-{i:02d}"
        snr = low + (high - low) * (i / max(1, n - 1))  # evenly spread, then shuffled
        drones.append(
            Drone(
                index=i,
                name=name,
                role="commander" if i == 0 else "member",
                snr_db=round(snr, 1),
                gps_fix_after_s=round(rng.uniform(*GPS_FIX_S), 1),
            )
        )
    snrs = [d.snr_db for d in drones]
    rng.shuffle(snrs)
    late = n // 2 if n > 2 else 1
    return [
        Drone(
            d.index,
            d.name,
            d.role,
            snrs[d.index],
            LATE_GPS_S if d.index == late else d.gps_fix_after_s,
        )
        for d in drones
    ]


# ``make demo ROS2=1``: the paper's workload as stock rclpy nodes (docs/ros2.md): every member
# publishes /chatter and serves /trigger, the commander listens and calls it
ROS2_GRAPH: Final = """\
ros2:
  topics:
    - {name: /chatter, type: std_msgs/msg/String, reliability: reliable, history_depth: 10}
  services:
    - {name: /trigger, type: std_srvs/srv/Trigger}
  nodes:
    - {name: talker, drones: member, publishes: [/chatter], serves: [/trigger]}
    - {name: listener, drones: commander, subscribes: [/chatter], calls: [/trigger]}
"""


def mission_text(
    drones: list[Drone], domain_id: int, swarm: str, *, loopback: bool, ros2: bool = False
) -> str:
    lines = [
        f"# generated by swarmd_lab.demo for {len(drones)} drones",
        f"swarm: {swarm}",
        f"domain_id: {domain_id}",
        "discovery:",
        f"  t_min_s: {T_MIN_S}",
        f"  t_max_s: {T_MAX_S}",
        f"  lease_s: {LEASE_S}",
        "participants:",
    ]
    for d in drones:
        # on loopback every drone shares 127.0.0.1: the mission then names no addresses
        address = "" if loopback else f", ipv4: {d.address}"
        lines.append(
            f"  - {{name: {d.name}, index: {d.index}, role: {d.role}, "
            f"mavlink_sysid: {d.sysid}{address}}}"
        )
    lines += [
        "topics:",
        "  - {name: swarm/ready, type: swarmd::Readiness, reliability: best_effort,",
        "     durability: volatile, history_depth: 1, writers: member, readers: commander}",
        "  - {name: swarm/command, type: swarmd::Command, reliability: reliable,",
        "     durability: volatile, history_depth: 8, writers: commander, readers: member}",
        "  - {name: swarm/outcome, type: swarmd::CommandOutcome, reliability: reliable,",
        "     durability: volatile, history_depth: 16, writers: member, readers: commander}",
    ]
    return "\n".join(lines) + "\n" + (ROS2_GRAPH if ros2 else "")


def xrce_port(d: Drone) -> int:
    return XRCE_PORT + (d.mavlink_port - PX4_PORT)


def px4_section(s: Scenario, d: Drone, vehicle: str) -> str:
    if vehicle in ("xrce", "xrce-client"):
        # xrce: swarmd is the stand-in's agent (only its key may open a session);
        # xrce-client: swarmd joins the drone's MicroXRCEAgent as a second client (a companion
        # that keeps its agent for ROS 2). The stand-in's core topic set has no home_position
        # (real PX4 publishes it): readiness without it; the take-off altitude is then
        # measured from the GPS altitude (docs/px4.md, Altitude)
        agent = vehicle == "xrce"
        key = f"  xrce_key: {d.sysid}\n" if agent else ""
        return f"""\
px4:
  enabled: true
  backend: {"xrce-agent" if agent else "xrce-client"}
  connection: udp:127.0.0.1:{xrce_port(d)}
{key}  require_home: false
  takeoff_alt_m: {TAKEOFF_ALT_M}
"""
    return f"""\
px4:
  enabled: true
  connection: udpin:127.0.0.1:{d.mavlink_port}
  signing: true
  signing_key: {s.px4_key_path(d)}
  takeoff_alt_m: {TAKEOFF_ALT_M}
"""


def config_text(
    s: Scenario, d: Drone, *, loopback: bool, vehicle: str = "mavlink", ros2: bool = False
) -> str:
    """A daemon config as an operator would write it (config/swarmd.yaml), per drone."""
    relay = "ros2:\n  relay: true\n" if ros2 else ""
    return f"""\
node: {d.name}
bundle:
  path: {s.bundle_path}
  trusted_key: {s.trusted_key}
  node_key: {s.root / "keys" / "nodes" / f"{d.name}.key"}
network:
  interface: {d.interface}
  ipv4: {d.address if loopback else "null"}
control:
  socket: {s.socket_path(d)}
  mode: "0660"
link:
  sources: [file, static]
  poll_interval_s: 0.5
  file: {s.link_path(d)}
  static_q: 0.5
discovery:
  mode: adaptive
{px4_section(s, d, vehicle)}dataplane:
  enabled: true
  readiness_period_s: 1.0
  state_dir: {s.root / "state"}
{relay}logging:
  level: info
  format: json
"""


def write(
    root: Path,
    drones: list[Drone],
    *,
    domain_id: int,
    loopback: bool,
    vehicle: str = "mavlink",
    ros2: bool = False,
) -> Scenario:
    """Keys, mission, signed bundle, link files and configs under ``root``."""
    late = next((d.name for d in drones if d.gps_fix_after_s >= LATE_GPS_S), None)
    s = Scenario(root, drones, domain_id, late)
    for sub in ("keys", "nodes", "run", "link", "logs", "state"):
        (root / sub).mkdir(parents=True, exist_ok=True)
    mission_path = root / "mission.yaml"
    mission_path.write_text(mission_text(drones, domain_id, "demo", loopback=loopback, ros2=ros2))
    mission = parse_mission(mission_path.read_text(), str(mission_path))
    generate_keys(root / "keys", [d.name for d in drones])
    built = build_from_files(mission, root / "keys" / SIGNING_KEY_FILE, root / "keys")
    s.bundle_path.write_bytes(built.data)
    (root / "keys" / "px4").mkdir(exist_ok=True)
    for d in drones:
        # what 'swarmctl px4 key --out' writes for PX4's SD card; the simulator reads it
        secret = node_secret(node_key_path(root / "keys", d.name))
        key = derive_key(secret, mission.swarm, d.name)
        write_file_atomic(s.px4_key_path(d), px4_key_file(key, 0), PRIVATE_MODE)
        s.link_path(d).write_text(json.dumps({"snr_db": d.snr_db}))
        s.config_path(d).write_text(
            config_text(s, d, loopback=loopback, vehicle=vehicle, ros2=ros2)
        )
    return s
