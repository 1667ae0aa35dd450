"""The testbed's dev bundle: N participants uav1..uavN (uav1 commands) on domain 0.

Topics are the data plane's well-known ones with the types it requires
(``swarmd.dataplane.endpoints.TOPIC_TYPES``): the 1 Hz ``swarm/ready`` from every member to
the commander (best effort, keep last 1, as in firmware_bundle/missions), ``swarm/command``
and ``swarm/outcome``. Discovery timing is the paper's: Tmin 8 s, Tmax 20 s, lease 20 s.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from swarmd.bundle.build import build_dev_bundle
from swarmd.bundle.keys import dev_signing_key, public_pem, raw_public
from swarmd.bundle.mission import parse_mission

SWARM = "wifibench"


@dataclass(frozen=True)
class BundleFiles:
    path: Path
    trusted_key: Path


def mission_text(addresses: list[str], *, t_min_s: float, t_max_s: float, lease_s: float) -> str:
    parts = [
        f"  - {{name: uav{i + 1}, index: {i}, role: {'commander' if i == 0 else 'member'}, "
        f"mavlink_sysid: {i + 1}, ipv4: {addr}}}"
        for i, addr in enumerate(addresses)
    ]
    return f"""\
swarm: {SWARM}
domain_id: 0
discovery: {{t_min_s: {t_min_s}, t_max_s: {t_max_s}, lease_s: {lease_s}}}
participants:
{chr(10).join(parts)}
topics:
  - {{name: swarm/ready, type: "swarmd::Readiness", reliability: best_effort,
     history_depth: 1, writers: member, readers: commander}}
  - {{name: swarm/command, type: "swarmd::Command", reliability: reliable,
     history_depth: 8, writers: commander, readers: member}}
  - {{name: swarm/outcome, type: "swarmd::CommandOutcome", reliability: reliable,
     history_depth: 16, writers: member, readers: commander}}
"""


def write_bundle(
    directory: Path,
    addresses: list[str],
    *,
    t_min_s: float = 8.0,
    t_max_s: float = 20.0,
    lease_s: float = 20.0,
) -> BundleFiles:
    """Build, dev-sign and write the bundle and its trust key under ``directory``."""
    text = mission_text(addresses, t_min_s=t_min_s, t_max_s=t_max_s, lease_s=lease_s)
    built = build_dev_bundle(parse_mission(text, "wifibench-mission.yaml"))
    directory.mkdir(parents=True, exist_ok=True)
    path = directory / "bundle.swb"
    path.write_bytes(built.data)
    key = directory / "swarm.pub"
    key.write_bytes(public_pem(raw_public(dev_signing_key(SWARM))))
    return BundleFiles(path, key)
