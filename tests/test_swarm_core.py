"""The swarm core on virtual time, no sockets: a commander and members joined by the
in-memory network (``MemNet``, the discovery tests' network: any ``SansIOCore`` with byte
datagrams fits it), each member's vehicle played by the test.

What moved here from the three-daemon loopback test: exactly-once execution under 30 %
user-data loss, and again after the operator resends the same command id (there it needed
a monkeypatched adapter method; here the network is lossy by construction)."""

from __future__ import annotations

import random
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from swarmd_lab.memnet import Channel, MemNet

from swarmd.dataplane import Command, CommandKind, CommandResult
from swarmd.dataplane.types import MAX_ALTITUDE_M, TimeEcho
from swarmd.dataplane.validity import stamp_ms
from swarmd.px4 import takeoff
from swarmd.px4.takeoff import FailReason, TakeoffFailed
from swarmd.px4.vehicle import TaskFinished, TaskKind, VehicleRequest
from swarmd.swarm.core import (
    MAX_RUNNING_IDS,
    PX4_DISABLED,
    UNKNOWN_KIND,
    RequestInvalid,
    SwarmCore,
    SwarmSettings,
)
from swarmd.swarm.events import (
    CommandExecuting,
    OutcomeReported,
    PeerTrafficVerified,
    PersistExecuted,
    SwarmEvent,
)
from swarmd.swarm.roles import Roles
from tests.test_dataplane_swarm import address_of, make_bundle, make_plane

VEHICLE_TASK_S = 1.0  # how long the played vehicle takes to finish any task


@dataclass
class Verdict:
    ready: bool = True
    reason: str | None = None
    armed: bool | None = False
    landed_state: str | None = "ON_GROUND"
    gps_fix: int | None = 3
    satellites: int | None = 12
    battery_pct: int | None = 90


@dataclass
class Vehicle:
    """The test plays each member's vehicle: its verdict, and how each task ends."""

    verdict: Verdict = field(default_factory=Verdict)
    requests: list[VehicleRequest] = field(default_factory=list)
    answer: Callable[[VehicleRequest], TaskFinished] = field(default=lambda r: _success(r))

    def verdict_at(self, now: float) -> Verdict:
        return self.verdict


def _success(r: VehicleRequest) -> TaskFinished:
    return TaskFinished(r.token, True, "IN_AIR" if r.kind is TaskKind.TAKEOFF else "", None)


class Swarm:
    def __init__(
        self,
        members: int = 3,
        *,
        loss: float = 0.0,
        seed: int = 1,
        vehicles: bool = True,
        lead_vehicle: bool = False,
    ) -> None:
        self.bundle = make_bundle(members)
        self.net = MemNet(random.Random(seed), Channel(loss=loss, delay_s=0.002, jitter_s=0.01))
        self.cores: dict[str, SwarmCore] = {}
        self.ids: dict[str, int] = {}
        self.vehicles: dict[str, Vehicle] = {}
        self.events: dict[str, list[SwarmEvent]] = {}
        self.net.on_event = self._on_event
        for p in self.bundle.participants:
            has_vehicle = lead_vehicle if p.name == "lead" else vehicles
            vehicle = self.vehicles[p.name] = Vehicle()
            core = SwarmCore(
                Roles.of(self.bundle, p),
                make_plane(self.bundle, p.name),
                verdict=vehicle.verdict_at if has_vehicle else None,
                link_q=lambda: 0.8,
                settings=SwarmSettings(readiness_period_s=0.5, stale_after_s=3.0),
            )
            self.cores[p.name] = core
            self.events[p.name] = []
            core.start(0.0)
            host, port = address_of(self.bundle, p.name)
            self.ids[p.name] = len(self.net)  # known before add drives it
            assert self.net.add(core, host, [port]) == self.ids[p.name]
        for a in self.cores:  # discovery, as the daemon reports it
            for b in self.cores:
                if a != b:
                    self.cores[a].peer_up(b, address_of(self.bundle, b), 1, 0.0)
            self.net.poke(self.ids[a])

    @property
    def lead(self) -> SwarmCore:
        return self.cores["lead"]

    @property
    def members(self) -> list[str]:
        return [n for n in self.cores if n != "lead"]

    def call(self, name: str, action: Callable[[float], Any]) -> Any:
        result = action(self.net.now)
        self.net.poke(self.ids[name])
        return result

    def run(self, seconds: float) -> None:
        self.net.run_until(self.net.now + seconds)

    def run_until_done(self, command_id: int, budget_s: float = 30.0) -> dict[str, Any]:
        end = self.net.now + budget_s
        while self.net.now < end:
            self.run(0.25)
            snap = self.lead.request_outcomes({"command_id": command_id}, self.net.now)
            if snap["done"]:
                return snap
        raise AssertionError(f"command {command_id} not done: {snap}")

    def requests(self, name: str) -> list[VehicleRequest]:
        return self.vehicles[name].requests

    def _on_event(self, node_id: int, event: SwarmEvent, now: float) -> None:
        name = next(n for n, i in self.ids.items() if i == node_id)
        self.events[name].append(event)
        if isinstance(event, VehicleRequest):
            vehicle = self.vehicles[name]
            vehicle.requests.append(event)
            self.net.call_at(now + VEHICLE_TASK_S, self._finish(name, vehicle.answer(event)))

    def _finish(self, name: str, done: TaskFinished) -> Callable[[float], None]:
        def finish(now: float) -> None:
            self.cores[name].task_finished(done, now)
            self.net.poke(self.ids[name])

        return finish


