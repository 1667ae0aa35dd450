"""A TAKEOFF never starts after its command's validity (docs/dataplane.md, "Validity at the
vehicle"; session 17).

The member judges a command's validity when it decides; the vehicle request then waits for
the state write (every write asked before it: ``SwarmApp._vehicle_request``), 0.3-1 s on a
slow SD card, much longer on a dying one. On main nothing judged it again, so a TAKEOFF
decided at the end of its validity took off when the write ended, after the operator had
been told it could no longer run. Now the request carries ``not_after`` (the validity end
on the member's clock) and the vehicle core, the last step before a frame goes to PX4,
refuses a TAKEOFF reaching it at or after that: no frame, ``expired_before_start`` to the
commander. LAND, HOLD and ABORT still run late (``vehicle.EXPIRES``: they only stop).

Here: the vehicle core on virtual time against the simulated PX4 (``Bench``), the swarm on
``MemNet`` with one member's requests held past the validity and handed to a real
``VehicleCore``, and the real daemon (the commander's own drone, its MAVLink simulator)
with the state write blocked on a gate that opens after the validity's end. The last two
fail on main: the take-off ran (armed, completed). No timing is asserted.
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from swarmd_lab.px4.sim_model import SimConfig
from swarmd_lab.px4.vehicle_sim import start_sim

from swarmd import statefile
from swarmd.cli.takeoff_cmd import render_outcomes
from swarmd.px4.constants import LandedState
from swarmd.px4.takeoff import FailReason, TakeoffFailed
from swarmd.px4.transport import parse_connection
from swarmd.px4.vehicle import EXPIRES, TaskKind, VehicleRequest
from swarmd.rawclock import run_on_raw_clock
from swarmd.swarm.events import PersistExecuted, SwarmEvent
from tests.daemon_support import (
    BundleFiles,
    loopback_daemon,
    run_domain,
    swarm_sections,
    write_bundle,
)
from tests.test_px4_vehicle import Bench
from tests.test_save_off_loop import SlowDisk, _app, _until
from tests.test_swarm_core import Swarm
from tests.test_takeoff_loopback import N, _mavlink_port

EXPIRED_BEFORE_START = str(FailReason.EXPIRED_BEFORE_START)
VALID_FOR_S = 1.0  # the TAKEOFF's validity in the swarm tests
STALL_S = 2.5  # how long m01's state write holds its requests: past the validity


# ---- the vehicle core, virtual time --------------------------------------------------------


def test_a_takeoff_reaching_the_vehicle_at_its_validity_end_sends_nothing() -> None:
    """Decided valid, arriving at ``not_after`` (the first instant it no longer is): no
    ARM, no TakeoffSequence, a refusal the member reports, and the vehicle stays quiet."""
    b = Bench()
    b.run(3.0)
    assert b.core.readiness(b.now).ready
    b.core.request(VehicleRequest(1, TaskKind.TAKEOFF, 4.0, ("lead", 7), b.now), b.now)
    b._pump_core()
    done = b.finished(1)
    assert done is not None and (done.ok, done.reason) == (False, EXPIRED_BEFORE_START)
    assert isinstance(done.outcome, TakeoffFailed)
    assert done.outcome.reason is FailReason.EXPIRED_BEFORE_START
    assert b.sent == [] and b.core.last_takeoff is None and not b.core.busy()
    b.run(5.0)
    assert b.sent == [] and b.sim.landed == LandedState.ON_GROUND


def test_a_takeoff_reaching_the_vehicle_within_its_validity_flies() -> None:
    """``not_after`` bounds the frames, not the outcome: a take-off whose ARM and
    NAV_TAKEOFF left in time (the ARM answered 10 ms after it, NAV_TAKEOFF at once) runs to
    its end past it (session 18: every frame is bounded, ``tests/test_takeoff_not_after.py``)."""
    b = Bench()
    b.run(3.0)
    not_after = b.now + 0.05
    b.core.request(VehicleRequest(1, TaskKind.TAKEOFF, 4.0, None, not_after), b.now)
    b._pump_core()
    b.run(30.0, stop=lambda: b.finished(1) is not None)
    done = b.finished(1)
    assert done is not None and done.ok, done
    assert b.now > not_after  # it ran on past the validity end, as it should


@pytest.mark.parametrize("kind", [TaskKind.LAND, TaskKind.HOLD, TaskKind.ABORT])
def test_a_stop_action_reaching_the_vehicle_after_its_validity_still_runs(kind: TaskKind) -> None:
    """LAND, HOLD and ABORT only stop the vehicle, and the member accepted them: refusing
    one late would leave the drone flying on (``vehicle.EXPIRES``)."""
    assert kind not in EXPIRES
    b = Bench()
    b.fly()
    before = len(b.sent)
    b.core.request(VehicleRequest(2, kind, None, ("lead", 8), b.now - 5.0), b.now)
    b._pump_core()
    b.run(30.0, stop=lambda: b.finished(2) is not None)
    done = b.finished(2)
    assert done is not None and done.ok and done.reason != EXPIRED_BEFORE_START, done
    assert len(b.sent) > before


# ---- the swarm on MemNet: a member's write holds the request past the validity -------------


class StalledMember(Swarm):
    """m01's vehicle requests reach a real ``VehicleCore`` (flying the simulated PX4,
    ``Bench``, ready) only ``STALL_S`` after the member decided (its state write on a dying
    card); the vehicle's ``TaskFinished`` goes back to the member's core. Every other
    member's vehicle is played as in ``Swarm``."""

    def __init__(self) -> None:
        self.bench = Bench()
        self.held: list[VehicleRequest] = []
        super().__init__(3, seed=17)

    def _on_event(self, node_id: int, event: SwarmEvent, now: float) -> None:
        if isinstance(event, VehicleRequest) and node_id == self.ids["m01"]:
            self.held.append(event)
            self.events["m01"].append(event)
            self.net.call_at(now + STALL_S, self._release(event))
            return
        super()._on_event(node_id, event, now)

    def _release(self, request: VehicleRequest) -> Callable[[float], None]:
        def release(now: float) -> None:
            bench = self.bench
            bench.run(now - bench.now)  # the simulated PX4 lived on meanwhile: ready
            assert bench.core.readiness(now).ready
            bench.core.request(request, now)
            bench._pump_core()
            done = bench.finished(request.token)
            if done is not None:
                self.cores["m01"].task_finished(done, now)
                self.net.poke(self.ids["m01"])

        return release


