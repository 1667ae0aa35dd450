"""A command's time echo names the life it dates (docs/dataplane.md, "A life runs only its
own commands"; docs/security.md, "An epoch used twice on a rebooted clock").

``validity.issued_in_life`` proves, on the member's own monotonic clock, that a command was
issued after its daemon started. Where the clocks can line up so that a command of an
earlier life passes that proof, written on virtual time:

- *an OS reboot* (the attack, failing before the echo named its epoch): the monotonic
  clock starts again, so the earlier boot's report stamp can fall, on the new clock,
  between the new daemon's start and now, inside the validity; the member restarted
  without its state file (its executed ids lost), and the earlier boot's command, with its
  original echo, sent again through the data plane ran a second time;
- *a daemon restart* (a guard, passing before and after): one clock, and nothing the
  commander's clock does lines the lives up, even when its ``CLOCK_MONOTONIC`` is slewed
  far past the 200 ppm crystal allowance (``clock_gettime(2)``: "affected by the
  incremental adjustments performed by adjtime(3) and NTP"; chrony slews at up to
  83,333 ppm by default, ``maxslewrate``).

The defence: each ``TimeEcho`` names the member's boot epoch of the report it dates, and a
member refuses (REJECTED ``memory_lost``) an echo of any other epoch than its current one
(``validity.another_life``); the clock rule stays for an epoch used twice.
"""

from __future__ import annotations

import math

import pytest

from swarmd.dataplane.types import Command, CommandKind, CommandResult, TimeEcho
from swarmd.dataplane.validity import EXPIRED, MEMORY_LOST, another_life, stamp_ms
from swarmd.px4.vehicle import DisarmUnconfirmed, TaskFinished, VehicleRequest
from swarmd.swarm.core import SwarmCore, SwarmSettings
from swarmd.swarm.events import CommandBeforeLife, OutcomeReported
from swarmd.swarm.roles import Roles
from tests.test_cmd_in_flight import Flight
from tests.test_dataplane_swarm import address_of, make_plane
from tests.test_swarm_core import Swarm


class ClockedCore(SwarmCore):
    """A ``SwarmCore`` on its own host's monotonic clock: ``offset + rate * t`` at the
    network's virtual time ``t`` (every driving input converted, the timer converted back)."""

    offset_s: float = 0.0
    rate: float = 1.0

    def local(self, now: float) -> float:
        return self.offset_s + self.rate * now

    def start(self, now: float) -> None:
        super().start(self.local(now))

    def receive_datagram(self, data: bytes, source: tuple[str, int], now: float) -> None:
        super().receive_datagram(data, source, self.local(now))

    def handle_timer(self, now: float) -> None:
        super().handle_timer(self.local(now))

    def get_timer(self) -> float | None:
        deadline = super().get_timer()
        if deadline is None:
            return None
        # rounded up, so that the converted fire time reaches the deadline
        return math.nextafter((deadline - self.offset_s) / self.rate, math.inf) + 1e-9

    def peer_up(self, name: str, locator: tuple[str, int] | None, epoch: int, now: float) -> None:
        super().peer_up(name, locator, epoch, self.local(now))

    def peer_down(self, name: str, now: float) -> None:
        super().peer_down(name, self.local(now))

    def task_finished(self, done: TaskFinished | DisarmUnconfirmed, now: float) -> None:
        super().task_finished(done, self.local(now))


def _clocked(
    flight: Flight,
    name: str,
    *,
    epoch: int,
    epochs: dict[str, int],
    offset_s: float = 0.0,
    rate: float = 1.0,
) -> ClockedCore:
    """``name``'s daemon starts (again) in boot ``epoch``, without any state file, on a
    clock reading ``offset_s + rate * t``; discovery on both sides reports it (the others in
    ``epochs``)."""
    swarm = flight.swarm
    bundle = swarm.bundle
    vehicle = swarm.vehicles[name]
    core = ClockedCore(
        Roles.of(bundle, bundle.participant(name)),
        make_plane(bundle, name, epoch=epoch, incarnation=epoch - 1),
        verdict=None if name == "lead" else vehicle.verdict_at,
        link_q=lambda: 0.8,
        settings=SwarmSettings(readiness_period_s=0.5, stale_after_s=3.0),
    )
    core.offset_s = offset_s
    core.rate = rate
    swarm.cores[name] = core
    now = swarm.net.now
    core.start(now)
    swarm.net.replace(swarm.ids[name], core)
    for other in swarm.cores:
        if other != name:
            core.peer_up(other, address_of(bundle, other), epochs[other], now)
            swarm.cores[other].peer_up(name, address_of(bundle, name), epoch, now)
            swarm.net.poke(swarm.ids[other])
    swarm.net.poke(swarm.ids[name])
    return core


