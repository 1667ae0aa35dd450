"""Issue 10's attacks on SPDP and discovery (docs/security.md, "Attack tests", attacks 3, 4,
7 and 9), each from a host on the swarm's LAN that is not in the bundle: forged disposes,
redirects to the attacker's locators, a locator on the drone's own MAVLink port, and a
bounded flood of forged SPDP.

The swarm, the attacker, the three things every test asserts and the rules they share are
``tests/attacker/lab.py``'s. Seen failing against main before the defences (f0f3378) for the
attack's own reason: a peer disposed, commands sent to the attacker, RTPS sent into the
MAVLink port.
"""

from __future__ import annotations

import subprocess
import threading
import time
from collections.abc import Callable
from typing import Final

import pytest

from swarmd.auth.freshness import Freshness
from tests.attacker import cpulimit, forge
from tests.attacker.flood import FloodResult, forged_pool, run_flood
from tests.attacker.host import drain
from tests.attacker.lab import (
    ATTACKER_KEY,
    LEAD,
    M1,
    M2,
    PX4_PORT,
    SETTLE_S,
    SPDP,
    Lab,
    settle,
)
from tests.attacker.swarm import FlashedSwarm

pytestmark = [pytest.mark.netns]


# -- 3. dispose, and a dispose flood during --require-all -----------------------------------


def test_forged_dispose_refused(lab: Lab) -> None:
    sw, atk = lab.swarm, lab.attacker
    before = lab.refusals()
    lost_before = len(sw.log_events(LEAD, "peer_lost"))
    datagram = forge.forged_dispose(lab.prefix(M1), lab.sn())
    atk.multicast(datagram)
    atk.send(datagram, sw.meta_addr(LEAD))
    # fresh, signed, but with the attacker's key: refused on the tag (or the signature)
    atk.multicast(forge.signed_dispose(lab.prefix(M1), lab.sn(), lab.fresh(M1), ATTACKER_KEY))

    def lost() -> bool:
        return len(sw.log_events(LEAD, "peer_lost")) > lost_before

    settle(lambda: lost() or lab.forged(before, LEAD) >= 1)
    assert not lost(), sw.log_events(LEAD, "peer_lost")
    assert sw.peer_states(LEAD)[sw.names[M1]] == "discovered"
    assert lab.moved(before, LEAD, SPDP + "auth_missing") >= 2, lab.refused_since(before, LEAD)
    assert lab.forged(before, LEAD) >= 1, lab.refused_since(before, LEAD)
    lab.assert_commander_commands_all()


def test_dispose_flood_during_require_all_takeoff(lab: Lab) -> None:
    """4 forged disposes a second for each member while the operator runs
    ``swarmctl takeoff --require-all``: the take-off still goes out and completes."""
    sw, atk = lab.swarm, lab.attacker
    lab.dirty = True  # the drones fly
    before = lab.refusals()
    lost_before = len(sw.log_events(LEAD, "peer_lost"))
    members = [lab.prefix(M1), lab.prefix(M2)]
    stop = threading.Event()

    def flood() -> None:
        deadline = time.monotonic() + 15.0  # bounded in time and in count (4/s x 2 x 15 s)
        while not stop.is_set() and time.monotonic() < deadline:
            for prefix in members:
                atk.multicast(forge.forged_dispose(prefix, lab.sn()))
            stop.wait(0.25)

    thread = threading.Thread(target=flood, name="dispose-flood")
    thread.start()
    try:
        time.sleep(0.5)
        done = sw.swarmctl(LEAD, "takeoff", "--require-all", "--timeout", "10", "--alt", "5")
    finally:
        stop.set()
        thread.join(timeout=5)
    assert sw.log_events(LEAD, "peer_lost")[lost_before:] == []
    assert done.returncode == 0, done.stdout + done.stderr
    assert lab.moved(before, LEAD, SPDP + "auth_missing") >= 8, lab.refused_since(before, LEAD)


# -- 4. redirect: an alive with the attacker's locator --------------------------------------


