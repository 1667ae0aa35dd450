"""Telling local senders apart on loopback (docs/security.md, "Telling local users apart"):
the socket-table lookup (swarmd.senderuid), the cores' decisions by it, and the attacks by
real processes of another user.

The attacker is the ``nobody`` user (uid 65534), run with ``setpriv``; the "node" and the
"PX4" are this test's own process (root): the configured user. No timing assertion: the
real-socket waits have caps, and what is asserted is counted.
"""

from __future__ import annotations

import asyncio
import os
import shutil
import socket
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
from swarmd_lab.pktinfo import nobody_spoofs

from swarmd.bundle.build import build_dev_bundle
from swarmd.bundle.mission import parse_mission
from swarmd.bundle.model import Bundle
from swarmd.bundle.ros2 import Ros2Participant, bundle_ros2_participants
from swarmd.cli.status_cmd import render_ros2
from swarmd.config import DaemonConfig, Ros2Section
from swarmd.px4.xrce_backend import XrceBackend
from swarmd.ros2.relay import LOOPBACK, Ros2Relay
from swarmd.ros2app import Ros2App
from swarmd.rtps.locator import Locator
from swarmd.rtps.spdp import SpdpParticipant, encode_spdp
from swarmd.rtps.types import Duration, GuidPrefix, VendorId
from swarmd.senderuid import MISS_READ_BURST, MISS_READS_PER_S, TTL_S, SenderUids
from swarmd.xrce.agent import XrceAgent
from swarmd.xrce.message import CreateClient, Header, encode_message
from tests.xrce_vehicle import XrceVehicle

REPO = Path(__file__).resolve().parent.parent
MISSION = (REPO / "firmware_bundle" / "missions" / "swarm3-ros2.yaml").read_text()
NOBODY = 65534
ME = os.geteuid()
KEY = 0x0BAD_CAFE
HEAD = "  sl  local_address rem_address   st tx_queue rx_queue tr tm->when retrnsmt   uid  timeout inode ref pointer drops\n"  # noqa: E501
needs_setpriv = pytest.mark.skipif(
    os.geteuid() != 0 or shutil.which("setpriv") is None, reason="needs root and setpriv"
)


# ---- the lookup, on a recorded table -----------------------------------------------------


def _v4(address: str, port: int, uid: int) -> str:
    word = socket.inet_aton(address)
    if sys.byteorder == "little":
        word = word[::-1]
    return f"   1: {word.hex().upper()}:{port:04X} 00000000:0000 07 00000000:00000000 00:00000000 00000000 {uid:5d}        0 1 2 0 0\n"  # noqa: E501


def _v6(address: str, port: int, uid: int) -> str:
    raw = socket.inet_pton(socket.AF_INET6, address)
    if sys.byteorder == "little":
        raw = b"".join(raw[i : i + 4][::-1] for i in range(0, 16, 4))
    return f"   1: {raw.hex().upper()}:{port:04X} {'0' * 32}:0000 07 00000000:00000000 00:00000000 00000000 {uid:5d}        0 1 2 0 0\n"  # noqa: E501


class _Clock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def _proc(tmp_path: Path, udp: str, udp6: str = "") -> Path:
    (tmp_path / "net").mkdir(exist_ok=True)
    (tmp_path / "net" / "udp").write_text(HEAD + udp)
    (tmp_path / "net" / "udp6").write_text(HEAD + udp6)
    return tmp_path


