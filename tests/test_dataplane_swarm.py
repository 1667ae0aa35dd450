"""A commander and ten members on a lossy in-process network, on virtual time.

The network (the lab's ``MemNet``, the one in-memory network every core's tests use) drops,
duplicates and delays every datagram independently with a seeded ``random.Random``;
independent delays reorder. Nothing here sleeps: the loop jumps to
the next datagram arrival, timer or application tick.
"""

from __future__ import annotations

import json
import random
from collections import Counter
from collections.abc import Callable

import pytest
from swarmd_lab.memnet import Channel, MemNet

from swarmd.auth.keys import KeyRing, NodeSecrets
from swarmd.bundle.build import build_dev_bundle
from swarmd.bundle.mission import parse_mission
from swarmd.bundle.model import Bundle, Role
from swarmd.dataplane import (
    TOPIC_COMMAND,
    TOPIC_READY,
    Command,
    CommandKind,
    CommandReceived,
    CommandResult,
    DataPlane,
    ForeignCommandId,
    OutcomeReceived,
    PacketDropped,
    Readiness,
    ReadinessReceived,
)
from swarmd.dataplane.ledger import KeptOutcome
from swarmd.dataplane.seal import AUTH_SUBMESSAGE_ID, protected_part, user_data_key, verify
from swarmd.rtps import AckNack, Data, Gap, Heartbeat, InfoDst, SkippedSubmessage, decode_message
from swarmd.rtps.types import VENDORID_SWARMD

Address = tuple[str, int]
Tick = tuple[float, Callable[[], object]]
MIN_DELAY_S = 0.001  # every datagram takes at least this long (plus up to max_delay_s)


def mission_text(members: int, command_depth: int = 8) -> str:
    lines = ["swarm: dp-test", "domain_id: 0", "participants:"]
    lines += ["  - {name: lead, index: 0, role: commander, mavlink_sysid: 1}"]
    for i in range(1, members + 1):
        lines += [f"  - {{name: m{i:02d}, index: {i}, role: member, mavlink_sysid: {i + 1}}}"]
    lines += [
        "topics:",
        "  - {name: swarm/ready, type: 'swarmd::Readiness', reliability: best_effort,",
        "     history_depth: 1, writers: member, readers: commander}",
        "  - {name: swarm/command, type: 'swarmd::Command', reliability: reliable,",
        f"     history_depth: {command_depth}, writers: commander, readers: member}}",
        "  - {name: swarm/outcome, type: 'swarmd::CommandOutcome', reliability: reliable,",
        "     history_depth: 16, writers: member, readers: commander}",
    ]
    return "\n".join(lines) + "\n"


def make_bundle(members: int, command_depth: int = 8) -> Bundle:
    return build_dev_bundle(parse_mission(mission_text(members, command_depth))).bundle


def address_of(bundle: Bundle, name: str) -> Address:
    p = bundle.participant(name)
    return (f"10.0.0.{p.index + 1}", bundle.user_port(p))


def keyring(bundle: Bundle, name: str) -> KeyRing:
    """``name``'s key ring as its daemon builds it (a dev bundle's derivable node keys)."""
    return KeyRing.from_bundle(bundle, name, NodeSecrets.dev(bundle.swarm, name))


def make_plane(
    bundle: Bundle,
    name: str,
    *,
    epoch: int = 1,
    incarnation: int = 0,
    executed_command_ids: list[tuple[str, int]] | tuple[()] = (),
    executed_outcomes: list[KeptOutcome] | tuple[()] = (),
) -> DataPlane:
    return DataPlane(
        bundle,
        name,
        keys=keyring(bundle, name),
        epoch=epoch,
        incarnation=incarnation,
        executed_command_ids=executed_command_ids,
        executed_outcomes=executed_outcomes,
    )