def test_exactly_once_with_30_percent_user_data_loss() -> None:
    """Every member executes the take-off once although 30 % of user datagrams are lost
    both ways, and again once when the commander resends the same command id."""
    swarm = Swarm(3, loss=0.30, seed=30)
    swarm.run(5.0)
    assert all(r["ready"] for r in swarm.lead.table.rows(swarm.net.now).values())
    sent = swarm.call(
        "lead", lambda now: swarm.lead.request_takeoff({"require_all": True, "alt_m": 4.0}, now)
    )
    cid = sent["command_id"]
    assert sent["sent"] and sorted(sent["ready"]) == ["m01", "m02", "m03"]
    nodes = swarm.run_until_done(cid)["nodes"]
    assert all(n["state"] == "completed" for n in nodes.values()), nodes
    for m in swarm.members:
        assert swarm.cores[m].executor_status()["counters"].get("received_takeoff") == 1
    # the operator's retry: the very same command id goes out again, under a new SN
    again = Command(cid, CommandKind.TAKEOFF, 4.0, swarm.members)
    plane = swarm.lead.plane
    assert plane is not None
    swarm.call("lead", lambda now: plane.send_command(again, now))
    for _ in range(120):
        swarm.run(0.25)
        counters = [swarm.cores[m].plane.counters for m in swarm.members]  # type: ignore[union-attr]
        if all(c.get("command_duplicate", 0) >= 1 for c in counters):
            break
    assert all(c.get("command_duplicate", 0) >= 1 for c in counters), counters
    for m in swarm.members:
        core = swarm.cores[m]
        assert core.executor_status()["counters"].get("received_takeoff") == 1
        assert core.plane is not None
        assert core.plane.status(swarm.net.now)["executed_commands"] == 1
        assert [r.kind for r in swarm.requests(m)] == [TaskKind.TAKEOFF]
    assert swarm.net.stats.lost > 0


def test_write_ahead_persist_comes_before_the_vehicle_moves() -> None:
    swarm = Swarm(1)
    swarm.run(2.0)
    sent = swarm.call("lead", lambda now: swarm.lead.request_command({"kind": "land"}, now))
    swarm.run_until_done(sent["command_id"])
    events = swarm.events["m01"]
    persist = next(i for i, e in enumerate(events) if isinstance(e, PersistExecuted))
    request = next(i for i, e in enumerate(events) if isinstance(e, VehicleRequest))
    assert persist < request
    saved = events[persist]
    assert isinstance(saved, PersistExecuted)
    assert ("lead", sent["command_id"]) in saved.executed


@pytest.mark.parametrize(
    ("kind", "task"),
    [("land", TaskKind.LAND), ("hold", TaskKind.HOLD), ("abort", TaskKind.ABORT)],
)
def test_land_hold_abort_reach_the_vehicle_and_complete(kind: str, task: TaskKind) -> None:
    swarm = Swarm(2)
    swarm.run(2.0)
    sent = swarm.call("lead", lambda now: swarm.lead.request_command({"kind": kind}, now))
    nodes = swarm.run_until_done(sent["command_id"])["nodes"]
    assert {n: s["state"] for n, s in nodes.items()} == {"m01": "completed", "m02": "completed"}
    for m in swarm.members:
        assert [(r.kind, r.origin, r.alt_m) for r in swarm.requests(m)] == [
            (task, ("lead", sent["command_id"]), None)
        ]