def _redirect(
    lab: Lab, forge_alives: Callable[[tuple[str, int], tuple[str, int]], None], settle_s: float
) -> None:
    """The shape both redirect attacks share: ``forge_alives(unicast, metatraffic)`` sends
    DATA(p)s of drone-1 naming the attacker's host, then the commander sends drone-1 a
    HOLD. Nothing may reach the attacker's ports, drone-1's locator at the commander must
    not move, and the HOLD must still be acknowledged (the real drone-1 got it)."""
    sw, atk = lab.swarm, lab.attacker
    here = sw.attacker_ns.address

    def locator() -> object:
        return next(p["locator"] for p in sw.status(LEAD)["peers"] if p["name"] == sw.names[M1])

    real_locator = locator()
    user, meta = atk.listener(17411), atk.listener(17410)
    try:
        forge_alives((here, 17411), (here, 17410))
        hold = sw.swarmctl(LEAD, "hold", "--only", sw.names[M1], "--timeout", "8", "--json")
        stolen = drain(user, settle_s) + drain(meta, 0.5)
    finally:
        user.close()
        meta.close()
    assert locator() == real_locator
    assert stolen == [], f"{len(stolen)} datagrams reached the attacker's host"
    assert hold.returncode == 0, hold.stdout + hold.stderr


def test_forged_alive_redirect_refused(lab: Lab) -> None:
    atk = lab.attacker
    learned = atk.member(lab.swarm.names[M1])
    assert learned is not None
    before = lab.refusals()

    def replayed_then_resigned(unicast: tuple[str, int], metatraffic: tuple[str, int]) -> None:
        lab.forged_alive_rounds(M1, learned, unicast, metatraffic)

    _redirect(lab, replayed_then_resigned, 0.5)
    lab.assert_replays_and_resigns_refused(before, LEAD, 3)
    lab.assert_commander_commands_all()


def test_captured_members_signed_redirect_refused_where_the_bundle_pins_it(lab: Lab) -> None:
    """Attack 4 by a captured member: drone-1's own key signs its DATA(p) naming the
    attacker's host (a victim) as both locators. Genuine, fresh, and refused whole
    (``bad_locator``): the flashed mission pins every drone's ``ipv4``. Then a command to
    drone-1 and a settle: nothing reaches the victim, drone-1's locator stays, the commander
    still commands all (docs/security.md, "Pinned addresses")."""
    atk = lab.attacker
    own = atk.member(lab.swarm.names[M1])
    assert own is not None and own.freshness is not None
    before = lab.refusals()
    lab.dirty = True  # genuine: it moves drone-1's replay windows at the others
    ring = lab.captured(M1)

    def signed_by_drone_1(unicast: tuple[str, int], metatraffic: tuple[str, int]) -> None:
        assert own.freshness is not None
        for k in range(3):
            freshness = Freshness(own.freshness.epoch, own.freshness.seq + 1 + k)
            atk.multicast(
                forge.forged_alive(
                    own.participant,
                    lab.sn(),
                    unicast=unicast,
                    metatraffic=metatraffic,
                    resign=(freshness, ring),
                )
            )
            time.sleep(0.3)

    _redirect(lab, signed_by_drone_1, SETTLE_S)
    for i in (LEAD, M2):
        assert lab.moved(before, i, SPDP + "bad_locator") >= 1, lab.refused_since(before, i)
    lab.assert_commander_commands_all()


# -- 7. a forged participant whose locator is the drone's own MAVLink port -----------------


def _count_rtps_to_mavlink(sw: FlashedSwarm) -> None:
    ruleset = f"""\
table inet atk_count {{
  chain output {{
    type filter hook output priority 0; policy accept;
    ip daddr 127.0.0.1 udp dport {PX4_PORT} @th,64,32 0x52545053 counter
  }}
}}
"""
    for i in range(sw.n):
        subprocess.run(  # noqa: S603 - fixed argv, ruleset on stdin
            sw.lan[i].command(["nft", "-f", "-"]), input=ruleset, text=True, check=True, timeout=10
        )


def _rtps_to_mavlink(sw: FlashedSwarm) -> list[int]:
    out = []
    for i in range(sw.n):
        text = sw.lan[i].run(["nft", "list", "table", "inet", "atk_count"]).stdout
        words = text.split()
        out.append(sum(int(words[k + 1]) for k, w in enumerate(words[:-1]) if w == "packets"))
    return out


