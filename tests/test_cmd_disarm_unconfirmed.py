"""The operator is told when a failed take-off's DISARM was never confirmed (docs/px4.md, "A
failed take-off's DISARM"; session 18).

A take-off that fails after its ARM repeats its DISARM on the ground for up to 2 s. When
neither PX4's answer nor a fresh HEARTBEAT shows it, the vehicle may still be armed, props
maybe spinning. Until session 18 that was a counter (``px4.disarm_unconfirmed``) and a log
line on the drone: the operator read FAILED and might walk up to an armed drone. Now the
member amends its answer (the same FAILED and reason, flagged
``OUTCOME_DISARM_UNCONFIRMED``), the commander marks the row, and ``swarmctl takeoff``'s
follow, ``watch`` and ``status`` say it; a confirmed DISARM changes nothing.

The swarm on ``MemNet`` (virtual time) with m01's vehicle requests handed to a real
``VehicleCore`` flying the simulated PX4 (``Bench``) whose link loses every NAV_TAKEOFF
(the take-off fails ``takeoff_no_ack`` armed on the ground) and, in the attack, every
DISARM too. The attack test fails on main: the row said ``failed`` and nothing more.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from swarmd.cli.commands_view import CommandWatch, FollowLines, render_commands
from swarmd.cli.takeoff_cmd import render_outcomes
from swarmd.px4.bridge import Px4Bridge, Px4Config
from swarmd.px4.constants import MavCmd
from swarmd.px4.messages import Observation, VehicleCommand
from swarmd.px4.vehicle import TaskFinished, VehicleRequest
from swarmd.swarm.events import OutcomeRecorded, OutcomeReported, SwarmEvent
from tests.test_px4_vehicle import Bench
from tests.test_swarm_core import Swarm

STEP_S = 0.01  # how often m01's vehicle is driven to the swarm's clock


def _lose(disarms: bool) -> Callable[[Observation | VehicleCommand, str], bool]:
    """Every NAV_TAKEOFF lost on the way down, and every DISARM too when ``disarms``."""

    def drop(msg: Observation | VehicleCommand, direction: str) -> bool:
        if direction != "down" or not isinstance(msg, VehicleCommand):
            return False
        disarm = msg.command == MavCmd.COMPONENT_ARM_DISARM and msg.params[0] == 0.0
        return msg.command == MavCmd.NAV_TAKEOFF or (disarms and disarm)

    return drop


class VehicleSwarm(Swarm):
    """m01's requests reach a real ``VehicleCore`` (``Bench``, its link losing what
    ``_lose`` says), driven on the swarm's clock; everything the core reports for a task
    (its ``TaskFinished``, a ``DisarmUnconfirmed`` after it) goes back to m01's core, as
    the daemon's bridge hands it on (``SwarmApp._on_task_finished``)."""

    def __init__(self, *, disarms_lost: bool, node: str = "m01") -> None:
        self.bench = Bench(drop=_lose(disarms_lost))
        self.handed = 0  # bench events already handed to ``node``
        self.node = node  # m01, or the commander's own drone (lead)
        super().__init__(1, seed=18, lead_vehicle=node == "lead")
        self.net.call_at(STEP_S, self._drive)

    def _drive(self, now: float) -> None:
        bench = self.bench
        bench.run(max(0.0, now - bench.now))
        new, self.handed = bench.events[self.handed :], len(bench.events)
        core = self.cores[self.node]
        for event in new:
            if isinstance(event, TaskFinished) or type(event).__name__ == "DisarmUnconfirmed":
                core.task_finished(event, now)  # type: ignore[arg-type]  # main lacks it
        if new:
            self.net.poke(self.ids[self.node])
        self.net.call_at(now + STEP_S, self._drive)

    def _on_event(self, node_id: int, event: SwarmEvent, now: float) -> None:
        if isinstance(event, VehicleRequest) and node_id == self.ids[self.node]:
            self.events[self.node].append(event)
            self.bench.run(max(0.0, now - self.bench.now))
            self.bench.core.request(event, now)
            self.bench._pump_core()
            return
        super()._on_event(node_id, event, now)


