"""What the operator sees when a LAND supersedes a running TAKEOFF on a drone (docs/px4.md,
"Two requests, one vehicle"): the swarm cores on virtual time (``tests.test_swarm_core``)
with m01's vehicle a real ``VehicleCore`` instead of the played one, and swarmctl's
rendering of the reason.

Before, the take-off ran on beside the LAND: the commander was told the TAKEOFF
``completed`` (or ``failed no_liftoff``) whatever the LAND had done. Now the take-off's row
says ``failed`` with the reason ``superseded: land``, and the LAND's says ``completed``.
"""

from __future__ import annotations

import argparse
from typing import Any

import pytest

from swarmd.cli import takeoff_cmd
from swarmd.cli.commands_view import reason_text, superseded_by
from swarmd.cli.outcomes_cmd import render_kept
from swarmd.cli.takeoff_cmd import render_outcomes
from swarmd.dataplane.types import CommandResult
from swarmd.px4.constants import MavState
from swarmd.px4.messages import MODE_LAND, MODE_LOITER, Heartbeat, Observation
from swarmd.px4.vehicle import TaskFinished, VehicleRequest
from swarmd.swarm.commander import CommandTracker
from tests.test_cmd_two_commanders import _row, _two_commanders
from tests.test_cmd_validity import _Outcomes
from tests.test_px4_supersede import _ready
from tests.test_swarm_core import Swarm


class RealVehicle:
    """``name``'s vehicle as a ``VehicleCore`` (ready on the ground, no autopilot answering
    unless the test feeds it: a take-off stays in ARMING, retransmitting ARM); its
    ``TaskFinished`` go to ``name``'s swarm core as the daemon's bridge sends them."""

    def __init__(self, swarm: Swarm, name: str) -> None:
        self.swarm, self.name = swarm, name
        self.core = _ready(MODE_LOITER, in_air=False, now=swarm.net.now)
        played = swarm.net.on_event
        assert played is not None

        def on_event(node_id: int, event: Any, now: float) -> None:
            if node_id == swarm.ids[name] and isinstance(event, VehicleRequest):
                swarm.events[name].append(event)
                swarm.vehicles[name].requests.append(event)
                self.core.request(event, now)
                self._pump(now)
                return
            played(node_id, event, now)

        swarm.net.on_event = on_event
        self._pump(swarm.net.now)

    def observe(self, obs: Observation, delay_s: float) -> None:
        """The autopilot says ``obs``, ``delay_s`` from now."""

        def deliver(now: float) -> None:
            self.core.receive_datagram(obs, None, now)
            self._pump(now)

        self.swarm.net.call_at(self.swarm.net.now + delay_s, deliver)

    def _pump(self, now: float) -> None:
        self.core.datagrams_to_send()
        for event in iter(self.core.next_event, None):
            if isinstance(event, TaskFinished):
                self.swarm.cores[self.name].task_finished(event, now)
                self.swarm.net.poke(self.swarm.ids[self.name])
        timer = self.core.get_timer()
        if timer is not None and self.core.busy():
            self.swarm.net.call_at(timer, self._tick)

    def _tick(self, now: float) -> None:
        self.core.handle_timer(now)
        self._pump(now)