class Swarm:
    """Every node's DataPlane on the one in-memory network (``MemNet``), its address and
    what its application saw."""

    def __init__(
        self,
        bundle: Bundle,
        planes: dict[str, DataPlane],
        *,
        seed: int = 1,
        drop: float = 0.0,
        duplicate: float = 0.0,
        max_delay_s: float = 0.001,
    ) -> None:
        self.bundle = bundle
        self.planes = planes
        channel = Channel(drop, duplicate, MIN_DELAY_S, max(0.0, max_delay_s - MIN_DELAY_S))
        self.net = MemNet(random.Random(seed), channel)  # noqa: S311 - seeded on purpose
        self.net.on_event = self._on_event
        self.ids: dict[str, int] = {}
        self.executed: Counter[tuple[str, int]] = Counter()  # (member, id)
        self.executed_at: dict[tuple[str, int], float] = {}  # first execution
        self.outcomes: dict[tuple[str, int], list[CommandResult]] = {}
        self.readiness: dict[str, list[tuple[float, int, int]]] = {}
        self.drops: Counter[str] = Counter()
        self.epochs: dict[str, int] = {}  # each node's boot epoch
        for name, plane in planes.items():
            host, port = address_of(bundle, name)
            self.ids[name] = len(self.net)
            self.net.add(plane, host, [port])

    @property
    def now(self) -> float:
        return self.net.now

    @property
    def members(self) -> list[str]:
        return [p.name for p in self.bundle.participants if p.role == Role.MEMBER]

    def flush(self, name: str) -> None:
        """Drive ``name``'s plane after the test called into it."""
        self.net.poke(self.ids[name])

    def _on_event(self, node_id: int, event: object, now: float) -> None:
        self.handle(next(n for n, i in self.ids.items() if i == node_id), event)

    def handle(self, name: str, event: object) -> None:
        match event:
            case CommandReceived(command=cmd):
                self.executed[(name, cmd.command_id)] += 1
                self.executed_at.setdefault((name, cmd.command_id), self.now)
                plane = self.planes[name]
                plane.report_outcome(cmd.command_id, CommandResult.ACCEPTED, self.now)
                plane.report_outcome(cmd.command_id, CommandResult.COMPLETED, self.now, "ok")
            case OutcomeReceived(node=node, outcome=o):
                self.outcomes.setdefault((node, o.command_id), []).append(o.result)
            case ReadinessReceived(node=node, sample=s, count=count):
                self.readiness.setdefault(node, []).append((self.now, s.seq, count))
            case PacketDropped(reason=reason):
                self.drops[reason] += 1
            case _:
                raise AssertionError(f"unexpected event {event!r}")

    def run_until(self, end: float, ticks: list[Tick] | None = None) -> None:
        """Advance virtual time to ``end``, delivering datagrams, timers and app ticks (an
        app tick drives every plane afterwards, as the daemon's ``Driver.call`` would)."""
        for at, action in sorted(ticks or [], key=lambda t: t[0]):

            def tick(now: float, action: Callable[[], object] = action) -> None:
                action()
                for node_id in self.ids.values():
                    self.net.poke(node_id)

            self.net.call_at(at, tick)
        self.net.run_until(end)

    def name_at(self, address: Address) -> str:
        for p in self.bundle.participants:
            if address_of(self.bundle, p.name) == address:
                return p.name
        raise AssertionError(f"no node at {address}")

    def up(self, at: str, peer: str) -> None:
        """``at``'s discovery reports ``peer`` with its current epoch (authenticated SPDP)."""
        self.planes[at].peer_up(
            peer, address_of(self.bundle, peer), self.now, epoch=self.epochs.get(peer, 1)
        )

    def restart(self, name: str, **kwargs: object) -> DataPlane:
        """``name``'s process restarts: a new plane in the next epoch; nobody knows yet."""
        self.epochs[name] = self.epochs.get(name, 1) + 1
        plane = make_plane(self.bundle, name, epoch=self.epochs[name], **kwargs)  # type: ignore[arg-type]
        self.planes[name] = plane
        self.net.replace(self.ids[name], plane)
        return plane

    def cut(self, name: str, cut: bool = True) -> None:
        """Nothing reaches ``name`` (its own datagrams still leave) until ``cut(name, False)``."""
        target = self.ids[name]
        loss = self.net.channel.loss
        self.net.link_loss = (lambda s, d: 1.0 if d == target else loss) if cut else None

    def discover_all(self) -> None:
        for a in self.planes:
            for b in self.planes:
                if a != b:
                    self.up(a, b)


def make_swarm(
    members: int = 10,
    *,
    seed: int = 1,
    drop: float = 0.0,
    duplicate: float = 0.0,
    max_delay_s: float = 0.001,
    command_depth: int = 8,
) -> Swarm:
    bundle = make_bundle(members, command_depth)
    planes = {p.name: make_plane(bundle, p.name) for p in bundle.participants}
    return Swarm(bundle, planes, seed=seed, drop=drop, duplicate=duplicate, max_delay_s=max_delay_s)


