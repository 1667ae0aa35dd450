"""The clock the validity proof rests on (docs/dataplane.md, "Validity", "The clock").

The member's deadline is never later than the commander's provided each clock measures its
own intervals within 100 ppm (``validity.DRIFT_PPM`` = 200, both summed). CLOCK_MONOTONIC,
``time.monotonic()`` and asyncio's default ``loop.time()``, is slewed by NTP: chrony slews
it up to ``maxslewrate`` 83,333 ppm by default, and the kernel lets ``adjtimex`` move the
tick by +-10 %. So a member on such a clock runs a command late.

- The arithmetic, asserted on the pure rules: a commander clock 8 % fast and a member clock
  8 % slow (each within chrony's default slew) make ``judge`` accept a command about 0.9 s
  after its true deadline (age 0.5 s, valid 10 s), and make ``issued_in_life`` take a
  command issued before the member's life began as issued in it; two clocks within the
  crystal tolerance (+-100 ppm) do neither.
- The property the daemon now has: ``swarmd run`` drives its daemon on an event loop whose
  ``time()`` is CLOCK_MONOTONIC_RAW (the crystal, never slewed; plus the time the host
  slept, tests/test_cmd_suspend.py): ``loop.time()`` read between two raw reads lies
  between them. Not a timing assertion: the two clocks differ
  by whatever NTP has slewed since boot (0.25 s on the build host), and the check is an
  ordering, whatever the speed of the machine.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from swarmd.dataplane.types import Command, CommandKind
from swarmd.dataplane.validity import echo_of, issued_in_life, judge, stamp_ms, valid_ms_of
from tests.daemon_support import loopback_config, run_domain, write_bundle

Clock = Callable[[float], float]  # true seconds -> what a node's clock reads


def _clock(origin_s: float, rate: float) -> Clock:
    return lambda t: origin_s + rate * t


def _dated(
    commander: Clock, member: Clock, report_at: float, issue_at: float, valid_s: float
) -> Command:
    """A TAKEOFF for m01 issued at true ``issue_at``, valid ``valid_s``, dated by m01's
    report sent and received at true ``report_at`` (no transit: the worst case for lateness,
    transit only moves the member's deadline earlier)."""
    echo = echo_of(
        "m01", stamp_ms(member(report_at)), commander(report_at), commander(issue_at), epoch=1
    )
    assert echo is not None
    return Command(1 << 32 | 1, CommandKind.TAKEOFF, 5.0, ["m01"], valid_ms_of(valid_s), [echo])


def _last_run(command: Command, member: Clock, not_before: float, step_s: float = 0.001) -> float:
    """The latest true time (to ``step_s``) at which m01 still accepts ``command``."""
    t = not_before
    while judge(command, "m01", member(t + step_s)).valid:
        t += step_s
        assert t < not_before + 60.0  # bounded: the search never runs away
    return t


SLEWED_FAST = 1.08  # the commander's clock, 8 % fast (chrony's default maxslewrate: 8.3 %)
SLEWED_SLOW = 0.92  # the member's, 8 % slow


def test_slewed_clocks_run_a_command_late() -> None:
    commander, member = _clock(1000.0, SLEWED_FAST), _clock(5000.0, SLEWED_SLOW)
    age_s, valid_s = 0.5, 10.0
    command = _dated(commander, member, 10.0, 10.0 + age_s, valid_s)
    true_deadline = 10.0 + age_s + valid_s
    last = _last_run(command, member, 10.0 + age_s)
    # the member's elapsed time reads 8 % short, the commander's age 8 % long: late by
    # (1.08 age + valid) (1 - 200 ppm) / 0.92 - age - valid = 0.954 s (0.952 s found, ms stamps)
    expected_late = (SLEWED_FAST * age_s + valid_s) * (1 - 200e-6) / SLEWED_SLOW - age_s - valid_s
    assert last - true_deadline == pytest.approx(expected_late, abs=0.003)
    assert last - true_deadline > 0.9  # a run 0.9 s after the command's end: late


def test_slewed_clocks_take_an_earlier_lifes_command_as_this_lifes() -> None:
    """The commander's age reads long, so the lower bound on the issue moves later than the
    issue: a command issued 0.5 s before the member's daemon started (which the lost life
    may have run) passes ``issued_in_life`` (echo age 5 s: up to 0.87 s before does)."""
    commander, member = _clock(1000.0, SLEWED_FAST), _clock(5000.0, SLEWED_SLOW)
    command = _dated(commander, member, 10.0, 15.0, 30.0)
    life_start = 15.5  # true seconds: after the issue
    verdict = issued_in_life(command, "m01", member(life_start), member(16.0))
    assert verdict.valid  # taken as this life's: could run a second time


@pytest.mark.parametrize("commander_ppm", [-100, 0, 100])
@pytest.mark.parametrize("member_ppm", [-100, 0, 100])
def test_clocks_within_the_crystal_tolerance_never_run_late(
    commander_ppm: int, member_ppm: int
) -> None:
    commander = _clock(1000.0, 1 + commander_ppm * 1e-6)
    member = _clock(5000.0, 1 + member_ppm * 1e-6)
    age_s, valid_s = 0.5, 10.0
    command = _dated(commander, member, 10.0, 10.0 + age_s, valid_s)
    assert _last_run(command, member, 10.0 + age_s) <= 10.0 + age_s + valid_s
    # and a command issued before the life began is never taken as this life's
    verdict = issued_in_life(command, "m01", member(10.0 + age_s + 0.002), member(12.0))
    assert not verdict.valid


def _raw() -> float:
    """CLOCK_MONOTONIC_RAW plus the sleep since boot (BOOTTIME minus MONOTONIC, read first:
    ``swarmd.rawclock``'s order, so two reads are ordered as the calls are;
    tests/test_cmd_suspend.py)."""
    boot = time.clock_gettime(time.CLOCK_BOOTTIME)
    monotonic = time.clock_gettime(time.CLOCK_MONOTONIC)
    return time.clock_gettime(time.CLOCK_MONOTONIC_RAW) + (boot - monotonic)


async def _bracket() -> tuple[float, float, float]:
    """``loop.time()`` between two raw reads."""
    loop = asyncio.get_running_loop()
    before = _raw()
    now = loop.time()
    after = _raw()
    return before, now, after


def test_swarmd_run_drives_its_daemon_on_the_raw_clock(
    workdir: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """``swarmd run``'s runner (``swarmd.cli.swarmd_main.main``) with the daemon replaced by
    a probe: the loop it runs the daemon on reads CLOCK_MONOTONIC_RAW, and so does every
    deadline scheduled on it (a ``call_later`` fires once the raw clock has passed it)."""
    import swarmd.daemon
    from swarmd.cli import swarmd_main

    files = write_bundle(workdir, 2, domain_id=run_domain())
    config = loopback_config(workdir, files)
    seen: dict[str, Any] = {}

    async def probe(*_args: Any, **_kwargs: Any) -> int:
        seen["bracket"] = await _bracket()
        loop = asyncio.get_running_loop()
        fired = loop.create_future()
        due = loop.time() + 0.01
        loop.call_at(due, lambda: fired.set_result(_raw()))
        seen["due"], seen["fired"] = due, await fired
        return 0

    monkeypatch.setattr(swarmd.daemon, "run", probe)
    assert swarmd_main.main(["run", "--config", str(config)]) == 0
    before, now, after = seen["bracket"]
    assert before <= now <= after, (before, now, after)
    assert seen["fired"] >= seen["due"]


def test_the_raw_clock_runner_returns_the_result_and_reads_raw() -> None:
    from swarmd.rawclock import run_on_raw_clock

    before, now, after = run_on_raw_clock(_bracket())
    assert before <= now <= after, (before, now, after)