def test_outcomes_without_an_id_list_what_was_issued_and_what_each_member_decided() -> None:
    """``swarmctl outcomes``'s request: the commander's commands newest first, and on a
    member its own final answer to each (a command it ran, then one it refused)."""
    swarm = Swarm(2)
    swarm.run(2.0)
    land = swarm.call(
        "lead", lambda now: swarm.lead.request_command({"kind": "land", "only": ["m01"]}, now)
    )["command_id"]
    swarm.run_until_done(land)
    swarm.vehicles["m01"].answer = lambda r: TaskFinished(r.token, False, "not_confirmed", None)
    hold = swarm.call("lead", lambda now: swarm.lead.request_command({"kind": "hold"}, now))
    swarm.run_until_done(hold["command_id"])
    kept = swarm.lead.request_outcomes({}, swarm.net.now)
    assert kept["role"] == "commander" and kept["ran"] == [] and kept["issued_evicted"] == 0
    assert [c["command_id"] for c in kept["issued"]] == [hold["command_id"], land]
    assert kept["issued"][1] == swarm.lead.request_outcomes({"command_id": land}, swarm.net.now)
    ran = swarm.cores["m01"].request_outcomes({}, swarm.net.now)
    assert ran["role"] == "member" and ran["issued"] == []
    assert [
        (r["command_id"], r["kind"], r["commander"], r["state"], r["reason"]) for r in ran["ran"]
    ] == [
        (hold["command_id"], "hold", "lead", "failed", "not_confirmed"),
        (land, "land", "lead", "completed", ""),
    ]
    assert [
        r["command_id"] for r in swarm.cores["m02"].request_outcomes({}, swarm.net.now)["ran"]
    ] == [hold["command_id"]]


def test_a_vehicle_failure_is_reported_failed_with_its_reason() -> None:
    swarm = Swarm(1)
    swarm.vehicles["m01"].answer = lambda r: TaskFinished(r.token, False, "not_confirmed", None)
    swarm.run(2.0)
    sent = swarm.call("lead", lambda now: swarm.lead.request_command({"kind": "hold"}, now))
    node = swarm.run_until_done(sent["command_id"])["nodes"]["m01"]
    assert (node["state"], node["reason"]) == ("failed", "not_confirmed")


def test_takeoff_refused_by_the_vehicle_as_not_ready_is_rejected() -> None:
    swarm = Swarm(1)
    refused = TakeoffFailed(FailReason.NOT_READY, "no_3d_fix", "no fix", 0.0)
    swarm.vehicles["m01"].answer = lambda r: TaskFinished(r.token, False, "not_ready", refused)
    swarm.run(2.0)
    sent = swarm.call("lead", lambda now: swarm.lead.request_takeoff({"alt_m": 5.0}, now))
    node = swarm.run_until_done(sent["command_id"])["nodes"]["m01"]
    assert node["state"] == "rejected"


def test_not_ready_member_is_refused_by_the_commander_then_by_itself() -> None:
    swarm = Swarm(2)
    swarm.vehicles["m02"].verdict = Verdict(ready=False, reason="prearm_failed")
    swarm.run(2.0)
    refused_all = swarm.call(
        "lead", lambda now: swarm.lead.request_takeoff({"require_all": True}, now)
    )
    assert refused_all["sent"] is False and refused_all["refused"] == {"m02": "prearm_failed"}
    sent = swarm.call("lead", lambda now: swarm.lead.request_takeoff({"alt_m": 5.0}, now))
    assert sent["ready"] == ["m01"] and sent["refused"] == {"m02": "prearm_failed"}
    nodes = swarm.run_until_done(sent["command_id"])["nodes"]
    assert nodes["m02"]["state"] == "refused" and nodes["m01"]["state"] == "completed"
    # sent to it anyway (raw command): the member refuses with its own live reason
    raw = swarm.call(
        "lead", lambda now: swarm.lead.request_command({"kind": "takeoff", "only": ["m02"]}, now)
    )
    n2 = swarm.run_until_done(raw["command_id"])["nodes"]["m02"]
    assert (n2["state"], n2["reason"]) == ("rejected", "prearm_failed")
    assert swarm.requests("m02") == []


def test_a_member_without_a_vehicle_rejects_everything() -> None:
    swarm = Swarm(1, vehicles=False)
    swarm.run(2.0)
    sent = swarm.call("lead", lambda now: swarm.lead.request_command({"kind": "land"}, now))
    node = swarm.run_until_done(sent["command_id"])["nodes"]["m01"]
    assert (node["state"], node["reason"]) == ("rejected", PX4_DISABLED)