def readiness_ticks(swarm: Swarm, start: float, seconds: int) -> list[Tick]:
    """Every member publishes readiness at 1 Hz, staggered by 10 ms per member."""
    ticks: list[Tick] = []
    for k, member in enumerate(swarm.members):
        for seq in range(1, seconds + 1):
            sample = Readiness(member, seq, True, "", False, 1, 3, 14, 87, 800)

            def publish(m: str = member, s: Readiness = sample) -> None:
                swarm.planes[m].publish_readiness(s, swarm.now)

            ticks.append((start + (seq - 1) + 0.01 * k, publish))
    return ticks


def send_at(swarm: Swarm, at: float, command: Command, by: str = "lead") -> Tick:
    """An application tick: ``by`` sends ``command`` at virtual time ``at``."""
    return (at, lambda: swarm.planes[by].send_command(command, swarm.now))


# --- exactly once under loss --------------------------------------------------------------


@pytest.mark.parametrize("seed", [1, 2, 3, 4, 5])
def test_every_member_executes_every_command_exactly_once_under_30_percent_loss(
    seed: int,
) -> None:
    swarm = make_swarm(10, seed=seed, drop=0.3, duplicate=0.1, max_delay_s=0.08)
    swarm.discover_all()
    lead = swarm.planes["lead"]
    kinds = [CommandKind.TAKEOFF, CommandKind.HOLD, CommandKind.LAND, CommandKind.ABORT]
    commands = [
        lead.make_command(k, altitude_m=12.5 if k == CommandKind.TAKEOFF else 0.0) for k in kinds
    ]
    ticks = [send_at(swarm, 1.0 + 0.05 * i, c) for i, c in enumerate(commands)]
    # the operator retries the take-off with the same id: members must not run it twice
    ticks.append(send_at(swarm, 2.0, commands[0]))
    swarm.run_until(60.0, ticks)

    ids = [c.command_id for c in commands]
    assert len(set(ids)) == len(ids)
    assert swarm.executed == Counter({(m, i): 1 for m in swarm.members for i in ids})
    for m in swarm.members:
        for i in ids:
            assert swarm.outcomes[(m, i)] == [CommandResult.ACCEPTED, CommandResult.COMPLETED]
    # the network really was hostile, and the protocol really repaired and deduplicated
    stats = swarm.net.stats
    assert 0.25 < stats.lost / stats.sent < 0.35
    assert stats.duplicated > 0 and stats.reordered > 0
    member_counters = sum((swarm.planes[m].counters for m in swarm.members), Counter[str]())
    assert member_counters["command_duplicate"] > 0  # the retried take-off at least
    status = lead.status(swarm.now)
    assert status["writers"][TOPIC_COMMAND]["data_resent"] > 0
    # once everything is acknowledged nothing is pending: the writer falls silent
    assert lead.get_timer() is None
    assert all(swarm.planes[m].get_timer() is None for m in swarm.members)


def test_commands_reach_members_that_discover_the_commander_late() -> None:
    """Discovery is asymmetric: a member may drop DATA from a commander it has not yet
    discovered; the commander's heartbeats repair it once the member has."""
    swarm = make_swarm(4, seed=7, drop=0.3, max_delay_s=0.02)
    lead = swarm.planes["lead"]
    for m in swarm.members:
        swarm.up("lead", m)
    cmd = lead.make_command(CommandKind.TAKEOFF, altitude_m=5.0)
    ticks: list[Tick] = [send_at(swarm, 0.5, cmd)]
    for k, m in enumerate(swarm.members):

        def up(m: str = m) -> None:
            swarm.up(m, "lead")

        ticks.append((1.0 + k, up))
    swarm.run_until(30.0, ticks)
    assert swarm.drops["peer_not_up"] > 0
    assert swarm.executed == Counter({(m, cmd.command_id): 1 for m in swarm.members})