def test_the_lookup_names_the_owner_of_a_loopback_sources_socket(tmp_path: Path) -> None:
    proc = _proc(
        tmp_path,
        _v4("127.0.0.1", 540, 1001) + _v4("0.0.0.0", 541, 1002) + _v4("10.0.0.5", 542, 1003)
        + "   9: garbage line\n" + _v4("127.0.0.2", 543, 1004),
        _v6("::1", 7400, 1005) + _v6("::", 544, 1006) + _v6("::ffff:127.0.0.1", 545, 1007),
    )  # fmt: skip
    uids = SenderUids(proc, _Clock())
    assert uids.uid_of(("127.0.0.1", 540)) == 1001
    assert uids.uid_of(("127.0.0.9", 541)) == 1002  # a wildcard socket sends from any address
    # bound to 10.0.0.5, it sends as 127.0.0.1:542 by IP_PKTINFO (swarmd.senderuid): its own
    assert uids.uid_of(("127.0.0.1", 542)) == 1003
    assert uids.uid_of(("127.0.0.1", 543)) == 1004  # bound to 127.0.0.2: IP_PKTINFO too
    assert uids.uid_of(("127.0.0.2", 543)) == 1004
    assert uids.uid_of(("::1", 7400, 0, 0)) == 1005  # an IPv6 socket's 4-tuple source
    assert uids.uid_of(("::1", 544)) == 1006
    assert uids.uid_of(("127.0.0.1", 544)) == 1006  # a dual-stack wildcard sends IPv4 too
    assert uids.uid_of(("::ffff:127.0.0.1", 545)) == 1007
    assert uids.uid_of(("127.0.0.1", 545)) == 1007
    # not loopback: not ours to tell (the cores decide by origin)
    assert uids.uid_of(("10.0.0.5", 542)) is None
    assert uids.uid_of("serial") is None
    assert uids.counters["reads"] >= 1


def test_a_port_two_users_hold_is_nobodys(tmp_path: Path) -> None:
    """Two uids co-bound with SO_REUSEADDR: the sender cannot be told; the same uid twice
    (SO_REUSEPORT) is that uid."""
    proc = _proc(
        tmp_path,
        _v4("127.0.0.1", 600, 1001) + _v4("0.0.0.0", 600, 1002)
        + _v4("127.0.0.1", 601, 1001) + _v4("127.0.0.1", 601, 1001),
    )  # fmt: skip
    uids = SenderUids(proc, _Clock())
    assert uids.uid_of(("127.0.0.1", 600)) is None
    assert uids.counters["ambiguous"] == 1
    assert uids.uid_of(("127.0.0.1", 601)) == 1001


def test_reads_are_reused_for_the_ttl_and_a_miss_rereads_at_most_once_per_interval(
    tmp_path: Path,
) -> None:
    clock = _Clock()
    proc = _proc(tmp_path, _v4("127.0.0.1", 700, 1001))
    uids = SenderUids(proc, clock)
    assert uids.uid_of(("127.0.0.1", 700)) == 1001
    assert uids.counters["reads"] == 1
    # the port changes hands: the old owner is named until the read is TTL_S old
    _proc(tmp_path, _v4("127.0.0.1", 700, 1002) + _v4("127.0.0.1", 701, 1003))
    clock.now += TTL_S / 2
    assert uids.uid_of(("127.0.0.1", 700)) == 1001
    # a miss re-reads (the sender bound its port after the last read)...
    assert uids.uid_of(("127.0.0.1", 701)) == 1003
    assert uids.counters["reads"] == 2
    # ... but a flood of misses re-reads within a budget: its burst, then its rate
    for i in range(1000):
        clock.now += 0.001
        assert uids.uid_of(("127.0.0.1", 2000 + i)) is None
    assert uids.counters["not_found"] == 1000
    reads = uids.counters["reads"] - 2
    assert reads <= MISS_READ_BURST + MISS_READS_PER_S * 1.0 + 1, reads
    assert uids.counters["miss_reads_over_budget"] > 0
    clock.now += TTL_S
    assert uids.uid_of(("127.0.0.1", 700)) == 1002


def test_no_table_names_nobody(tmp_path: Path) -> None:
    uids = SenderUids(tmp_path, _Clock())
    assert uids.uid_of(("127.0.0.1", 700)) is None
    assert uids.counters["unreadable"] == 2


def test_the_lookup_on_this_computers_own_table() -> None:
    """A socket of ours is our uid; once closed, its port is nobody's."""
    sock = socket.socket(socket.AF_INET6, socket.SOCK_DGRAM)
    sock.bind(("::1", 0))
    port = sock.getsockname()[1]
    uids = SenderUids()
    assert uids.uid_of(("::1", port, 0, 0)) == ME
    sock.close()
    fresh = SenderUids()
    assert fresh.uid_of(("::1", port, 0, 0)) is None