def test_a_land_from_another_commander_supersedes_the_takeoff_and_both_are_told(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Commander A's TAKEOFF is arming on m01 when commander B's LAND arrives. A is told its
    TAKEOFF failed ``superseded: land``; B that its LAND completed (the state shows AUTO.LAND).
    [main: the take-off ran on beside the LAND and A's row said nothing of it]"""
    swarm = _two_commanders(monkeypatch)
    vehicle = RealVehicle(swarm, "m01")
    lead = swarm.cores["lead"]
    sent = swarm.call(
        "lead", lambda now: lead.request_takeoff({"alt_m": 5.0, "only": ["m01"]}, now)
    )
    takeoff = int(sent["command_id"])
    swarm.run(0.3)
    assert vehicle.core.busy() and vehicle.core.last_takeoff is not None
    lead2 = swarm.cores["lead2"]
    sent2 = swarm.call(
        "lead2", lambda now: lead2.request_command({"kind": "land", "only": ["m01"]}, now)
    )
    land = int(sent2["command_id"])
    swarm.run(0.3)
    assert (_row(swarm, "lead", takeoff)["state"], _row(swarm, "lead", takeoff)["reason"]) == (
        "failed",
        "superseded: land",
    )
    # PX4 switches to AUTO.LAND: the LAND is confirmed by state, by a heartbeat received an
    # ack timeout (0.5 s) after NAV_LAND left at least (docs/px4.md, "Fresh state")
    vehicle.observe(Heartbeat(12, 2, 1 | 128, MODE_LAND.custom_mode, MavState.ACTIVE), 0.6)
    swarm.run(3.0)
    assert _row(swarm, "lead2", land)["state"] == "completed"
    assert _row(swarm, "lead", takeoff)["state"] == "failed"  # once, not overwritten
    # the drone's own record: the TAKEOFF failed superseded, the LAND completed
    ran = swarm.cores["m01"].request_outcomes({}, swarm.net.now)["ran"]
    mine = {(r["commander"], r["command_id"]): (r["state"], r["reason"]) for r in ran}
    assert mine[("lead", takeoff)] == ("failed", "superseded: land")
    assert mine[("lead2", land)] == ("completed", "")


def test_a_takeoff_during_a_land_is_refused_busy_and_rejected(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """A TAKEOFF that meets a running LAND never runs: REJECTED ``busy`` (nothing sent)."""
    swarm = _two_commanders(monkeypatch)
    vehicle = RealVehicle(swarm, "m01")
    lead2 = swarm.cores["lead2"]
    swarm.call("lead2", lambda now: lead2.request_command({"kind": "land", "only": ["m01"]}, now))
    swarm.run(0.3)
    assert vehicle.core.busy()
    lead = swarm.cores["lead"]
    sent = swarm.call(
        "lead", lambda now: lead.request_takeoff({"alt_m": 5.0, "only": ["m01"]}, now)
    )
    swarm.run(0.5)
    row = _row(swarm, "lead", int(sent["command_id"]))
    assert (row["state"], row["reason"]) == ("rejected", "busy")
    assert vehicle.core.last_takeoff is None  # no take-off sequence was ever made


# ---- swarmctl's rendering ----------------------------------------------------------------


def test_the_reason_reads_as_words_in_tables_and_stays_exact_in_json() -> None:
    assert superseded_by("superseded: land") == "LAND"
    assert superseded_by("superseded") is None and superseded_by("not_confirmed") is None
    assert superseded_by(None) is None and superseded_by("superseded:") is None
    assert reason_text("superseded: abort") == "superseded by ABORT"
    assert reason_text("busy") == "busy" and reason_text("") == "-"
    tracker = CommandTracker()
    tracker.sent(2, "takeoff", ["uav2"], 0.0, valid_for_s=10.0)
    tracker.record(2, "uav2", CommandResult.FAILED, "superseded: land", 1.0)
    snap = tracker.snapshot(2, 2.0)
    assert snap is not None
    table = "\n".join(render_outcomes(snap))
    assert "FAILED" in table and "superseded by LAND" in table
    assert snap["nodes"]["uav2"]["reason"] == "superseded: land"  # --json: the code


def test_a_drones_superseded_reason_is_escaped_before_the_terminal() -> None:
    """The kind after ``superseded:`` comes from a drone: data, never escape sequences."""
    row = {
        "command_id": 2,
        "kind": "takeoff",
        "commander": "lead",
        "state": "failed",
        "reason": "superseded: \x1b[2Jland",
        "age_s": 1.0,
        "life": 1,
    }
    lines = render_kept({"issued": [], "ran": [row], "life": 1}, 1_700_000_000.0)
    text = "\n".join(lines)
    assert "\x1b" not in text and "superseded by" in text


def test_the_follow_line_says_what_happened_to_the_command(
    capsys: pytest.CaptureFixture[str],
) -> None:
    tracker = CommandTracker()
    tracker.sent(2, "takeoff", ["uav2"], 0.0, valid_for_s=10.0)
    tracker.record(2, "uav2", CommandResult.FAILED, "superseded: land", 1.0)
    snap = tracker.snapshot(2, 12.0)
    assert snap is not None
    args = argparse.Namespace(json=False, timeout=0.0)
    reply = {"command_id": 2, "ready": ["uav2"], "valid_for_s": 10.0}
    run = takeoff_cmd._Run(args)  # noqa: SLF001 - the follow loop, as swarmctl runs it
    code = takeoff_cmd._follow(_Outcomes(snap), run, reply, "takeoff")  # type: ignore[arg-type]  # noqa: SLF001
    out = capsys.readouterr().out
    assert code == 1  # the drone did not take off
    assert "uav2: failed: superseded on the drone by a later LAND" in out
    assert "this TAKEOFF stopped there and sent nothing more" in out