def test_commander_restart_with_new_incarnation_keeps_exactly_once() -> None:
    swarm = make_swarm(5, seed=11, drop=0.3, duplicate=0.1, max_delay_s=0.05)
    swarm.discover_all()
    old = swarm.planes["lead"]
    first = old.make_command(CommandKind.TAKEOFF, altitude_m=8.0)
    swarm.run_until(20.0, [(1.0, lambda: old.send_command(first, swarm.now))])
    assert all(swarm.executed[(m, first.command_id)] == 1 for m in swarm.members)

    # The commander restarts (same GUIDs, from the bundle) faster than any lease expires:
    # the members never see peer_down, only its new epoch in its SPDP. Its new life tries
    # to resend the last command it had on record (refused at the sender: not of this life,
    # tests/test_cmd_id_of_life.py), then issues a new one.
    new = swarm.restart("lead", incarnation=1)
    for m in swarm.members:
        swarm.up("lead", m)
        swarm.up(m, "lead")
    with pytest.raises(ForeignCommandId):
        new.send_command(first, swarm.now)
    second = new.make_command(CommandKind.LAND)
    # ids carry the boot epoch (2 now), not the boot counter, which a lost state file resets
    assert second.command_id >> 32 == new.epoch == 2 and second.command_id != first.command_id
    swarm.run_until(60.0, [(21.5, lambda: new.send_command(second, swarm.now))])
    expected = {(m, c.command_id): 1 for m in swarm.members for c in (first, second)}
    assert swarm.executed == Counter(expected)
    assert new.status(swarm.now)["writers"][TOPIC_COMMAND]["last_sn"] == (1 << 32) + 1


def test_member_side_proxy_reset_redelivers_but_does_not_reexecute() -> None:
    """peer_down/peer_up on a member resets its reader state; the commander, which noticed
    nothing, repairs from its history: SN-level dedup is gone, the id set still holds."""
    swarm = make_swarm(3, seed=5)
    swarm.discover_all()
    lead = swarm.planes["lead"]
    cmd = lead.make_command(CommandKind.HOLD)
    swarm.run_until(5.0, [send_at(swarm, 1.0, cmd)])
    member = swarm.members[0]
    plane = swarm.planes[member]
    plane.peer_down("lead", swarm.now)
    swarm.up(member, "lead")
    # the next command makes the commander heartbeat from the start of its history
    nxt = lead.make_command(CommandKind.LAND)
    swarm.run_until(20.0, [send_at(swarm, 6.0, nxt)])
    assert swarm.executed[(member, cmd.command_id)] == 1
    assert swarm.executed[(member, nxt.command_id)] == 1
    assert plane.counters["command_duplicate"] >= 1


@pytest.mark.parametrize("persisted", [True, False])
def test_executed_ids_survive_a_member_restart_only_when_persisted(persisted: bool) -> None:
    """A member process restart loses its reader state and comes back in a new epoch. The
    commander learns the epoch from its SPDP and restarts its proxy for the member
    (volatile), so its history is not replayed; a resend of the same id by the operator
    runs again unless the persisted id set holds it (docs/dataplane.md, "Member restarts")."""
    swarm = make_swarm(2, seed=3)
    swarm.discover_all()
    lead = swarm.planes["lead"]
    cmd = lead.make_command(CommandKind.TAKEOFF, altitude_m=3.0)
    swarm.run_until(5.0, [send_at(swarm, 1.0, cmd)])
    member = swarm.members[0]
    saved = swarm.planes[member].executed_command_ids
    assert saved == [("lead", cmd.command_id)]
    reborn = swarm.restart(member, incarnation=1, executed_command_ids=saved if persisted else ())
    swarm.up(member, "lead")
    swarm.up("lead", member)
    assert lead.counters["peer_restarts"] == 1
    swarm.run_until(6.0)
    assert swarm.executed[(member, cmd.command_id)] == 1  # history not replayed
    swarm.run_until(10.0, [send_at(swarm, 6.0, cmd)])
    assert swarm.executed[(member, cmd.command_id)] == (1 if persisted else 2)
    assert reborn.counters["command_duplicate"] == (1 if persisted else 0)


def test_targeted_command_runs_only_on_its_targets() -> None:
    swarm = make_swarm(4, seed=2)
    swarm.discover_all()
    lead = swarm.planes["lead"]
    cmd = lead.make_command(CommandKind.LAND, targets=["m02", "m04"])
    swarm.run_until(5.0, [send_at(swarm, 1.0, cmd)])
    assert swarm.executed == Counter({("m02", cmd.command_id): 1, ("m04", cmd.command_id): 1})
    # one copy per target: the members that are not targets get no copy, only a GAP for
    # the SN, and acknowledge it (nothing left to repair towards them)
    for other in ("m01", "m03"):
        to_other = [
            decode_message(protected_part(t.payload)).submessages
            for t in swarm.net.transmissions
            if t.target == address_of(swarm.bundle, other)
        ]
        kinds = {type(sm) for sms in to_other for sm in sms}
        assert Gap in kinds and Data not in kinds, kinds  # its own readiness is all it sent
        assert swarm.planes[other].counters.get("command_not_targeted", 0) == 0
    status = lead.status(swarm.net.now)["writers"]["swarm/command"]
    assert status["unacked_readers"] == 0 and status["gaps_sent"] >= 2