# ---- the cores' decisions, on hand-set time -----------------------------------------------


def _participants() -> tuple[Ros2Participant, ...]:
    return bundle_ros2_participants(_bundle())


def _bundle() -> Bundle:
    return build_dev_bundle(parse_mission(MISSION)).bundle


def _lead_node() -> Ros2Participant:
    return next(p for p in _participants() if p.drone == "lead")


def _node_spdp(p: Ros2Participant, sn: int = 1) -> bytes:
    """A declared node's DATA(p): what its process, or anyone who read the bundle, sends."""
    return encode_spdp(
        SpdpParticipant(
            GuidPrefix(p.guid_prefix),
            lease_duration=Duration.from_seconds(100.0),
            vendor_id=VendorId(b"\x01\x0f"),
            metatraffic_unicast_locators=(Locator.udpv6(LOOPBACK, p.metatraffic_port),),
            default_unicast_locators=(Locator.udpv4("10.42.0.10", p.user_port),),
            builtin_endpoints=0xFC03,
            entity_name="/",
        ),
        sequence_number=sn,
        timestamp=None,
    )


def _relay(node_uids: frozenset[int] | None) -> Ros2Relay:
    return Ros2Relay(_participants(), "lead", domain_id=0, lease_s=8.0, node_uids=node_uids)


@pytest.mark.parametrize("sender_uid", [NOBODY, None], ids=["other_user", "socket_gone"])
def test_the_relay_drops_a_declared_nodes_prefix_from_another_user(sender_uid: int | None) -> None:
    relay = _relay(frozenset({1000}))
    relay.peer_discovered("drone-1", "10.42.0.11", 0.0)
    relay.datagrams_to_send()
    while relay.next_event() is not None:
        pass
    before = relay.liveness()
    relay.receive_datagram(_node_spdp(_lead_node()), ("::1", 40000, 0, 0), 1.0, sender_uid)
    assert relay.datagrams_to_send() == [] and relay.next_event() is None
    assert relay.counters["rx_foreign_user"] == 1
    assert relay.liveness() == before
    assert relay.status(1.0)["local"][0]["state"] == "not heard"
    # the node's own user: heard, answered
    relay.receive_datagram(_node_spdp(_lead_node()), ("::1", 40001, 0, 0), 1.5, 1000)
    assert relay.status(1.5)["local"][0]["state"] == "heard"
    assert relay.counters["tx_start_answers"] == 1 and relay.datagrams_to_send()


def test_without_node_users_every_local_sender_is_taken() -> None:
    """Today's behaviour when ``ros2.node_users`` is absent (documented)."""
    relay = _relay(None)
    relay.receive_datagram(_node_spdp(_lead_node()), ("::1", 40000, 0, 0), 1.0, NOBODY)
    assert relay.status(1.0)["local"][0]["state"] == "heard"
    assert relay.counters["rx_foreign_user"] == 0


def _create_client(key: int) -> bytes:
    return encode_message(Header(0x80, 0, 0), [CreateClient(key.to_bytes(4, "big"), 0x81)])


def test_the_agent_drops_every_loopback_datagram_of_another_user_unread() -> None:
    agent = XrceAgent(expected_key=KEY.to_bytes(4, "big"), vehicle_uid=1000)
    for port in range(100):
        agent.receive_datagram(_create_client(KEY), ("127.0.0.1", 40000 + port), 0.0, NOBODY)
        agent.receive_datagram(_create_client(KEY), ("::1", 41000 + port, 0, 0), 0.0, None)
    assert agent.datagrams_to_send() == [] and not agent.sessions
    assert agent.dropped["foreign_user"] == 200
    assert agent.key_checks.checks == 0  # no key compared, no budget spent
    # another host (an FMU on Ethernet) is no loopback user: untouched
    agent.receive_datagram(_create_client(KEY), ("10.41.10.2", 35000), 0.0, None)
    assert list(agent.sessions) == [("10.41.10.2", 35000)]


