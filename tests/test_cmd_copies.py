"""Commands that fit any swarm: one copy per member (docs/dataplane.md, "One copy per member").

Issue 18 gave every command one time echo per target, about 20 octets each, so a command to
more than ~30 members no longer fitted one 1400-octet datagram. Now each member's copy
names only that member and carries only its echo: the datagram a member receives has the
same size whether the swarm has 2 or 1000 drones. Checked here with the real encoder on
bundles of 100 and 1000 members, for the longest name a bundle allows, and end to end: a
``takeoff --require-all`` at N = 50 on MemNet runs once on every member. A member handed a
copy with another member's echo (a commander bug: nobody else holds the pair key) cannot
date the command and refuses it.
"""

from __future__ import annotations

from collections.abc import Mapping

import pytest

from swarmd.bundle.build import build_dev_bundle
from swarmd.bundle.mission import parse_mission
from swarmd.bundle.model import Bundle
from swarmd.dataplane import TOPIC_COMMAND, Command, CommandKind, CommandReceived, DataPlane
from swarmd.dataplane.plane import MAX_DATAGRAM_BYTES
from swarmd.dataplane.seal import protected_part
from swarmd.dataplane.types import MAX_NAME_CHARS, TimeEcho, decode_sample, encode_sample
from swarmd.dataplane.validity import EXPIRED, judge, stamp_ms
from swarmd.px4.vehicle import TaskKind
from swarmd.rtps import Data, decode_message
from tests.test_dataplane_swarm import address_of, make_plane
from tests.test_swarm_core import Swarm

COMMAND_READY_TOPICS = """topics:
  - {name: swarm/ready, type: 'swarmd::Readiness', reliability: best_effort,
     history_depth: 1, writers: member, readers: commander}
  - {name: swarm/command, type: 'swarmd::Command', reliability: reliable,
     history_depth: 8, writers: commander, readers: member}
  - {name: swarm/outcome, type: 'swarmd::CommandOutcome', reliability: reliable,
     history_depth: 16, writers: member, readers: commander}
"""


def _bundle(names: list[str]) -> Bundle:
    """A commander ``lead`` and members ``names``. MAVLink has 254 vehicle ids, so a
    bigger swarm reuses them (the mission parser allows it past 254 participants)."""
    lines = ["swarm: big", "domain_id: 0", "participants:"]
    lines.append("  - {name: lead, index: 0, role: commander, mavlink_sysid: 1}")
    for i, name in enumerate(names, start=1):
        lines.append(
            f"  - {{name: {name}, index: {i}, role: member, mavlink_sysid: {i % 254 + 1}}}"
        )
    return build_dev_bundle(parse_mission("\n".join(lines) + "\n" + COMMAND_READY_TOPICS)).bundle


def _issue_to_all(bundle: Bundle, names: list[str]) -> tuple[DataPlane, Command, list[bytes]]:
    """The commander of ``bundle`` with every member up issues a TAKEOFF to all of them,
    each with an echo of a report it holds; returns the datagrams it sends."""
    lead = make_plane(bundle, "lead")
    for i, name in enumerate(names):
        lead.peer_up(name, (f"10.1.{i // 250}.{i % 250 + 1}", 7411), 0.0, epoch=1)
    echoes = [TimeEcho(name, 4_000_000_000 + i, 250 + i, 1) for i, name in enumerate(names)]
    command = lead.make_command(
        CommandKind.TAKEOFF, altitude_m=10.0, targets=names, valid_ms=3000, echoes=echoes
    )
    lead.send_command(command, 1.0)
    return lead, command, [payload for payload, _ in lead.datagrams_to_send()]


def _copies(datagram: bytes) -> list[Command]:
    """The command samples in one of the commander's datagrams (MAC already checked by
    the members in the end-to-end tests; here only the octets)."""
    message = decode_message(protected_part(datagram))
    return [
        decode_sample(sm.serialized_payload, Command)
        for sm in message.submessages
        if isinstance(sm, Data) and sm.serialized_payload is not None
    ]