def _send(flight: Flight, command: Command) -> None:
    """The commander's plane sends ``command`` (first issue or a resend of the same id)."""
    swarm = flight.swarm
    lead = swarm.lead
    plane = lead.plane
    assert plane is not None
    local = lead.local if isinstance(lead, ClockedCore) else (lambda t: t)
    swarm.call("lead", lambda now: plane.send_command(command, local(now)))


def _takeoff(flight: Flight) -> Command:
    """A TAKEOFF for m01, valid 30 s, dated by m01's last report the commander holds."""
    lead = flight.swarm.lead
    plane = lead.plane
    assert plane is not None
    now = flight.swarm.net.now
    local = lead.local(now) if isinstance(lead, ClockedCore) else now
    return plane.make_command(
        CommandKind.TAKEOFF,
        altitude_m=5.0,
        targets=["m01"],
        valid_ms=30_000,
        echoes=plane.time_echoes(["m01"], local),
    )


def _refused_memory_lost(flight: Flight, cid: int) -> bool:
    return any(
        isinstance(e, OutcomeReported)
        and e.command_id == cid
        and (e.result, e.reason) == (CommandResult.REJECTED, MEMORY_LOST)
        for e in flight.swarm.events["m01"]
    )


def test_an_earlier_boots_command_never_runs_again_when_the_new_clock_passes_its_stamp() -> None:
    """m01 runs a TAKEOFF (valid 30 s), then its OS reboots: its monotonic clock starts
    again and its state file is lost. The new clock is such that it passes the earlier
    boot's echoed stamp (plus the commander's age) 1 s after the new daemon started. The
    same command, its original echo, is sent again 3 s after the restart: on the new clock
    the earlier boot's report is 2 s old and was sent after this life began. It must be
    refused (``memory_lost``): the earlier boot ran it."""
    flight = Flight(1, seed=51)
    swarm = flight.swarm
    swarm.run(3.0)
    old = _takeoff(flight)
    (echo,) = old.echoes
    _send(flight, old)
    swarm.run(0.5)
    assert len(flight.ran("m01", old.command_id)) == 1
    # the OS reboot: the new clock reads 1 s before the old echo's issue bound at the start
    issue_bound_s = (echo.stamp_ms + echo.age_ms) / 1000.0
    reboot = _clocked(
        flight, "m01", epoch=2, epochs={"lead": 1}, offset_s=issue_bound_s - 1.0 - swarm.net.now
    )
    swarm.run(3.0)
    assert reboot.local(swarm.net.now) > issue_bound_s + 1.5  # the coincidence holds
    _send(flight, old)
    swarm.run(3.0)
    assert len(flight.ran("m01", old.command_id)) == 1
    assert _refused_memory_lost(flight, old.command_id)
    new = _takeoff(flight)  # a command of the new life runs
    _send(flight, new)
    swarm.run(3.0)
    assert len(flight.ran("m01", new.command_id)) == 1


def test_a_daemon_restart_cannot_line_the_clocks_up_even_under_a_slewed_commander_clock() -> None:
    """Guard (passes before and after the echo's epoch): on one host's monotonic clock the
    clocks cannot line up. The earlier life ran a copy only if its bound ``stamp + age`` was
    at or before its receipt, which is before the restart, so the restarted life refuses it
    whatever the commander's clock did. Tried with the worst the commander's clock can do:
    it runs 5 % fast (an NTP slew), and m01's reports are lost for 8 s, so the echo's age
    reads 8.4 s for 8 s and the bound lies 0.4 s after the true issue. A copy that arrives
    before the bound is refused (fail closed: an honest command lost, not one run twice);
    one held back past it (the link from the commander cut for 0.6 s) runs, then m01's
    daemon restarts without its state file and the same command is sent again: refused."""
    flight = Flight(1, seed=52)
    swarm = flight.swarm
    _clocked(flight, "lead", epoch=2, epochs={"m01": 1}, rate=1.05)
    swarm.run(3.0)
    flight.cut = lambda a, b: a == "m01"  # what m01 sends is lost from now on
    swarm.run(8.0)
    early = _takeoff(flight)
    _send(flight, early)
    swarm.run(0.1)
    assert flight.ran("m01", early.command_id) == []  # before its bound: refused
    assert _refused_memory_lost(flight, early.command_id)
    old = _takeoff(flight)
    flight.cut = lambda a, b: True  # both ways, for 0.6 s
    _send(flight, old)
    swarm.run(0.6)
    flight.cut = lambda a, b: a == "m01"
    swarm.run(0.3)  # the commander's repair delivers it past the bound
    assert len(flight.ran("m01", old.command_id)) == 1
    _clocked(flight, "m01", epoch=2, epochs={"lead": 2})  # a daemon restart: the same clock
    flight.cut = lambda a, b: False
    swarm.run(1.0)
    _send(flight, old)
    swarm.run(3.0)
    assert len(flight.ran("m01", old.command_id)) == 1
    assert _refused_memory_lost(flight, old.command_id)