def _failed_takeoff(disarms_lost: bool) -> tuple[VehicleSwarm, int, list[dict[str, Any]]]:
    """A take-off to m01 that fails; the commander's snapshots while the follow would run
    (every 0.25 s until the row settles)."""
    swarm = VehicleSwarm(disarms_lost=disarms_lost)
    swarm.run(3.0)
    request: dict[str, Any] = {"alt_m": 5.0, "valid_for_s": 10.0}
    sent = swarm.call("lead", lambda now: swarm.lead.request_takeoff(request, now))
    assert sent["sent"] and sent["ready"] == ["m01"], sent
    cid = int(sent["command_id"])
    snaps: list[dict[str, Any]] = []
    for _ in range(200):  # 50 s of virtual time at most
        swarm.run(0.25)
        snap = swarm.lead.request_outcomes({"command_id": cid}, swarm.net.now)
        snaps.append(snap)
        if snap["done"]:
            break
    assert snaps[-1]["done"], snaps[-1]
    return swarm, cid, snaps


def _follow(snaps: list[dict[str, Any]]) -> list[str]:
    """What ``swarmctl takeoff`` prints while it follows (the same ``FollowLines``)."""
    follow = FollowLines()
    return [line for snap in snaps for line in follow.lines(snap, "takeoff")]


def test_an_unconfirmed_disarm_reaches_the_operator() -> None:
    """Every DISARM lost: the vehicle stays armed on the ground after ``takeoff_no_ack``.
    [main: the row said failed, no mark, the follow ended at the failure]"""
    swarm, cid, snaps = _failed_takeoff(disarms_lost=True)
    node = snaps[-1]["nodes"]["m01"]
    assert (node["state"], node["reason"]) == ("failed", "takeoff_no_ack")
    assert node.get("disarm_unconfirmed") is True
    assert swarm.bench.sim.armed  # honest: it is armed, and the operator is told
    assert swarm.bench.core.disarm_unconfirmed == 1
    lines = _follow(snaps)
    assert lines[0].startswith("m01: accepted")
    assert lines[1].startswith("m01: failed (takeoff_no_ack)")
    assert "DISARM was never confirmed" in lines[2] and "abort --only m01" in lines[2]
    assert len(lines) == 3
    (row,) = [r for r in render_outcomes(snaps[-1]) if "m01" in r]
    assert "[disarm not confirmed]" in row
    status = {"role": "commander", "commands": [snaps[-1]]}
    assert any("disarm not confirmed" in ln and "m01" in ln for ln in render_commands(status))
    # swarmctl watch, started before the failure: the amendment is a line of its own
    watch = CommandWatch()
    watch.update({"commands": [snaps[0]]})
    said = [ln for snap in snaps[1:] for ln in watch.update({"commands": [snap]})]
    assert sum("DISARM was never confirmed" in ln for ln in said) == 1
    # an amendment, never a second execution: one request, one TAKEOFF received
    m01 = swarm.cores["m01"]
    assert len([e for e in swarm.events["m01"] if isinstance(e, VehicleRequest)]) == 1
    counters = m01.executor_status()["counters"]
    assert counters.get("received_takeoff") == 1
    assert counters.get("takeoff_disarm_unconfirmed") == 1
    assert counters.get("outcome_failed") == 1


def test_a_confirmed_disarm_changes_nothing() -> None:
    """The control: the DISARM arrives, PX4 disarms: no amendment, no mark, the follow says
    the failure alone (the row settles once the window for an amendment is over)."""
    swarm, cid, snaps = _failed_takeoff(disarms_lost=False)
    node = snaps[-1]["nodes"]["m01"]
    assert (node["state"], node["reason"]) == ("failed", "takeoff_no_ack")
    assert node["disarm_unconfirmed"] is False
    assert not swarm.bench.sim.armed
    assert swarm.bench.core.disarm_unconfirmed == 0
    lines = _follow(snaps)
    assert [ln.split(" after ")[0] for ln in lines] == [
        "m01: accepted",
        "m01: failed (takeoff_no_ack)",
    ]
    assert "disarm" not in " ".join(render_commands({"role": "commander", "commands": snaps[-1:]}))
    counters = swarm.cores["m01"].executor_status()["counters"]
    assert "takeoff_disarm_unconfirmed" not in counters