@pytest.mark.parametrize("members", [100, 1000])
def test_a_takeoff_to_every_member_fits_one_datagram_per_member(members: int) -> None:
    names = [f"drone-{i:04d}" for i in range(1, members + 1)]
    bundle = _bundle(names)
    lead, command, datagrams = _issue_to_all(bundle, names)
    assert len(datagrams) == members  # one datagram per member: nothing was split
    assert max(map(len, datagrams)) < MAX_DATAGRAM_BYTES
    assert len(set(map(len, datagrams))) == 1  # the same size for every member
    seen: dict[str, Command] = {}
    for datagram in datagrams:
        (copy,) = _copies(datagram)
        (target,) = copy.targets
        assert [e.node for e in copy.echoes] == [target]  # its own echo, nobody else's
        seen[target] = copy
    assert sorted(seen) == names
    assert {(c.command_id, c.kind, c.valid_ms) for c in seen.values()} == {
        (command.command_id, CommandKind.TAKEOFF, 3000)
    }
    assert seen[names[-1]].echoes == [command.echoes[-1]]
    # one sample: every member's copy is the same SN of the one writer
    writer = lead.status(1.0)["writers"][TOPIC_COMMAND]
    assert writer["written"] == 1 and writer["data_sent"] == members


def test_the_largest_copy_a_bundle_allows_fits_one_datagram() -> None:
    """A copy's size depends only on the member's name, at most ``MAX_NAME_CHARS``."""
    longest = ["d" * MAX_NAME_CHARS, "e" * MAX_NAME_CHARS]
    _, _, datagrams = _issue_to_all(_bundle(longest), longest)
    assert len(datagrams) == 2 and max(map(len, datagrams)) < MAX_DATAGRAM_BYTES
    # a generous margin: room for the sample to grow without ever fragmenting
    assert max(map(len, datagrams)) < MAX_DATAGRAM_BYTES // 4


def test_the_last_member_of_1000_verifies_and_dates_its_copy() -> None:
    """End to end through the member's MAC and its validity check, for the 1000th member."""
    names = [f"drone-{i:04d}" for i in range(1, 1001)]
    bundle = _bundle(names)
    lead = make_plane(bundle, "lead")
    member = make_plane(bundle, names[-1])
    for i, name in enumerate(names):
        lead.peer_up(name, (f"10.1.{i // 250}.{i % 250 + 1}", 7411), 0.0, epoch=1)
    member.peer_up("lead", ("10.1.9.9", 7411), 0.0, epoch=1)
    echoes = [TimeEcho(name, stamp_ms(0.0), 100, 1) for name in names]
    command = lead.make_command(
        CommandKind.TAKEOFF, altitude_m=10.0, targets=names, valid_ms=3000, echoes=echoes
    )
    lead.send_command(command, 1.0)
    mine = [p for p, (host, _) in lead.datagrams_to_send() if host == "10.1.3.250"]
    assert len(mine) == 1
    member.receive_datagram(mine[0], ("10.1.9.9", 7411), 1.0)
    received = [e for e in iter(member.next_event, None) if isinstance(e, CommandReceived)]
    assert [e.command.command_id for e in received] == [command.command_id]
    assert judge(received[0].command, names[-1], 1.0).valid


def test_a_member_given_another_members_echo_refuses() -> None:
    """The commander's copy for m01 carries m02's echo, with m01's own stamp and age in it
    (so only the name is wrong): m01 cannot date the command on its own clock, refuses it
    as ``expired`` and says so; m02's (right) copy of the same command runs."""
    swarm = Swarm(2, seed=31)
    swarm.run(3.0)
    plane = swarm.lead.plane
    assert plane is not None
    now = swarm.net.now
    own = {e.node: e for e in plane.time_echoes(["m01", "m02"], now)}
    wrong = TimeEcho("m02", own["m01"].stamp_ms, own["m01"].age_ms, own["m01"].epoch)
    command = plane.make_command(
        CommandKind.TAKEOFF, altitude_m=5.0, targets=["m01", "m02"], valid_ms=3000
    )
    swarm.lead.tracker.sent(command.command_id, "takeoff", ["m01", "m02"], now, valid_for_s=3.0)
    copies = {
        swarm.bundle.participant(name).guid_prefix: encode_sample(
            Command(command.command_id, command.kind, 5.0, [name], 3000, [echo])
        )
        for name, echo in (("m01", wrong), ("m02", own["m02"]))
    }
    writer = plane._endpoints.by_topic[TOPIC_COMMAND]  # the commander's bug, played by hand
    swarm.call("lead", lambda t: plane._queue(writer.write(copies, t)[1]))
    nodes = swarm.run_until_done(command.command_id)["nodes"]
    assert (nodes["m01"]["state"], nodes["m01"]["reason"]) == ("rejected", EXPIRED)
    assert swarm.requests("m01") == []
    assert swarm.cores["m01"].executor_status()["counters"]["refused_expired"] == 1
    assert nodes["m02"]["state"] == "completed"
    assert [r.kind for r in swarm.requests("m02")] == [TaskKind.TAKEOFF]