def test_an_unknown_kind_number_is_rejected_not_run_as_another_kind() -> None:
    swarm = Swarm(1)
    member = swarm.cores["m01"]
    member._execute("lead", Command(7, 99, 0.0, []), 0.0)  # type: ignore[arg-type]
    reported = [e for e in iter(member.next_event, None) if isinstance(e, OutcomeReported)]
    assert [(e.result, e.reason) for e in reported] == [(CommandResult.REJECTED, UNKNOWN_KIND)]
    assert swarm.requests("m01") == []


def test_the_commanders_own_drone_flies_with_the_swarm() -> None:
    swarm = Swarm(1, lead_vehicle=True)
    swarm.run(2.0)
    rows = swarm.lead.table.rows(swarm.net.now)
    assert rows["lead"]["local"] and rows["lead"]["ready"]
    sent = swarm.call("lead", lambda now: swarm.lead.request_takeoff({"alt_m": 3.0}, now))
    assert sorted(sent["ready"]) == ["lead", "m01"]
    nodes = swarm.run_until_done(sent["command_id"])["nodes"]
    assert nodes["lead"]["state"] == "completed" and nodes["m01"]["state"] == "completed"
    assert [r.kind for r in swarm.requests("lead")] == [TaskKind.TAKEOFF]


def test_readiness_every_period_and_at_once_on_a_change() -> None:
    swarm = Swarm(1)
    member = swarm.cores["m01"]
    swarm.run(2.0)
    published = member.counters["readiness_published"]
    assert published in (4, 5)  # t = 0, 0.5, 1.0, 1.5 (and 2.0): the 0.5 s period
    member.vehicle_changed(True, None, swarm.net.now)  # the first verdict: no extra report
    swarm.vehicles["m01"].verdict = Verdict(ready=False, reason="heartbeat_stale")
    swarm.call("m01", lambda now: member.vehicle_changed(False, "heartbeat_stale", now))
    assert member.counters["readiness_published"] == published + 1
    swarm.run(0.1)
    row = swarm.lead.table.rows(swarm.net.now)["m01"]
    assert (row["ready"], row["reason"]) == (False, "heartbeat_stale")


def test_requests_are_validated() -> None:
    swarm = Swarm(2)
    swarm.run(1.0)
    now = swarm.net.now
    with pytest.raises(RequestInvalid, match="not a commandable node: uav9"):
        swarm.lead.request_takeoff({"only": ["uav9"]}, now)
    with pytest.raises(RequestInvalid, match="alt_m"):
        swarm.lead.request_takeoff({"alt_m": 1000}, now)
    with pytest.raises(RequestInvalid, match="alt_m"):
        swarm.lead.request_takeoff({"alt_m": True}, now)
    with pytest.raises(RequestInvalid, match="kind must be one of"):
        swarm.lead.request_command({"kind": "flip"}, now)
    with pytest.raises(RequestInvalid, match="must be an integer"):
        swarm.lead.request_outcomes({"command_id": "1"}, now)
    with pytest.raises(RequestInvalid, match="unknown command id"):
        swarm.lead.request_outcomes({"command_id": 12345}, now)
    with pytest.raises(RequestInvalid, match="not a commander"):
        swarm.cores["m01"].request_takeoff({}, now)


def test_one_takeoff_ceiling_and_it_fits_the_wire() -> None:
    """The swarm core validates against px4's ceiling (one fact, one place), and any
    altitude it accepts also passes the wire's garbage cap, so a valid request is never
    refused later as undecodable."""
    assert takeoff.MAX_TAKEOFF_ALT_M <= MAX_ALTITUDE_M
    swarm = Swarm(2)
    swarm.run(1.0)
    now = swarm.net.now
    sent = swarm.lead.request_takeoff({"alt_m": takeoff.MAX_TAKEOFF_ALT_M}, now)
    assert sent["command_id"] > 0
    with pytest.raises(RequestInvalid, match="alt_m"):
        swarm.lead.request_takeoff({"alt_m": takeoff.MAX_TAKEOFF_ALT_M + 0.5}, now)