# ---- the rule, on one member ------------------------------------------------------------------


def _dated(stamp: int, age_ms: int, epoch: int, valid_ms: int = 30_000) -> Command:
    echo = TimeEcho("m01", stamp, age_ms, epoch)
    return Command(7, CommandKind.TAKEOFF, 5.0, ["m01"], valid_ms, [echo])


def _verdict(life_s: float, command: Command, now: float) -> tuple[bool, str, str]:
    """m01 (boot epoch 1, its daemon started at ``life_s``) takes ``command`` from the
    commander at ``now``: (ran, reason of its answer, detail of a memory_lost refusal)."""
    member = Swarm(1).cores["m01"]
    member.start(life_s)
    member.handle_timer(life_s + 0.5)  # its report stamped life + 0.5 s (its report log)
    member._execute("lead", command, now)
    events = list(iter(member.next_event, None))
    ran = any(isinstance(e, VehicleRequest) for e in events)
    reasons = [e.reason for e in events if isinstance(e, OutcomeReported)]
    details = [e.detail for e in events if isinstance(e, CommandBeforeLife)]
    return ran, reasons[-1] if reasons else "", details[0] if details else ""


def test_another_life_reads_the_echo_for_this_member_only() -> None:
    assert another_life(_dated(0, 0, 1), "m01", 1) is None
    assert another_life(_dated(0, 0, 1), "m01", 2) is not None  # an earlier life's
    assert another_life(_dated(0, 0, 3), "m01", 2) is not None  # no life of ours yet
    assert another_life(_dated(0, 0, 1), "m02", 2) is None  # no echo for m02: judge's
    bare = Command(7, CommandKind.TAKEOFF, 5.0, ["m01"], 3000, [])
    assert another_life(bare, "m01", 2) is None


@pytest.mark.parametrize("echo_epoch", [0, 2, 2**32 - 1])
def test_an_echo_of_another_epoch_is_refused_even_when_the_clock_would_pass_it(
    echo_epoch: int,
) -> None:
    """The echo's stamp and age date the issue 1 s after this life began and 1 s before
    now, well inside its validity: the clock rules pass it; the epoch refuses it."""
    life, now = 100.0, 102.0
    ran, reason, detail = _verdict(life, _dated(stamp_ms(life + 0.5), 500, echo_epoch), now)
    assert (ran, reason) == (False, MEMORY_LOST)
    assert f"epoch {echo_epoch}" in detail
    ran, reason, _ = _verdict(life, _dated(stamp_ms(life + 0.5), 500, 1), now)
    assert (ran, reason) == (True, "")  # the same copy dated by this life: runs


def test_an_echo_of_another_epoch_says_memory_lost_even_when_late() -> None:
    """Checked first: another life's stamp is on a clock that says nothing about lateness
    here, so the answer is what the member knows: it was issued to an earlier life."""
    life, now = 100.0, 200.0
    ran, reason, _ = _verdict(life, _dated(stamp_ms(life), 0, 0, valid_ms=1000), now)
    assert (ran, reason) == (False, MEMORY_LOST)
    ran, reason, _ = _verdict(life, _dated(stamp_ms(life), 0, 1, valid_ms=1000), now)
    assert (ran, reason) == (False, EXPIRED)  # this life's echo: late, as before


def test_a_reused_epoch_still_meets_the_clock_rule() -> None:
    """Why ``issued_in_life`` stays: a node whose epoch file is lost and whose wall clock
    reads the same seconds again (no RTC, no NTP: ``swarmd.auth.epoch``) may start a life
    in an epoch it had before. A copy dated by a report of that earlier life (2 s before
    this one began) names this epoch, and is refused by this life's clock."""
    life, now = 100.0, 101.0
    ran, reason, detail = _verdict(life, _dated(stamp_ms(life - 2.0), 500, 1), now)
    assert (ran, reason) == (False, MEMORY_LOST)
    assert "this life began" in detail  # the clock rule's refusal, not the epoch's


def test_the_commander_echoes_the_epoch_it_authenticated_the_report_under() -> None:
    """``time_echoes`` names the member's boot epoch of the echoed report: 1, then 2 once
    the restarted member's first report of its new life arrived (none in between)."""
    flight = Flight(1, seed=53)
    swarm = flight.swarm
    swarm.run(3.0)
    plane = swarm.lead.plane
    assert plane is not None
    assert [e.epoch for e in plane.time_echoes(["m01"], swarm.net.now)] == [1]
    _clocked(flight, "m01", epoch=7, epochs={"lead": 1})
    assert plane.time_echoes(["m01"], swarm.net.now) == []
    swarm.run(1.0)
    assert [e.epoch for e in plane.time_echoes(["m01"], swarm.net.now)] == [7]