def test_a_takeoff_held_past_its_validity_never_starts_and_the_operator_is_told() -> None:
    """On main m01's vehicle started the take-off 2.5 s into a 1 s validity; now it refuses
    it, and the commander's row (what ``swarmctl takeoff`` prints) says why."""
    swarm = StalledMember()
    swarm.run(3.0)
    sent_at = swarm.net.now
    request: dict[str, Any] = {"alt_m": 5.0, "valid_for_s": VALID_FOR_S}
    sent = swarm.call("lead", lambda now: swarm.lead.request_takeoff(request, now))
    assert sent["sent"] and sorted(sent["ready"]) == ["m01", "m02", "m03"], sent
    cid = int(sent["command_id"])
    snap = swarm.run_until_done(cid)
    nodes = snap["nodes"]
    assert (nodes["m01"]["state"], nodes["m01"]["reason"]) == ("rejected", EXPIRED_BEFORE_START)
    assert nodes["m02"]["state"] == nodes["m03"]["state"] == "completed"
    # decided within the validity, its end dated on the member's clock never later than
    # the commander's (MemNet: one clock for all)
    (held,) = swarm.held
    assert held.kind is TaskKind.TAKEOFF and held.origin == ("lead", cid)
    assert held.not_after is not None and sent_at < held.not_after <= sent_at + VALID_FOR_S
    assert swarm.bench.sent == [] and swarm.bench.core.last_takeoff is None
    (m01,) = [row for row in render_outcomes(snap) if "m01" in row]
    assert "REJECTED" in m01 and EXPIRED_BEFORE_START in m01