def test_forged_loopback_locator_refused(lab: Lab) -> None:
    sw, atk = lab.swarm, lab.attacker
    learned = atk.member(sw.names[M2])
    assert learned is not None
    _count_rtps_to_mavlink(sw)
    before = lab.refusals()
    try:
        loopback = ("127.0.0.1", PX4_PORT)
        lab.forged_alive_rounds(M2, learned, loopback, loopback)
        # a captured drone-1 announcing loopback for itself: authentic, and still refused
        # for the locator (it moves drone-1's replay window a little: the swarm restarts)
        lab.dirty = True
        own = atk.member(sw.names[M1])
        assert own is not None and own.freshness is not None
        own_key = (Freshness(own.freshness.epoch, own.freshness.seq + 1), lab.captured(M1))
        atk.multicast(
            forge.forged_alive(
                own.participant, lab.sn(), unicast=loopback, metatraffic=loopback, resign=own_key
            )
        )
        # give the daemons the time to answer (directed replies, heartbeats, readiness)
        time.sleep(SETTLE_S)
        into_mavlink = _rtps_to_mavlink(sw)
    finally:
        for i in range(sw.n):
            sw.lan[i].run(["nft", "delete", "table", "inet", "atk_count"], check=False)
    assert into_mavlink == [0] * sw.n, f"RTPS into 127.0.0.1:{PX4_PORT}: {into_mavlink}"
    lab.assert_replays_and_resigns_refused(before, LEAD, 3)
    assert lab.moved(before, LEAD, SPDP + "bad_locator") >= 1, lab.refused_since(before, LEAD)
    lab.assert_commander_commands_all()


# -- 9. a bounded multicast flood of forged SPDP -------------------------------------------

FLOOD_RATE_HZ: Final = 5000.0
FLOOD_S: Final = 10.0


def test_spdp_flood_loses_no_real_peer(lab: Lab) -> None:
    sw, atk = lab.swarm, lab.attacker
    lab.dirty = True  # thousands of foreign entries in every daemon
    before = lab.refusals()
    pool = forged_pool(sw, atk, 2000, seed=10)
    result: FloodResult = run_flood(sw, atk, pool, FLOOD_RATE_HZ, FLOOD_S)
    assert result.sent >= 0.8 * FLOOD_RATE_HZ * FLOOD_S * 0.5, result  # the flood happened
    assert result.peers_lost == {}, result
    # half the flood claims the members' prefixes: each must be refused as a replay, on its
    # receiver tag or signature, or on a spent budget (counters.dropped.auth_*), never taken as
    # a renewal; the kernel may drop some under load, hence 10 %
    for i in range(sw.n):
        refused = {k: v for k, v in lab.refused_since(before, i).items() if "auth" in k}
        assert sum(refused.values()) >= 0.1 * result.sent / 2, (sw.names[i], refused, result)
        assert refused.get(SPDP + "auth_replayed", 0) > 0, refused
        signed = sum(v for k, v in refused.items() if "tag" in k or "signature" in k)
        assert signed > 0, refused  # the re-signed ones: refused on the tag (or signature)
    lab.assert_commander_commands_all()


# A drone's CPU is shared (PX4 bridge, ROS nodes) and a Jetson Nano's A57 is ~3-5x slower
# than this box: each daemon capped at 5 % of one core. Before the batched read and the
# offset-read replay check (docs/security.md, "Flood") a daemon needed ~7 % of a core here
# at 5,000/s: the kernel dropped ~40 % of the SPDP port's datagrams, real renewals among
# them, and a real peer's lease lapsed (bench/flood.py --cpu-percent 4). Now ~3 %.
CAPPED_PERCENT: Final = 5.0
CAPPED_MAX_KERNEL_DROP: Final = 0.10


def test_spdp_flood_on_a_capped_cpu_loses_no_real_peer(lab: Lab) -> None:
    reason = cpulimit.unavailable_reason()
    if reason is not None:
        pytest.skip(reason)
    sw, atk = lab.swarm, lab.attacker
    lab.dirty = True  # thousands of foreign entries, and daemons in a cgroup
    pool = forged_pool(sw, atk, 2000, seed=11)
    with cpulimit.CpuLimit(f"{sw.lan.prefix}-cap", CAPPED_PERCENT) as limit:
        for i in range(sw.n):
            limit.add(sw.daemon_pid(i))
        result: FloodResult = run_flood(sw, atk, pool, FLOOD_RATE_HZ, FLOOD_S)
    assert result.sent >= 0.8 * FLOOD_RATE_HZ * FLOOD_S * 0.5, result  # the flood happened
    # the daemon kept up: what the kernel dropped on the SPDP sockets (real renewals among
    # it, at random) stays small; before the fix this was ~40 % on every drone
    for name, drops in result.spdp_socket_drops.items():
        assert drops <= CAPPED_MAX_KERNEL_DROP * result.sent, (name, result)
    assert result.peers_lost == {}, result