def test_the_agent_takes_the_configured_user_from_the_loopback() -> None:
    agent = XrceAgent(expected_key=KEY.to_bytes(4, "big"), vehicle_uid=1000)
    agent.receive_datagram(_create_client(KEY), ("127.0.0.1", 40000), 0.0, 1000)
    assert list(agent.sessions) == [("127.0.0.1", 40000)]
    assert agent.dropped["foreign_user"] == 0


# ---- real processes of another user ----------------------------------------------------

# The attacker's program: ``count`` datagrams (hex argv[3]) to [argv[1]]:argv[2], from
# ``ports`` sockets in turn; "ready" after the first round; ``close``: each socket closed right
# after its send. Bounded in count and time.
ATTACKER = """
import socket, sys, time
host, port, data = sys.argv[1], int(sys.argv[2]), bytes.fromhex(sys.argv[3])
count, ports, close = int(sys.argv[4]), int(sys.argv[5]), sys.argv[6] == "1"
family = socket.AF_INET6 if ":" in host else socket.AF_INET
socks = [] if close else [socket.socket(family, socket.SOCK_DGRAM) for _ in range(ports)]
for s in socks:
    s.setblocking(False)
deadline = time.monotonic() + 20.0
for i in range(count):
    if time.monotonic() > deadline:
        break
    s = socket.socket(family, socket.SOCK_DGRAM) if close else socks[i % ports]
    try:
        s.sendto(data, (host, port))
    except (BlockingIOError, ConnectionRefusedError):
        pass
    if close:
        s.close()
    if i == ports - 1 or (close and i == 0):
        print("ready", flush=True)
    if i % 200 == 199:
        time.sleep(0.01)
print("done", flush=True)
"""


def _attacker(
    host: str, port: int, data: bytes, *, count: int, ports: int = 1, close: bool = False
) -> subprocess.Popen[str]:
    return subprocess.Popen(  # noqa: S603 - fixed argv
        [
            "setpriv", f"--reuid={NOBODY}", f"--regid={NOBODY}", "--clear-groups",  # noqa: S607
            sys.executable, "-I", "-c", ATTACKER,
            host, str(port), data.hex(), str(count), str(ports), "1" if close else "0",
        ],
        stdout=subprocess.PIPE, text=True,
    )  # fmt: skip


class _Log:
    def __init__(self) -> None:
        self.lines: list[tuple[str, dict[str, Any]]] = []

    def info(self, event: str, **fields: Any) -> None:
        self.lines.append((event, fields))

    warning = error = exception = info


def _free_port(family: socket.AddressFamily, host: str) -> int:
    with socket.socket(family, socket.SOCK_DGRAM) as s:
        s.bind((host, 0))
        return int(s.getsockname()[1])


def _ros2_app(node_users: frozenset[int] | None, log: _Log, alive: list[bytes]) -> Ros2App:
    config = DaemonConfig(
        file="swarmd.yaml",
        node="lead",
        interface="lo",
        ros2=Ros2Section(
            relay=True,
            relay_port=_free_port(socket.AF_INET6, "::1"),
            lease_s=8.0,
            node_users=node_users,
        ),
    )
    return Ros2App(
        config, _bundle(), epoch=1, log=log, count=lambda _c: None, on_liveness=alive.append
    )


async def _until(cond: Any, cap_s: float = 10.0) -> bool:
    loop = asyncio.get_running_loop()
    start = loop.time()
    while not cond():
        if loop.time() - start > cap_s:
            return False
        await asyncio.sleep(0.02)
    return True