def test_the_bridge_hands_the_amendment_to_its_task_listener() -> None:
    """The daemon's path: the bridge gives ``DisarmUnconfirmed`` to the listener it gives
    each ``TaskFinished`` (``SwarmApp._on_task_finished`` -> ``SwarmCore.task_finished``)."""
    from swarmd.px4.vehicle import DisarmUnconfirmed

    bridge = Px4Bridge.from_config(Px4Config(connection="udpin:127.0.0.1:0", sysid=1))
    heard: list[object] = []
    bridge.on_task_finished(heard.append)
    event = DisarmUnconfirmed(7, "takeoff_no_ack", "DISARM no ack after 4 sends")
    bridge._on_event(event)  # noqa: SLF001 - the driver's callback, without a loop
    assert heard == [event]


def test_the_commanders_own_drone_marks_its_row_too() -> None:
    """The commander's drone runs its command at issue and records its own outcomes in its
    tracker (no wire): the amendment marks that row the same way."""
    swarm = VehicleSwarm(disarms_lost=True, node="lead")
    swarm.run(3.0)
    request: dict[str, Any] = {"kind": "takeoff", "alt_m": 5.0, "only": ["lead"]}
    sent = swarm.call("lead", lambda now: swarm.lead.request_command(request, now))
    cid = int(sent["command_id"])
    snap = swarm.run_until_done(cid)
    node = snap["nodes"]["lead"]
    assert (node["state"], node["reason"], node["disarm_unconfirmed"]) == (
        "failed",
        "takeoff_no_ack",
        True,
    )
    assert swarm.bench.sim.armed


def _failed_then(kind: str) -> tuple[VehicleSwarm, dict[str, Any], dict[str, Any]]:
    """A take-off to m01 fails (every NAV_TAKEOFF and DISARM lost), and while its DISARM
    repeats run the commander sends ``kind`` to m01: the take-off's and its snapshots once
    both settled."""
    swarm = VehicleSwarm(disarms_lost=True)
    swarm.run(3.0)
    request: dict[str, Any] = {"alt_m": 5.0, "valid_for_s": 10.0}
    sent = swarm.call("lead", lambda now: swarm.lead.request_takeoff(request, now))
    cid = int(sent["command_id"])
    for _ in range(400):  # 20 s of virtual time at most
        swarm.run(0.05)
        snap = swarm.lead.request_outcomes({"command_id": cid}, swarm.net.now)
        if snap["nodes"]["m01"]["state"] == "failed":
            break
    assert snap["nodes"]["m01"]["state"] == "failed", snap
    seq = swarm.bench.core.last_takeoff
    assert seq is not None and seq.disarming  # the repeats run: the new request stops them
    second = {"kind": kind, "only": ["m01"]}
    then = swarm.call("lead", lambda now: swarm.lead.request_command(second, now))
    return swarm, swarm.run_until_done(cid), swarm.run_until_done(int(then["command_id"]))


def test_a_hold_that_stops_the_disarm_repeats_still_leaves_the_operator_told() -> None:
    """Review 18: a request that reaches the vehicle while a failed take-off repeats its
    DISARM stops the repeats (vehicle.py: any request runs). A HOLD does not disarm, so the
    vehicle stays armed on the ground, and the DISARM was never confirmed: the take-off's row
    must say so. [main: the repeats counted as "stopped", no amendment, no mark, while the
    vehicle sat armed]"""
    swarm, takeoff, hold = _failed_then("hold")
    assert swarm.bench.sim.armed  # honest: still armed after the HOLD
    node = takeoff["nodes"]["m01"]
    assert (node["state"], node["reason"]) == ("failed", "takeoff_no_ack")
    assert node["disarm_unconfirmed"] is True
    assert hold["nodes"]["m01"]["state"] == "completed"
    counters = swarm.cores["m01"].executor_status()["counters"]
    assert counters.get("takeoff_disarm_unconfirmed") == 1
    assert swarm.bench.core.disarm_unconfirmed == 1


