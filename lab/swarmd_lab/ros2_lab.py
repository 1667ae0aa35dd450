"""Lab helpers for real ROS 2 nodes in network namespaces (issue 19).

Fast DDS 3.2 decides that two participants share a host by ``/etc/machine-id`` and then moves
their data through shared memory, silently, whatever the network namespace: an emulated drone
needs its own machine id and its own ``/dev/shm``. ``host_argv`` wraps a command so that it runs
in a private mount namespace (``unshare -m``, private propagation: nothing leaks to the host)
with both bind-mounted/fresh. ``discovery_counts`` classifies the RTPS datagrams of a capture
by their builtin endpoint (DDSI-RTPS 2.5 9.3.2: SPDP 0x000100c2/c7, SEDP publications
0x000003c2/c7 and subscriptions 0x000004c2/c7).
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import time
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Final

from swarmd.bundle.ros2 import GRAPH_TOPIC, Ros2Participant
from swarmd.ros2.relay_spdp import static_edp_entity_id
from swarmd_lab.netns import Lan, Namespace

SPDP_IDS: Final = frozenset({"0x000100c2", "0x000100c7"})
SEDP_IDS: Final = frozenset({"0x000003c2", "0x000003c7", "0x000004c2", "0x000004c7"})
_TSHARK_TIMEOUT_S: Final = 60.0
# swarmd's RTPS vendor id 53.57 ("SW") as tshark prints rtps.vendorId
SWARMD_VENDOR: Final = frozenset({"0x5357", "21335"})

# mount the host's own machine id and a fresh /dev/shm, then exec the command
_MOUNT_SCRIPT: Final = (
    'mount --bind "$0" /etc/machine-id && mount -t tmpfs -o size=64m tmpfs /dev/shm && exec "$@"'
)


# The ROS 2 nodes of the lab's missions (``chatter_mission``), as YAML flow mappings: a
# talker serves /trigger, a listener (or a second subscriber, the monitor) calls it.
TALKER_NODE: Final = "{name: talker, drones: member, publishes: [/chatter], serves: [/trigger]}"
LISTENER_NODE: Final = (
    "{name: listener, drones: commander, subscribes: [/chatter], calls: [/trigger]}"
)
MONITOR_NODE: Final = "{name: monitor, drones: member, subscribes: [/chatter], calls: [/trigger]}"
# swarmd's own discovery quick (announcements every 0.2-0.5 s), so a run converges in seconds
QUICK_DISCOVERY: Final = "{t_min_s: 0.2, t_max_s: 0.5, lease_s: 4}"


def drone_names(n: int) -> list[str]:
    """The drones of a ``chatter_mission`` of ``n``: the lead, then drone-1 .. drone-(n-1)."""
    return ["lead", *(f"drone-{i}" for i in range(1, n))]


def chatter_mission(
    swarm: str,
    domain_id: int,
    addresses: Sequence[str],
    nodes: Sequence[str] = (TALKER_NODE, LISTENER_NODE),
    *,
    ros2_domain: int = 7,
    discovery: str | None = QUICK_DISCOVERY,
) -> str:
    """The text of a mission for real ROS 2 nodes in namespaces: one drone per address (the
    lead commands, ``drone_names``), swarmd's readiness topic, the ROS 2 topic ``/chatter``
    (std_msgs/String, reliable, depth 10) and service ``/trigger`` (std_srvs/Trigger), and
    ``nodes`` (YAML flow mappings: ``TALKER_NODE``, ...); ``discovery`` None: the defaults."""
    participants = [
        f"  - {{name: {name}, index: {i}, role: {'commander' if i == 0 else 'member'}, "
        f"mavlink_sysid: {i + 1}, ipv4: {address}}}"
        for i, (name, address) in enumerate(
            zip(drone_names(len(addresses)), addresses, strict=True)
        )
    ]
    lines = [f"swarm: {swarm}", f"domain_id: {domain_id}"]
    if discovery is not None:
        lines.append(f"discovery: {discovery}")
    lines += ["participants:", *participants]
    lines += [
        "topics:",
        '  - {name: swarm/ready, type: "swarmd::Readiness", writers: member, readers: commander}',
        "ros2:",
        f"  domain_id: {ros2_domain}",
        "  topics:",
        "    - {name: /chatter, type: std_msgs/msg/String, reliability: reliable,"
        " history_depth: 10}",
        "  services:",
        "    - {name: /trigger, type: std_srvs/srv/Trigger}",
        "  nodes:",
        *(f"    - {node}" for node in nodes),
    ]
    return "\n".join(lines) + "\n"


def write_machine_id(directory: Path, host_index: int) -> Path:
    """A per-host machine id file (32 hex digits, as systemd writes it)."""
    path = directory / f"machine-id-{host_index}"
    path.write_text(f"{0x5A17_0000 + host_index:032x}\n")
    return path


def host_argv(argv: Sequence[str], machine_id: Path) -> list[str]:
    """``argv`` in a private mount namespace with ``machine_id`` and its own ``/dev/shm``."""
    unshare = shutil.which("unshare") or "unshare"
    return [
        unshare,
        "-m",
        "--propagation",
        "private",
        "sh",
        "-c",
        _MOUNT_SCRIPT,
        str(machine_id),
        *argv,
    ]


def own_host_argv(argv: Sequence[str], workdir: Path, host_index: int) -> list[str]:
    """``argv`` as run on emulated host ``host_index``: with that host's own machine id
    (``write_machine_id`` under ``workdir``) and its own ``/dev/shm`` (``host_argv``)."""
    return host_argv(argv, write_machine_id(workdir, host_index))


@dataclass(frozen=True, slots=True)
class DiscoveryCounts:
    rtps: int  # RTPS datagrams on the link
    spdp: int  # datagrams carrying an SPDP submessage
    sedp: int  # datagrams carrying an SEDP submessage (DATA, HEARTBEAT, ACKNACK, GAP)
    multicast: int  # RTPS datagrams to a multicast group
    spdp_swarmd: int = 0  # of ``spdp``: swarmd's own (vendor 53.57), the rest are ROS 2's
    sedp_swarmd: int = 0

    @property
    def ros2_spdp(self) -> int:
        return self.spdp - self.spdp_swarmd

    @property
    def ros2_sedp(self) -> int:
        return self.sedp - self.sedp_swarmd


def rtps_fields(pcap: Path, *fields: str, timeout_s: float = _TSHARK_TIMEOUT_S) -> list[list[str]]:
    """``fields`` of every RTPS datagram in the capture (tshark's RTPS dissector), one list
    per datagram; a field with several submessages' values holds them comma-separated;
    tshark may read for ``timeout_s``.

    RTPS has no port of its own in tshark: it is found by a heuristic, which by default runs
    after the port table. Fast DDS 3.2 puts a stock node's unique-flow graph reader at
    ``portBase - 400`` = 7000 (and up), the AFS (RX) ports, so without trying the heuristic
    first those datagrams are decoded as AFS and missed (bench/ros2_relist.py found it)."""
    argv = [shutil.which("tshark") or "tshark", "-r", str(pcap), "-Y", "rtps", "-T", "fields"]
    argv += ["-o", "udp.try_heuristic_first:TRUE", "-E", "separator=;"]
    for f in fields:
        argv += ["-e", f]
    result = subprocess.run(  # noqa: S603 - argv list
        argv, capture_output=True, text=True, timeout=timeout_s, check=True
    )
    return [
        (line.split(";") + [""] * len(fields))[: len(fields)]
        for line in result.stdout.splitlines()
        if line.strip()
    ]


def discovery_counts(pcap: Path, senders: frozenset[str] | None = None) -> DiscoveryCounts:
    """Count the capture's RTPS datagrams by discovery kind (tshark's RTPS dissector);
    ``senders``: only datagrams from these IPv4 addresses (the drones, not an attacker)."""
    rows = rtps_fields(
        pcap, "ip.src", "ip.dst", "rtps.sm.wrEntityId", "rtps.sm.rdEntityId", "rtps.vendorId"
    )
    rtps = spdp = sedp = multicast = spdp_swarmd = sedp_swarmd = 0
    for src, dst, writers, readers, vendor in rows:
        if senders is not None and src not in senders:
            continue
        ids = set(writers.split(",")) | set(readers.split(","))
        is_swarmd = vendor.split(",")[0].strip().lower() in SWARMD_VENDOR
        rtps += 1
        spdp += bool(ids & SPDP_IDS)
        sedp += bool(ids & SEDP_IDS)
        spdp_swarmd += bool(ids & SPDP_IDS) and is_swarmd
        sedp_swarmd += bool(ids & SEDP_IDS) and is_swarmd
        multicast += dst.startswith(("224.", "239."))
    return DiscoveryCounts(rtps, spdp, sedp, multicast, spdp_swarmd, sedp_swarmd)


def node_env(env_file: Path) -> dict[str, str]:
    """The environment a ROS 2 node starts with: ours without any ROS_*/RMW_* or Fast DDS
    profile variable (so nothing of the caller's leaks in), plus the generated env file's."""
    env = {k: v for k, v in os.environ.items() if not k.startswith(("ROS_", "RMW_"))}
    env.pop("FASTDDS_DEFAULT_PROFILES_FILE", None)
    for line in env_file.read_text().splitlines():
        if line and not line.startswith("#"):
            key, _, value = line.partition("=")
            env[key] = value
    return env


def node_argv(role: str, seconds: float, *extra: str, name: str | None = None) -> list[str]:
    """The command of one ``swarmd_lab.ros2_node`` (``role``: talker or listener; ``name``:
    its node name when not the role's) running ``seconds``, with ``extra`` options."""
    argv = [sys.executable, "-m", "swarmd_lab.ros2_node", role]
    if name is not None:
        argv += ["--name", name]
    return [*argv, "--seconds", str(seconds), *extra]


class NodeLauncher:
    """Starts ROS 2 nodes on hosts as on drones of their own: drone ``drones[i]`` is
    ``hosts[i]``, its nodes in a private mount namespace with the drone's machine id (written
    under ``workdir``) and its own ``/dev/shm`` (``host_argv``), each in the environment of its
    generated ``profiles/<drone>/<node>.env`` (``node_env``)."""

    def __init__(
        self,
        hosts: Lan | Sequence[Namespace],
        drones: Sequence[str],
        profiles: Path,
        workdir: Path,
    ) -> None:
        self.hosts, self.drones, self.profiles = hosts, drones, profiles
        self.machine_ids = [write_machine_id(workdir, i) for i in range(len(drones))]

    def start(
        self,
        i: int,
        node: str,
        argv: Sequence[str],
        *,
        stdout: int | IO[bytes] | None = subprocess.PIPE,
        stderr: int | IO[bytes] | None = None,
    ) -> subprocess.Popen[bytes]:
        """``argv`` (the command of ``node``) on drone ``i``."""
        return self.hosts[i].popen(
            host_argv(argv, self.machine_ids[i]),
            env=node_env(self.profiles / self.drones[i] / f"{node}.env"),
            stdout=stdout,
            stderr=stderr,
        )


def start_capture(hub: str, bridge: str, pcap: Path, timeout_s: float) -> subprocess.Popen[bytes]:
    """tshark writing ``pcap`` from ``bridge`` in namespace ``hub``; returns once it is
    capturing (the file has its header). RuntimeError when it does not start in time."""
    tshark = shutil.which("tshark") or "tshark"
    proc = subprocess.Popen(  # noqa: S603 - argv list
        ["ip", "netns", "exec", hub, tshark, "-i", bridge, "-w", str(pcap), "-q"],  # noqa: S607
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if pcap.exists() and pcap.stat().st_size > 0:
            return proc
        time.sleep(0.1)
    proc.kill()
    proc.wait()
    raise RuntimeError(f"tshark did not start capturing on {bridge} in {hub}")


def ros2_ports(participants: Iterable[Ros2Participant]) -> frozenset[int]:
    """Every port the bundle gives a ROS 2 participant (metatraffic and user data)."""
    return frozenset(port for p in participants for port in (p.metatraffic_port, p.user_port))


def graph_entity_ids(participants: Iterable[Ros2Participant]) -> frozenset[str]:
    """The ``ros_discovery_info`` (rmw's graph topic) writer and reader entity ids of the
    bundle's participants, as tshark prints them (``0x00006c03``): the profile fixes every
    endpoint's entity id to its ``userDefinedID`` (swarmd.ros2.profile)."""
    out = set()
    for p in participants:
        for i, e in enumerate(p.endpoints):
            if e.dds_topic == GRAPH_TOPIC:
                octets = static_edp_entity_id(p.first_user_id + i, e.kind).split(".")
                out.add("0x" + "".join(f"{int(o):02x}" for o in octets))
    return frozenset(out)


def graph_datagrams(
    pcap: Path, entity_ids: frozenset[str], senders: frozenset[str], ports: frozenset[int]
) -> int:
    """Datagrams from ``senders`` to one of the ROS 2 participants' ``ports`` with a
    submessage to or from one of ``entity_ids``: ROS 2's graph traffic (``ros_discovery_info``
    DATA, HEARTBEAT, ACKNACK) on the captured link. The ports matter: entity ids are unique
    only within a participant, and swarmd's own endpoints use small ones too."""
    rows = rtps_fields(pcap, "ip.src", "udp.dstport", "rtps.sm.wrEntityId", "rtps.sm.rdEntityId")
    count = 0
    for src, port, writers, readers in rows:
        if src not in senders or not port.isdigit() or int(port) not in ports:
            continue
        if (set(writers.split(",")) | set(readers.split(","))) & entity_ids:
            count += 1
    return count