@needs_setpriv
@pytest.mark.parametrize("close", [False, True], ids=["keeps_socket", "closes_socket"])
def test_another_user_announcing_a_declared_node_is_dropped_and_nothing_moves(close: bool) -> None:
    """(a) and (c): ``nobody`` sends the lead drone's declared node's DATA(p) (its prefix is
    in the bundle) to the relay, from a socket it keeps or closes right after sending: the
    relay counts it, the node stays "not heard", no start answer goes out, the liveness word
    (signed to the other drones) does not move. Then the node's own user is heard."""

    async def main() -> tuple[dict[str, Any], list[bytes], dict[str, Any], list[Any]]:
        log, alive = _Log(), list[bytes]()
        app = _ros2_app(frozenset({ME}), log, alive)
        app.start(asyncio.get_running_loop())
        try:
            app.peer_up("drone-1", "10.42.0.11")  # something the relay would answer with
            attacker = _attacker("::1", app.config.ros2.relay_port, _node_spdp(_lead_node()),
                                 count=20, close=close)  # fmt: skip
            assert attacker.stdout is not None
            out, _ = await asyncio.to_thread(attacker.communicate, None, 30)
            assert "done" in out
            await _until(lambda: app.relay.counters["rx"] >= 20)
            attacked = app.status(0.0)
            attacked_alive = list(alive)
            # the node's own user, from a socket it keeps, resending as Fast DDS does (its
            # initial announcements, 100 ms apart; a first one can meet a spent lookup
            # budget, swarmd.senderuid): heard
            with socket.socket(socket.AF_INET6, socket.SOCK_DGRAM) as mine:
                mine.bind(("::1", 0))
                for sn in range(1, 11):
                    mine.sendto(_node_spdp(_lead_node(), sn), ("::1", app.config.ros2.relay_port))
                    if await _until(lambda: app.relay.counters["tx_start_answers"] > 0, 0.1):
                        break
            return attacked, attacked_alive, app.status(0.0), log.lines
        finally:
            app.close()

    attacked, alive, after, lines = asyncio.run(main())
    counters = attacked["counters"]
    assert counters["rx"] == 20 and counters["rx_foreign_user"] == 20, counters
    assert counters["tx_start_answers"] == 0
    assert attacked["local"][0]["state"] == "not heard" and alive == []
    assert after["local"][0]["state"] == "heard" and after["counters"]["tx_start_answers"] >= 1
    assert not any(event == "ros2_local_users_not_told_apart" for event, _ in lines)


@needs_setpriv
def test_a_nodes_port_another_user_holds_too_is_counted_in_the_relays_status() -> None:
    """``nobody`` binds the node's port at another address (``[2001:db8::7]:P``, IPV6_FREEBIND)
    and keeps it, after one datagram sent as the node by ``IPV6_PKTINFO``: the spoof and the
    node's own DATA(p) are both dropped (the port is two uids'), and the status says why
    beside ``rx_foreign_user``: ``sender_port_shared`` (as PX4's backend does), the
    ``sender_port_shared`` warning logged. On main the relay's status had no such count."""

    async def main() -> tuple[dict[str, Any], list[Any], int]:
        log = _Log()
        app = _ros2_app(frozenset({ME}), log, [])
        app.start(asyncio.get_running_loop())
        relay_at = ("::1", app.config.ros2.relay_port)
        try:
            with socket.socket(socket.AF_INET6, socket.SOCK_DGRAM) as node:
                node.bind(("::1", 0))
                port = node.getsockname()[1]
                holder = nobody_spoofs("2001:db8::7", port, relay_at, "::1", hold=True)
                try:
                    assert holder.stdout is not None
                    sent = await asyncio.to_thread(holder.stdout.readline)
                    assert sent == "sent\n"  # its socket open until stdin closes
                    node.sendto(_node_spdp(_lead_node()), relay_at)
                    await _until(lambda: app.relay.counters["rx"] >= 2)
                    return app.status(0.0), log.lines, port
                finally:
                    await asyncio.to_thread(holder.communicate, None, 10)
        finally:
            app.close()

    status, lines, port = asyncio.run(main())
    counters = status["counters"]
    assert counters["rx"] == 2 and counters["rx_foreign_user"] == 2, counters
    assert counters["sender_port_shared"] == 2  # the spoof and the node's own
    assert status["local"][0]["state"] == "not heard"
    shared = [fields for event, fields in lines if event == "sender_port_shared"]
    assert [(f["port"], f["taken_uids"], f["other_uids"]) for f in shared] == [
        (port, [ME], [NOBODY])
    ]


