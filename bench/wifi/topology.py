"""The testbed's Linux side: one namespace per drone, each wired to its own ns-3 node.

Per drone i (testbed notes, "Topology that works")::

    drone namespace <prefix>-<i>          hub namespace <prefix>-hub (ns-3 runs here)
      eth0 (MAC = ns-3 node i's MAC) ──veth── v<i> ─┐
                                                   br<i> (no snooping, no STP, delay 0)
                                    tap t<i> ──────┘   ◀── TapBridge UseLocal, node i

Everything, bridges and taps included, lives in namespaces this module creates, so the
host's own network stack is never touched and deleting the namespaces deletes every
interface with them. ns-3 itself runs inside the hub namespace, where it opens the taps.
IPv6 is disabled before any interface comes up (pitfall 4: only ARP and IGMP remain),
rp_filter is 0 (pitfall 7) and each drone has a 224.0.0.0/4 route on eth0 (pitfall 5).
eth0 gets the MAC ns-3 will allocate to node i (00:00:00:00:00:01, ...; pitfall 3): the
channel process reports the real ones and ``check_macs`` compares.
"""

from __future__ import annotations

import subprocess
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Final

from swarmd_lab.closing import Closing
from swarmd_lab.netns import (
    Namespace,
    NamespaceRecord,
    NetnsError,
    add_veth,
    cleanup_dead_runs,
    configure_host,
)

BASE: Final = "swf"  # swarmd wifi testbed; cleanup_dead_runs("swf") sweeps killed runs
MAX_DRONES: Final = 250
_SYSCTL_TIMEOUT_S: Final = 10.0


class TopologyError(NetnsError):
    """A command failed while building the testbed's namespaces."""


def _ip(*args: str) -> None:
    proc = subprocess.run(
        ["ip", *args], capture_output=True, text=True, timeout=_SYSCTL_TIMEOUT_S, check=False
    )
    if proc.returncode != 0:
        raise TopologyError(f"ip {' '.join(args)}: {proc.stderr.strip() or proc.returncode}")


def _sysctls(namespace: str, settings: Sequence[tuple[str, str]]) -> None:
    # one shell per namespace instead of one `sysctl` per key: 20 drones start in ~1 s
    script = "; ".join(f"echo {v} > /proc/sys/{k.replace('.', '/')}" for k, v in settings)
    proc = subprocess.run(
        ["ip", "netns", "exec", namespace, "sh", "-ec", script],
        capture_output=True,
        text=True,
        timeout=_SYSCTL_TIMEOUT_S,
        check=False,
    )
    if proc.returncode != 0:
        raise TopologyError(f"sysctl in {namespace}: {proc.stderr.strip() or proc.returncode}")


def ns3_mac(index: int) -> str:
    """The MAC ns-3 allocates to the i-th Wi-Fi device of a fresh process (Mac48Address)."""
    value = index + 1
    return ":".join(f"{(value >> (8 * k)) & 0xFF:02x}" for k in range(5, -1, -1))


@dataclass
class Testbed(Closing):
    """Build with ``with Testbed(prefix, n) as tb:``; torn down on every exit path."""

    prefix: str
    size: int
    subnet_octet: int = 0
    hub: str = ""
    drones: list[Namespace] = field(default_factory=list)
    _namespaces: NamespaceRecord = field(default_factory=NamespaceRecord)

    def __post_init__(self) -> None:
        if not 1 <= self.size <= MAX_DRONES:
            raise ValueError(f"the testbed holds 1..{MAX_DRONES} drones, not {self.size}")
        self.hub = f"{self.prefix}-hub"

    @property
    def tap_prefix(self) -> str:
        return "t"

    def address(self, index: int) -> str:
        return f"10.78.{self.subnet_octet}.{index + 1}"

    def _open(self) -> None:
        cleanup_dead_runs(BASE)
        no_v6 = [
            ("net.ipv6.conf.all.disable_ipv6", "1"),
            ("net.ipv6.conf.default.disable_ipv6", "1"),
        ]
        # IPv6 goes off right after each namespace exists, before any other interface is
        # up (pitfall 4); lo alone is up by then and carries nothing to the channel
        self._namespaces.add(self.hub)
        _sysctls(self.hub, no_v6)
        for i in range(self.size):
            name = f"{self.prefix}-{i}"
            self._namespaces.add(name)
            _sysctls(
                name,
                [
                    *no_v6,
                    ("net.ipv4.conf.all.rp_filter", "0"),
                    ("net.ipv4.conf.default.rp_filter", "0"),
                ],
            )
            h = ("-n", self.hub)
            add_veth(self.hub, f"v{i}", name)
            _ip("-n", name, "link", "set", "eth0", "address", ns3_mac(i))
            _ip(
                *h,
                "link",
                "add",
                f"br{i}",
                "type",
                "bridge",
                "mcast_snooping",
                "0",
                "stp_state",
                "0",
                "forward_delay",
                "0",
            )
            _ip(*h, "tuntap", "add", "dev", f"t{i}", "mode", "tap")
            _ip(*h, "link", "set", f"v{i}", "master", f"br{i}")
            _ip(*h, "link", "set", f"t{i}", "master", f"br{i}")
            for dev in (f"br{i}", f"v{i}", f"t{i}"):
                _ip(*h, "link", "set", dev, "up")
            configure_host(name, f"{self.address(i)}/24")
            self.drones.append(Namespace(name, self.address(i), 24))

    def check_macs(self, macs: Sequence[str]) -> None:
        """Raise unless ns-3's MACs are the ones eth0 got (else ns-3 dies on frame one)."""
        want = [ns3_mac(i) for i in range(self.size)]
        if [m.lower() for m in macs] != want:
            raise TopologyError(f"ns-3 allocated MACs {list(macs)}, expected {want}")

    def close(self) -> None:
        """Stop what runs in the namespaces and delete them (idempotent)."""
        for drone in self.drones:
            drone.stop_children()
        self._namespaces.close()
        self.drones.clear()
