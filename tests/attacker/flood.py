"""Issue 10 attack 9: a bounded multicast flood of forged SPDP, and what it cost the swarm.

Shared by ``tests/test_attacks_discovery_netns.py`` and ``bench/flood.py``: the flood runs
in a thread (bounded by count and by time) while the main thread watches every daemon's peer
table; daemon CPU comes from ``/proc/<pid>/stat`` (utime + stime) before and after.
"""

from __future__ import annotations

import random
import threading
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from typing import Any

from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey

from swarmd.auth.freshness import Freshness
from swarmd.rtps.types import GuidPrefix
from tests.attacker import forge
from tests.attacker.host import Attacker
from tests.attacker.swarm import FlashedSwarm, cpu_seconds

POLL_S = 0.25


@dataclass
class FloodResult:
    rate_hz: float
    seconds: float  # how long the flood really ran
    sent: int
    # drone -> real peers seen in another state than "discovered" during the flood, or
    # reported lost in its log ("peer_lost"); the target is {}
    peers_lost: dict[str, list[str]] = field(default_factory=dict)
    cpu_percent: dict[str, float] = field(default_factory=dict)  # per daemon, of one core
    idle_cpu_percent: dict[str, float] = field(default_factory=dict)  # same, without flood
    polls: int = 0
    # datagrams the kernel dropped before the daemon read them (UDP RcvbufErrors in the
    # drone's namespace, /proc/net/snmp): a flood the daemon never saw, so never counted
    kernel_rcvbuf_drops: dict[str, int] = field(default_factory=dict)
    # the same, for the SPDP sockets alone (/proc/net/udp "drops", per socket)
    spdp_socket_drops: dict[str, int] = field(default_factory=dict)
    # drone -> {peer: seconds after the flood started when it was first seen lost}
    lost_at_s: dict[str, dict[str, float]] = field(default_factory=dict)

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


def forged_pool(sw: FlashedSwarm, atk: Attacker, size: int, seed: int) -> list[bytes]:
    """The flood's datagrams (``forge.flood_pool``) from what the attacker sniffed: the
    members' announcements and their (public) freshness, re-signed with a key of its own."""
    atk.wait_for(lambda: all(atk.member(n) for n in sw.names), 20.0)
    learned = [m for n in sw.names if (m := atk.member(n)) is not None]
    fresh: dict[GuidPrefix, Freshness] = {
        m.participant.guid_prefix: m.freshness for m in learned if m.freshness is not None
    }
    return forge.flood_pool(
        [m.participant for m in learned],
        size,
        random.Random(seed),
        fresh=fresh,
        signer=Ed25519PrivateKey.generate(),
    )


def rcvbuf_errors(sw: FlashedSwarm, i: int) -> int:
    """UDP RcvbufErrors of drone i's namespace (/proc/net/snmp is per network namespace)."""
    lines = [ln.split() for ln in sw.lan[i].run(["cat", "/proc/net/snmp"]).stdout.splitlines()]
    udp = [ln for ln in lines if ln and ln[0] == "Udp:"]
    if len(udp) < 2 or "RcvbufErrors" not in udp[0]:
        return 0
    return int(udp[1][udp[0].index("RcvbufErrors")])


def spdp_socket_drops(sw: FlashedSwarm, i: int) -> int:
    """Datagrams drone i's kernel dropped on its SPDP sockets (the multicast port and the
    metatraffic unicast port) for want of receive buffer: /proc/net/udp's last column."""
    ports = {sw.spdp_group[1], sw.meta_addr(i)[1]}
    total = 0
    for line in sw.lan[i].run(["cat", "/proc/net/udp"]).stdout.splitlines()[1:]:
        words = line.split()
        if len(words) >= 13 and int(words[1].split(":")[1], 16) in ports:
            total += int(words[-1])
    return total


def run_flood(
    sw: FlashedSwarm,
    atk: Attacker,
    pool: list[bytes],
    rate_hz: float,
    seconds: float,
    *,
    idle_s: float = 3.0,
    send: Callable[[float, int, float], int] | None = None,
) -> FloodResult:
    """Flood ``pool`` at ``rate_hz`` for at most ``seconds`` (and ``rate_hz * seconds``
    datagrams) to the SPDP group; record lost real peers and daemon CPU. ``send(rate,
    max_count, max_s)``, when given, sends instead (a spoofer: ``tests/attacker/spoof.py``)
    and returns how many it sent."""
    pids = {i: sw.daemon_pid(i) for i in range(sw.n)}
    # the same daemons without a flood, for comparison
    cpu0 = {i: cpu_seconds(p) for i, p in pids.items()}
    time.sleep(idle_s)
    cpu1 = {i: cpu_seconds(p) for i, p in pids.items()}
    lost_before = {i: len(sw.log_events(i, "peer_lost")) for i in range(sw.n)}
    result = FloodResult(rate_hz, 0.0, 0)
    result.idle_cpu_percent = {
        sw.names[i]: round(100 * (cpu1[i] - cpu0[i]) / idle_s, 1) for i in pids
    }
    sent: list[int] = []

    def flood() -> None:
        if send is not None:
            sent.append(send(rate_hz, int(rate_hz * seconds), seconds))
            return
        sent.append(
            atk.paced(
                pool,
                sw.spdp_group,
                rate_hz=rate_hz,
                max_count=int(rate_hz * seconds),
                max_s=seconds,
            )
        )

    lost: dict[str, set[str]] = {}
    kernel0 = {i: rcvbuf_errors(sw, i) for i in range(sw.n)}
    socket0 = {i: spdp_socket_drops(sw, i) for i in range(sw.n)}
    thread = threading.Thread(target=flood, name="spdp-flood")
    start = time.monotonic()
    c0 = {i: cpu_seconds(p) for i, p in pids.items()}
    thread.start()
    while thread.is_alive() and time.monotonic() - start < seconds + 5.0:
        for i in range(sw.n):
            try:
                states = sw.peer_states(i)
            except Exception:  # noqa: BLE001 - an unreachable daemon under flood is a finding
                lost.setdefault(sw.names[i], set()).add("<control socket unreachable>")
                continue
            for name, state in states.items():
                if state != "discovered":
                    lost.setdefault(sw.names[i], set()).add(name)
                    at = result.lost_at_s.setdefault(sw.names[i], {})
                    at.setdefault(name, round(time.monotonic() - start, 2))
        result.polls += 1
        time.sleep(POLL_S)
    thread.join(timeout=seconds + 5.0)
    c1 = {i: cpu_seconds(p) for i, p in pids.items()}
    result.seconds = round(time.monotonic() - start, 2)
    result.kernel_rcvbuf_drops = {
        sw.names[i]: rcvbuf_errors(sw, i) - kernel0[i] for i in range(sw.n)
    }
    result.spdp_socket_drops = {
        sw.names[i]: spdp_socket_drops(sw, i) - socket0[i] for i in range(sw.n)
    }
    result.sent = sent[0] if sent else 0
    result.cpu_percent = {
        sw.names[i]: round(100 * (c1[i] - c0[i]) / result.seconds, 1) for i in pids
    }
    for i in range(sw.n):
        for event in sw.log_events(i, "peer_lost")[lost_before[i] :]:
            lost.setdefault(sw.names[i], set()).add(str(event.get("peer")))
    result.peers_lost = {k: sorted(v) for k, v in lost.items()}
    return result