def test_the_status_view_names_the_relays_refusals_of_other_users() -> None:
    """The human ``swarmctl status`` line of the relay carries both counts when any."""
    counters = {"rx_foreign_user": 3, "sender_port_shared": 2}
    view = "\n".join(render_ros2({"relay": "::1:7399", "counters": counters}))
    assert "dropped 3 datagrams of other local users (2 from a node's port" in view
    quiet = "\n".join(render_ros2({"relay": "::1:7399", "counters": {"rx_foreign_user": 0}}))
    assert "dropped" not in quiet


@needs_setpriv
def test_without_node_users_the_relay_says_so_and_takes_another_users_datagram() -> None:
    """Absent ``ros2.node_users``: today's behaviour, and one start-up line saying so."""

    async def main() -> tuple[dict[str, Any], list[Any]]:
        log: _Log = _Log()
        app = _ros2_app(None, log, [])
        app.start(asyncio.get_running_loop())
        try:
            attacker = _attacker("::1", app.config.ros2.relay_port, _node_spdp(_lead_node()),
                                 count=1)  # fmt: skip
            await asyncio.to_thread(attacker.communicate, None, 30)
            await _until(lambda: app.relay.counters["rx"] >= 1)
            return app.status(0.0), log.lines
        finally:
            app.close()

    status, lines = asyncio.run(main())
    assert status["local"][0]["state"] == "heard"
    assert [e for e, _ in lines].count("ros2_local_users_not_told_apart") == 1


FLOOD_PORTS = 256
FLOOD_COUNT = 200_000
WAIT_S = 30.0


@needs_setpriv
def test_a_flood_from_every_loopback_port_of_another_user_leaves_sitl_px4_its_session() -> None:
    """(b) ``nobody`` floods CREATE_CLIENTs of the right key's neighbours from 256 loopback
    ports (the shape that, unconfigured, keeps a loopback PX4 out while it lasts:
    tests/test_xrce_key_guess.py); PX4 SITL of the configured user connects mid-flood and gets
    its session; the flood is dropped unread, no key of it checked."""
    flood = encode_message(Header(0x80, 0, 0), [CreateClient((KEY + 1).to_bytes(4, "big"), 0x81)])

    async def main() -> dict[str, Any]:
        port = _free_port(socket.AF_INET, "127.0.0.1")
        log = _Log()
        backend = XrceBackend(
            "xrce-agent", f"udp:127.0.0.1:{port}", expected_key=KEY, loopback_user=ME, log=log
        )
        await backend.start(lambda _obs, _now: None)
        attacker = _attacker("127.0.0.1", port, flood, count=FLOOD_COUNT, ports=FLOOD_PORTS)
        vehicle = XrceVehicle(KEY, 1, ("127.0.0.1", port))
        loop = asyncio.get_running_loop()
        try:
            assert attacker.stdout is not None
            ready = await asyncio.to_thread(attacker.stdout.readline)
            assert ready.strip() == "ready"
            await _until(lambda: backend.stats()["dropped"].get("foreign_user", 0) >= 1000)
            await vehicle.start()
            started = loop.time()
            await _until(lambda: backend.session == "established", WAIT_S)
            return {
                "stats": backend.stats(),
                "flooding": attacker.poll() is None,
                "after_s": loop.time() - started,
                "vehicle": vehicle.engine.state,
                "lines": log.lines,
            }
        finally:
            vehicle.kill()
            attacker.kill()
            await asyncio.to_thread(attacker.communicate, None, 30)
            await backend.close()

    result = asyncio.run(main())
    stats = result["stats"]
    assert result["vehicle"] == "established" and stats["session"] == "established", stats
    assert result["flooding"], stats  # the flood still ran when PX4 got in
    assert stats["dropped"]["foreign_user"] >= 1000
    assert stats["refused"].get("over_budget", 0) == 0 and stats["refused"].get("wrong_key", 0) == 0
    assert stats["key_checks"] in (1, 2, 3)  # PX4's own tries only
    assert not any(event == "xrce_local_users_not_told_apart" for event, _ in result["lines"])