def test_an_abort_that_stops_the_disarm_repeats_owns_the_disarm() -> None:
    """The control: an ABORT stops the repeats and disarms the vehicle itself (its own row
    says how); the take-off's row gets no mark (nothing is left unconfirmed)."""
    swarm, takeoff, abort = _failed_then("abort")
    node = takeoff["nodes"]["m01"]
    assert (node["state"], node["disarm_unconfirmed"]) == ("failed", False)
    assert abort["nodes"]["m01"]["state"] in ("completed", "failed")
    assert "takeoff_disarm_unconfirmed" not in swarm.cores["m01"].executor_status()["counters"]


def test_the_amendment_is_in_both_journals_not_a_copy_of_the_failure() -> None:
    """Review 18: the amendment's events, which the daemon logs (``command_outcome`` on the
    drone, ``command_outcome_received`` on the commander, warnings when flagged), say what
    it is. The journal is what is left once ``swarmctl takeoff`` exited or the commander
    restarted. [main: both lines repeated the failure's fields word for word]"""
    swarm, cid, _ = _failed_takeoff(disarms_lost=True)

    def flagged(events: list[SwarmEvent], kind: type) -> list[bool]:
        return [
            bool(getattr(e, "disarm_unconfirmed", False))
            for e in events
            if isinstance(e, OutcomeReported | OutcomeRecorded)
            and type(e) is kind
            and e.command_id == cid
            and e.result.name == "FAILED"
        ]

    assert flagged(swarm.events["m01"], OutcomeReported) == [False, True]
    assert flagged(swarm.events["lead"], OutcomeRecorded) == [False, True]


def test_the_commanders_own_drone_logs_its_amendment_too() -> None:
    """The commander's own drone records to its tracker, not the wire: it logs the
    amendment as its own ``command_outcome`` all the same. [main: nothing logged]"""
    swarm = VehicleSwarm(disarms_lost=True, node="lead")
    swarm.run(3.0)
    request: dict[str, Any] = {"kind": "takeoff", "alt_m": 5.0, "only": ["lead"]}
    sent = swarm.call("lead", lambda now: swarm.lead.request_command(request, now))
    cid = int(sent["command_id"])
    swarm.run_until_done(cid)
    told = [
        bool(getattr(e, "disarm_unconfirmed", False))
        for e in swarm.events["lead"]
        if isinstance(e, OutcomeReported) and e.command_id == cid and e.result.name == "FAILED"
    ]
    assert told == [False, True]


class _Log:
    """The daemon's logger as ``CoreEvents._on_event`` calls it: (level, event, fields)."""

    def __init__(self) -> None:
        self.lines: list[tuple[str, str, dict[str, Any]]] = []

    def __getattr__(self, level: str) -> Callable[..., None]:
        return lambda event, **fields: self.lines.append((level, event, fields))


def test_the_daemon_logs_the_amendment_as_a_warning() -> None:
    """``SwarmApp``'s event handler: the flagged outcome is a warning with
    ``disarm_unconfirmed: true`` on both ends; an unflagged one stays an info line."""
    from types import SimpleNamespace

    from swarmd.dataplane.types import CommandResult
    from swarmd.swarmapp_events import CoreEvents

    log = _Log()
    app: Any = SimpleNamespace(log=log)
    failed = CommandResult.FAILED
    for armed in (False, True):
        CoreEvents._on_event(  # noqa: SLF001 - the driver's callback, without a daemon
            app, OutcomeReported(7, "TAKEOFF", failed, "takeoff_no_ack", disarm_unconfirmed=armed)
        )
        CoreEvents._on_event(  # noqa: SLF001
            app,
            OutcomeRecorded("m01", 7, failed, "takeoff_no_ack", True, disarm_unconfirmed=armed),
        )
    assert [(lvl, ev, f["disarm_unconfirmed"]) for lvl, ev, f in log.lines] == [
        ("info", "command_outcome", False),
        ("info", "command_outcome_received", False),
        ("warning", "command_outcome", True),
        ("warning", "command_outcome_received", True),
    ]