def test_a_command_that_names_no_echo_for_a_target_is_refused_there() -> None:
    """Through the public API: echoes for other members only give the target no echo."""
    swarm = Swarm(2, seed=32)
    swarm.run(3.0)
    plane = swarm.lead.plane
    assert plane is not None
    echoes = plane.time_echoes(["m02"], swarm.net.now)
    command = plane.make_command(
        CommandKind.HOLD, targets=["m01", "m02"], valid_ms=5000, echoes=echoes
    )
    swarm.lead.tracker.sent(
        command.command_id, "hold", ["m01", "m02"], swarm.net.now, valid_for_s=5.0
    )
    swarm.call("lead", lambda t: plane.send_command(command, t))
    nodes = swarm.run_until_done(command.command_id)["nodes"]
    assert (nodes["m01"]["state"], nodes["m01"]["reason"]) == ("rejected", EXPIRED)
    assert nodes["m02"]["state"] == "completed"


def test_takeoff_require_all_at_50_runs_once_everywhere() -> None:
    swarm = Swarm(50, loss=0.05, seed=50)
    swarm.run(4.0)
    assert all(r["ready"] for r in swarm.lead.table.rows(swarm.net.now).values())
    start = len(swarm.net.transmissions)
    sent = swarm.call(
        "lead", lambda now: swarm.lead.request_takeoff({"require_all": True, "alt_m": 4.0}, now)
    )
    assert sent["sent"] and len(sent["ready"]) == 50 and sent["refused"] == {}
    nodes = swarm.run_until_done(sent["command_id"])["nodes"]
    assert {n["state"] for n in nodes.values()} == {"completed"}, nodes
    swarm.run(10.0)  # repairs and late copies, if any, change nothing
    for m in swarm.members:
        assert [r.kind for r in swarm.requests(m)] == [TaskKind.TAKEOFF]
        assert swarm.cores[m].executor_status()["counters"]["received_takeoff"] == 1
    lead_id = swarm.ids["lead"]
    sent_by_lead = [t for t in swarm.net.transmissions[start:] if t.node == lead_id]
    assert max(t.size for t in sent_by_lead) < MAX_DATAGRAM_BYTES


def test_a_copy_moved_to_another_member_is_refused() -> None:
    """The attacker records m01's copy and sends it to m02: it is sealed for m01 (m01's
    pair key, m01's prefix), so m02 refuses it before decoding anything and runs nothing."""
    swarm = Swarm(2, seed=33)
    swarm.run(3.0)
    start = swarm.net.now
    sent = swarm.call(
        "lead", lambda now: swarm.lead.request_takeoff({"alt_m": 5.0, "only": ["m01"]}, now)
    )
    cid = int(sent["command_id"])
    to_m01 = address_of(swarm.bundle, "m01")
    marker = cid.to_bytes(8, "little")
    captured = [
        t.payload
        for t in swarm.net.transmissions
        if t.time >= start and t.target == to_m01 and marker in t.payload
    ]
    assert captured
    m02 = swarm.cores["m02"]
    assert m02.plane is not None
    refused_before = _auth_refusals(m02.plane.counters)
    lead = address_of(swarm.bundle, "lead")
    for datagram in captured:
        m02.receive_datagram(datagram, lead, swarm.net.now)
        swarm.net.poke(swarm.ids["m02"])
    assert _auth_refusals(m02.plane.counters) == refused_before + len(captured)
    swarm.run(5.0)
    assert swarm.requests("m02") == []
    assert [r.kind for r in swarm.requests("m01")] == [TaskKind.TAKEOFF]


def _auth_refusals(counters: Mapping[str, int]) -> int:
    return sum(n for name, n in counters.items() if name.startswith("dropped_auth_"))