def test_every_command_kind_is_dispatched_to_one_vehicle_task() -> None:
    """A new CommandKind without a branch fails mypy (assert_never); at run time each kind
    reaches the vehicle exactly once, as its own task."""
    swarm = Swarm(1)
    member = swarm.cores["m01"]
    member.handle_timer(0.0)  # m01's first report, stamped 0.0
    echo = [TimeEcho("m01", stamp_ms(0.0), 0, 1)]  # dated: "issued as m01 sent its report"
    for i, kind in enumerate(CommandKind):
        member._execute("lead", Command(100 + i, kind, 5.0, [], 3000, echo), 0.0)
    requests = [e for e in iter(member.next_event, None) if isinstance(e, VehicleRequest)]
    assert [r.kind.name for r in requests] == [k.name for k in CommandKind]
    received = Counter(e.kind for e in swarm.events["m01"] if isinstance(e, CommandExecuting))
    assert sum(received.values()) == 0  # nothing went through the network for these


@settings(max_examples=100, deadline=None)
@given(data=st.lists(st.binary(max_size=200), max_size=20))
def test_anything_a_peer_sends_is_dropped_or_taken_never_raised(data: list[bytes]) -> None:
    swarm = Swarm(1)
    member = swarm.cores["m01"]
    for i, payload in enumerate(data):
        member.receive_datagram(payload, address_of(swarm.bundle, "lead"), 0.1 * i)
    member.receive_datagram(
        b"RTPS\x02\x05\x01\x0f" + bytes(12) + b"".join(data), ("10.9.9.9", 1), 9.0
    )
    assert swarm.requests("m01") == []


def test_verified_user_data_reports_its_sender_alive_to_the_driver() -> None:
    """Every readiness sample that passed its MAC becomes ``PeerTrafficVerified(member)`` at
    the commander: what the daemon feeds to ``DiscoveryEngine.peer_traffic`` (vouching,
    docs/discovery.md). Members hear nothing from each other, so they report nobody."""
    swarm = Swarm(3, loss=0.0, seed=31)
    swarm.run(5.0)
    heard = Counter(e.node for e in swarm.events["lead"] if isinstance(e, PeerTrafficVerified))
    assert sorted(heard) == ["m01", "m02", "m03"]
    assert all(count >= 3 for count in heard.values())  # ~1 Hz for 5 s
    for member in ("m01", "m02", "m03"):
        assert not [e for e in swarm.events[member] if isinstance(e, PeerTrafficVerified)]


def test_a_member_reports_at_once_to_a_commander_it_finds_again() -> None:
    """After a loss (the commander's blackout, issue 20) the member's next readiness report
    leaves at the re-discovery, not up to a period later: the commander's row counts it
    within the network's delay. One extra report, not a burst."""
    swarm = Swarm(2)
    swarm.cores["m01"].settings = SwarmSettings(readiness_period_s=1.0, stale_after_s=3.0)
    swarm.run(5.0)
    swarm.call("m01", lambda now: swarm.cores["m01"].peer_down("lead", now))
    swarm.run(10.3)  # mid-period: the member's next tick is up to 1 s away
    before = swarm.cores["m01"].counters["readiness_published"]
    received = swarm.lead.table.rows(swarm.net.now)["m01"]["count"]
    swarm.call("m01", lambda now: swarm.cores["m01"].peer_up(
        "lead", address_of(swarm.bundle, "lead"), 1, now))  # fmt: skip
    swarm.run(0.05)  # the channel's delay is 2-12 ms
    assert swarm.cores["m01"].counters["readiness_published"] == before + 1
    assert swarm.lead.table.rows(swarm.net.now)["m01"]["count"] == received + 1
    swarm.run(2.0)  # then one a second again, from the re-discovery
    assert swarm.cores["m01"].counters["readiness_published"] == before + 3


def test_the_commanders_own_ids_are_bounded_and_its_last_outcome_still_lands_locally() -> None:
    """The commander's own drone runs its commands at issue; the ids it keeps to route their
    outcomes to its tracker (not the wire) stay bounded over a long day of commands."""
    swarm = Swarm(1, lead_vehicle=True)
    swarm.run(2.0)
    member = swarm.lead.member
    last = 0
    for _ in range(MAX_RUNNING_IDS + 40):
        sent = swarm.call("lead", lambda now: swarm.lead.request_command({"kind": "hold"}, now))
        last = sent["command_id"]
        swarm.run(0.05)
    assert len(member._own) <= MAX_RUNNING_IDS + len(member._running)
    nodes = swarm.run_until_done(last)["nodes"]
    assert nodes["lead"]["state"] == "completed"