def test_keep_last_history_gaps_samples_a_slow_member_missed() -> None:
    """More commands than the history holds while one member is cut off: it gets the
    newest ``depth`` and a GAP (or a heartbeat's firstSN) for the rest, never stalls."""
    swarm = make_swarm(2, seed=9, command_depth=2)
    swarm.discover_all()
    lead = swarm.planes["lead"]
    cut = swarm.members[0]
    commands = [lead.make_command(CommandKind.HOLD) for _ in range(5)]
    cut_plane = swarm.planes[cut]
    ticks = [send_at(swarm, 1.0 + 0.1 * i, c) for i, c in enumerate(commands)]
    swarm.net.isolate(swarm.ids[cut])  # unreachable: its datagrams, both ways, are lost
    swarm.run_until(3.0, ticks)
    swarm.net.isolate(swarm.ids[cut], False)
    swarm.run_until(30.0)
    got = [i for (m, i) in swarm.executed if m == cut]
    assert got == [c.command_id for c in commands[-2:]]
    reader = cut_plane.status(swarm.now)["readers"][TOPIC_COMMAND]
    assert reader["skipped"] + reader["gapped"] == 3
    assert lead.get_timer() is None


# --- readiness: the paper's 1 Hz workload ---------------------------------------------------


def test_readiness_20th_message_from_every_member_on_a_clean_channel() -> None:
    swarm = make_swarm(10, seed=1)
    swarm.discover_all()
    swarm.run_until(30.0, readiness_ticks(swarm, start=0.5, seconds=25))
    for m in swarm.members:
        rx = swarm.readiness[m]
        assert [count for _, _, count in rx] == list(range(1, 26))
        t20, seq20, _ = rx[19]
        assert seq20 == 20 and 19.5 <= t20 < 19.7  # sent at 19.5 s + stagger + 1 ms
    status = swarm.planes["lead"].status(swarm.now)
    m03 = swarm.planes["lead"].readiness_received("m03")
    assert m03 is not None and m03.last is not None
    assert m03.count == 25 and m03.last.ready
    assert json.loads(json.dumps(status)) == status  # what swarmctl status prints


@pytest.mark.parametrize("seed", [1, 2])
def test_readiness_under_loss_counts_each_sample_once_and_never_goes_back(seed: int) -> None:
    swarm = make_swarm(10, seed=seed, drop=0.3, duplicate=0.2, max_delay_s=1.5)
    swarm.discover_all()
    swarm.run_until(45.0, readiness_ticks(swarm, start=0.5, seconds=40))
    for m in swarm.members:
        rx = swarm.readiness[m]
        seqs = [seq for _, seq, _ in rx]
        assert seqs == sorted(set(seqs)), "a duplicate or an older sample was delivered"
        assert [c for _, _, c in rx] == list(range(1, len(rx) + 1))
        assert len(rx) >= 20  # 40 sent at 70 %: the 20th arrives
    lead_counters = swarm.planes["lead"].counters
    assert lead_counters["stale_sample"] > 0  # duplicates and late arrivals were filtered
    assert swarm.planes["lead"].get_timer() is None  # best effort: no heartbeats


def test_steady_state_is_one_datagram_per_member_and_period_and_idle_reliable_is_silent() -> None:
    """What the testbed's ``rtps_user`` class holds at steady state (docs/testbed.md, "What
    swarmd's frames are"): each member's readiness is one datagram (DATA + AUTH) to the
    commander per period, and the idle reliable ``swarm/command``/``swarm/outcome`` endpoints
    send nothing (no HEARTBEAT, ACKNACK or GAP). The channel's 18 frames/s at N = 10 are
    these 9 datagrams and the 9 802.11 ACKs answering them."""
    swarm = make_swarm(9, seed=1)
    swarm.discover_all()
    swarm.run_until(25.0, readiness_ticks(swarm, start=0.5, seconds=20))
    lead = address_of(swarm.bundle, "lead")
    per_member: Counter[str] = Counter()
    for payload, source, destination in swarm.net.payloads():
        *body, auth = decode_message(payload).submessages
        assert destination == lead, f"{source} sent to {destination}"
        assert isinstance(auth, SkippedSubmessage) and auth.submessage_id == AUTH_SUBMESSAGE_ID
        assert [type(sm).__name__ for sm in body] == ["Data"]
        per_member[swarm.name_at(source)] += 1
    assert per_member == {m: 20 for m in swarm.members}
    assert all(plane.get_timer() is None for plane in swarm.planes.values())