def test_the_commanders_own_drone_dates_its_request_from_the_issue() -> None:
    """The commander's own drone runs a command at issue (``run_own``): its validity ends
    ``valid_for_s`` after now, on the same clock."""
    swarm = Swarm(1, seed=17, lead_vehicle=True)
    swarm.run(3.0)
    request: dict[str, Any] = {"kind": "takeoff", "alt_m": 5.0, "only": ["lead"]}
    request["valid_for_s"] = VALID_FOR_S
    issued_at = swarm.net.now
    sent = swarm.call("lead", lambda now: swarm.lead.request_command(request, now))
    assert sent["sent"], sent
    (own,) = swarm.requests("lead")
    assert own.not_after == pytest.approx(issued_at + VALID_FOR_S)
    assert own.kind is TaskKind.TAKEOFF


# ---- the real daemon: the state write blocked past the validity ---------------------------


@pytest.fixture
def files(workdir: Path) -> BundleFiles:
    return write_bundle(workdir, 2, domain_id=run_domain(), lease_s=20.0)


def test_a_real_daemons_takeoff_held_by_a_blocked_write_past_its_validity_never_starts(
    workdir: Path, files: BundleFiles, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The commander's own drone (uav1, the MAVLink simulator on loopback): an earlier
    decision's state write is blocked on a gate, so the TAKEOFF the operator then sends
    waits behind it (the write-ahead). The gate opens only after the command's validity
    has ended on the loop's clock. On main the take-off then started (ARM, lift-off,
    ``completed``); now the vehicle refuses it and the commander's row says
    ``expired_before_start``."""

    async def main() -> None:
        port = _mavlink_port(N + 1)  # beyond the ports the loopback tests use
        extra = swarm_sections(workdir / "state", f"udpin:127.0.0.1:{port}", period_s=0.5)
        daemon = loopback_daemon(workdir, files, "uav1", extra=extra)
        await daemon.start()
        endpoint = parse_connection(f"udpout:127.0.0.1:{port}")
        sim = await start_sim(SimConfig(sysid=1, gps_fix_after_s=0.2), endpoint, seed=0)
        app = _app(daemon)
        state = app.state
        assert state is not None
        disk = SlowDisk(state.path.name)
        monkeypatch.setattr(statefile, "write_atomic", disk)
        try:
            bridge = app.bridge
            assert bridge is not None
            await _until(lambda: daemon.status()["readiness"]["uav1"]["ready"], "ready")
            disk.armed = True
            app._on_event(PersistExecuted((("uav2", 1),), command=("uav2", 1)))
            await _until(lambda: disk.log == ["write_started"], "the write blocked")
            sent = app.request_command(
                {"kind": "takeoff", "only": ["uav1"], "alt_m": 5.0, "valid_for_s": 0.2}
            )
            assert sent["sent"], sent
            cid = sent["command_id"]
            end = app._driver().now() + 0.2
            loop = asyncio.get_running_loop()

            def open_after_the_validity() -> None:
                if loop.time() > end:
                    disk.gate.set()
                    return
                loop.call_later(0.05, open_after_the_validity)

            open_after_the_validity()
            await _until(lambda: app.request_outcomes({"command_id": cid})["done"], "done")
            node = app.request_outcomes({"command_id": cid})["nodes"]["uav1"]
            assert (node["state"], node["reason"]) == ("rejected", EXPIRED_BEFORE_START), node
            assert disk.log == ["write_started", "written"]
            assert bridge.core.last_takeoff is None and bridge.core.last_arm_at is None
            assert not sim.model.armed
        finally:
            disk.gate.set()
            sim.close()
            await daemon.stop("test")

    run_on_raw_clock(main())