# --- on the wire ----------------------------------------------------------------------------


def test_datagrams_decode_and_carry_the_bundle_guids() -> None:
    swarm = make_swarm(2, seed=4, drop=0.3)
    swarm.discover_all()
    lead = swarm.planes["lead"]
    cmd = lead.make_command(CommandKind.TAKEOFF, altitude_m=10.0)
    ticks = readiness_ticks(swarm, 0.5, 3) + [send_at(swarm, 1.0, cmd)]
    swarm.run_until(20.0, ticks)
    b = swarm.bundle
    lead_p = b.participant("lead")
    seen: Counter[str] = Counter()
    for payload, source, destination in swarm.net.payloads():
        msg = decode_message(payload)
        sender = b.by_prefix(msg.header.guid_prefix)
        receiver = b.participant(swarm.name_at(destination))
        assert sender is not None and address_of(b, sender.name) == source
        assert msg.header.vendor_id == VENDORID_SWARMD
        assert destination[1] == b.user_port(receiver)
        # no INFO_DST (the tag names the receiver); the last submessage is the authenticator
        *body, auth = msg.submessages
        assert isinstance(auth, SkippedSubmessage) and auth.submessage_id == AUTH_SUBMESSAGE_ID
        key = keyring(b, receiver.name).pair_key(sender.guid_prefix)
        assert key is not None
        assert verify(user_data_key(key), payload, receiver.guid_prefix, 1)
        for sm in body:
            assert not isinstance(sm, InfoDst)
            assert isinstance(sm, Data | Heartbeat | AckNack | Gap)
            seen[type(sm).__name__] += 1
            writer_side, reader_side = (
                (receiver, sender) if isinstance(sm, AckNack) else (sender, receiver)
            )
            matches = b.matches(writer_side, reader_side)
            writer_guids = {m.local.entity_id for m in matches}
            reader_guids = {m.remote.entity_id for m in matches}
            assert sm.writer_id in writer_guids and sm.reader_id in reader_guids
            if isinstance(sm, Data):
                topic = next(m.topic for m in matches if m.local.entity_id == sm.writer_id)
                assert topic != TOPIC_COMMAND or sender == lead_p
                assert topic != TOPIC_READY or receiver == lead_p
                assert sm.serialized_payload is not None
                assert sm.serialized_payload[:2] == b"\x00\x01"  # CDR_LE
                assert len(sm.serialized_payload) % 4 == 0
    assert seen["Data"] and seen["Heartbeat"] and seen["AckNack"]


# --- take-off latency on virtual time (docs/dataplane.md, "Numbers") ------------------------


def command_latencies(members: int, drop: float, seed: int) -> tuple[list[float], int]:
    """Virtual seconds from ``send_command`` to each member's execution, and datagrams sent."""
    swarm = make_swarm(members, seed=seed, drop=drop, max_delay_s=0.005)
    swarm.discover_all()
    cmd = swarm.planes["lead"].make_command(CommandKind.TAKEOFF, altitude_m=10.0)
    swarm.run_until(60.0, [send_at(swarm, 1.0, cmd)])
    assert len(swarm.executed) == members
    return [t - 1.0 for t in swarm.executed_at.values()], swarm.net.stats.sent


def test_latency_driver_sees_every_member_execute() -> None:
    latencies, sent = command_latencies(10, 0.3, seed=1)
    assert len(latencies) == 10 and all(t >= 0.0 for t in latencies) and sent > 10


if __name__ == "__main__":  # python -m tests.test_dataplane_swarm
    import statistics

    print("| loss | per member, median | all 10, median | all 10, p95 | all 10, max | datagrams |")
    for loss in (0.0, 0.1, 0.3):
        each: list[float] = []
        worst: list[float] = []
        sent: list[int] = []
        for s in range(1, 51):
            lat, n = command_latencies(10, loss, s)
            each += lat
            worst.append(max(lat))
            sent.append(n)
        p95 = statistics.quantiles(worst, n=20)[18]
        print(
            f"| {loss:.0%} | {statistics.median(each) * 1e3:.0f} ms "
            f"| {statistics.median(worst) * 1e3:.0f} ms | {p95 * 1e3:.0f} ms "
            f"| {max(worst) * 1e3:.0f} ms | {statistics.median(sent):.0f} |"
        )
