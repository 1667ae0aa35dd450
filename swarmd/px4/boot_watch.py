"""Has PX4 rebooted behind the MAVLink link? Its boot clock says so (``time_boot_ms``).

Theory of operation
-------------------
Over XRCE-DDS a rebooted PX4 opens a new session, and the translator hands the vehicle
state a ``StateReset``. MAVLink has no session. What a rebooted PX4 does say is its boot
clock: ATTITUDE, ATTITUDE_QUATERNION, LOCAL_POSITION_NED, GLOBAL_POSITION_INT and
SYSTEM_TIME carry ``time_boot_ms``, "Timestamp (time since system boot)" (MAVLink
common.xml), which starts again near zero at every boot. PX4's ONBOARD mode streams the
first four at 30..100 Hz and SYSTEM_TIME at 1 Hz (``mavlink_main.cpp``). ``BootWatch``
judges each batch of frames the backend accepted (one UDP datagram, or one read of the UART):

- **one clock per message**: each message keeps its own last value, because PX4 stamps
  each with its own sample's time (an ATTITUDE may be a few ms newer than the
  GLOBAL_POSITION_INT sent after it). Within one message the time only grows.
- **a clear jump back**: a new life when a message's time goes back by more than
  ``REBOOT_JUMP_MS`` (1 s). A smaller step back is a frame that came late (UDP may reorder;
  on one loopback or serial path frames are milliseconds apart), never a reboot, and the
  newest value is kept. A new life's first frames carry PX4's boot time (seconds), so the
  jump is the last life's uptime less that: any life that ran for more than its boot time
  plus 1 s is told apart.
- **wrap**: uint32 ms wraps after 2^32 ms (49.7 days). A value that went back where the
  same life, counted forward on our monotonic clock since its last value, would have
  passed 2^32 is the wrap, not a reboot.
- **after a silence**: a PX4 that reboots is silent while it boots. After ``SILENCE_S``
  (2.5 s, readiness' heartbeat timeout: the state is already ``heartbeat_stale``) with no
  frame, the next frames may be a new life's. The first boot clock must then be where the
  same life's would be now (its last value plus the silence counted on our clock, less
  the jump), else it is a new life: this tells apart a life shorter than the next one's
  boot, which the jump back alone would not. A clock past the last value and past the
  silence itself is the same life too: a new one booted within the silence, and these are
  frames that waited in our buffer while the daemon's loop stalled (a suspend, a long
  callback). Until a boot clock comes, a batch without one is dropped (counted), so a
  rebooted PX4's first HEARTBEAT never meets the last life's landed state; it costs at
  most one heartbeat after a silence. If no boot clock comes
  within ``UNDECIDED_MAX_S`` (a firmware that streams none), whose life it is stays
  unknown: a reset, the safe side, and frames flow again.

Only frames the link already trusts reach it: the backend checks the system and
component, the pinned address and, with signing, the signature and its freshness first
(``mavlink_backend.MavlinkIntake``). A forged, replayed or foreign frame moves nothing here.

Pure: ``now`` is the caller's monotonic seconds.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Final

from swarmd.px4.readiness import DEFAULT_HEARTBEAT_TIMEOUT_S

BOOT_CLOCK_WRAP: Final = 1 << 32  # time_boot_ms is a uint32 (MAVLink common.xml)
REBOOT_JUMP_MS: Final = 1000  # back by more than this: a new life (module docstring)
SILENCE_S: Final = DEFAULT_HEARTBEAT_TIMEOUT_S  # quiet this long: the next life is unknown
UNDECIDED_MAX_S: Final = 2.0  # 2 x SYSTEM_TIME's period: no boot clock by then, reset


@dataclass(frozen=True, slots=True)
class LifeVerdict:
    """What to do with one batch: deliver it (after a ``StateReset`` when ``reset`` says
    why), or drop it (``deliver`` False: after a silence, no boot clock yet)."""

    deliver: bool
    reset: str | None = None


@dataclass(slots=True)
class BootWatch:
    """One autopilot's boot clock, per message (see the module docstring)."""

    silence_s: float = SILENCE_S
    jump_ms: int = REBOOT_JUMP_MS
    undecided_max_s: float = UNDECIDED_MAX_S
    # message -> (its newest time_boot_ms, when we received it)
    clocks: dict[str, tuple[int, float]] = field(default_factory=dict)
    last_at: float | None = None  # the last trusted batch
    undecided_since: float | None = None  # a silence ended here, no boot clock since
    last_reset: str | None = None
    counts: dict[str, int] = field(
        default_factory=lambda: {
            "resets": 0,  # new lives told (and unknown lives after a silence)
            "late": 0,  # a message's time went back less than the jump: reordered, kept
            "wraps": 0,  # the uint32 wrapped within one life
            "dropped_after_silence": 0,  # frames of a batch no boot clock could place yet
        }
    )

    def batch(self, clocks: Sequence[tuple[str, int]], frames: int, now: float) -> LifeVerdict:
        """Judge ``frames`` trusted frames received at ``now``, whose boot clocks, in
        order, are ``clocks`` (message name, ``time_boot_ms``)."""
        quiet = self.last_at is not None and now - self.last_at >= self.silence_s
        self.last_at = now
        if quiet and self.undecided_since is None:
            self.undecided_since = now
        reset: str | None = None
        for message, time_boot_ms in clocks:
            # after a reset the batch's later clocks are the new life's first values
            why = self._judge(message, time_boot_ms, now, self.undecided_since is not None)
            reset = reset or why
            self.undecided_since = None  # the boot clock has placed this batch
        if reset is not None:
            return self._reset(reset)
        if self.undecided_since is None:
            return LifeVerdict(True)
        if now - self.undecided_since >= self.undecided_max_s:
            self.undecided_since = None
            return self._reset(
                f"no boot clock {self.undecided_max_s:g} s after a silence of "
                f">= {self.silence_s:g} s: the life is unknown"
            )
        self.counts["dropped_after_silence"] += frames
        return LifeVerdict(False)

    def stats(self) -> dict[str, object]:
        return {**self.counts, "last_reset": self.last_reset}

    def _reset(self, why: str) -> LifeVerdict:
        self.counts["resets"] += 1
        self.last_reset = why
        return LifeVerdict(True, why)

    def _judge(self, message: str, time_boot_ms: int, now: float, silence: bool) -> str | None:
        """Why ``message`` at ``time_boot_ms`` is a new life, or None (the same one).
        ``silence``: the first boot clock after a silence (module docstring)."""
        own = self.clocks.get(message)
        # a message not heard yet (GLOBAL_POSITION_INT once a fix comes) is judged against
        # the newest other one: it carries the same clock, a little older at most
        ref = own if own is not None else self._newest()
        if ref is None:
            self.clocks[message] = (time_boot_ms, now)
            # after a silence, with nothing of the last life to compare: unknown, reset
            return "a boot clock after a silence, none before it to compare" if silence else None
        last_ms, last_at = ref
        # where the same life's clock would be now, counted on ours
        expected = last_ms + round((now - last_at) * 1000)
        late = False
        if silence:
            same = self._kept_time(time_boot_ms, expected) or self._waited_in_a_buffer(
                time_boot_ms, last_ms, now - last_at
            )
        elif time_boot_ms >= last_ms:
            same = True
        elif last_ms - time_boot_ms <= self.jump_ms:
            self.counts["late"] += 1  # reordered: the same life, its newest value kept
            same = late = True
        else:
            same = expected + self.jump_ms >= BOOT_CLOCK_WRAP and (
                time_boot_ms <= expected + self.jump_ms - BOOT_CLOCK_WRAP
            )
            self.counts["wraps"] += same
        if same:
            if own is None or not late:
                self.clocks[message] = (time_boot_ms, now)
            return None
        # a new life: every message's clock starts over from its first frame
        self.clocks.clear()
        self.clocks[message] = (time_boot_ms, now)
        if silence:
            return (
                f"PX4 rebooted: {message}.time_boot_ms {time_boot_ms} after a silence, "
                f"where its last life would say {expected % BOOT_CLOCK_WRAP}"
            )
        return f"PX4 rebooted: {message}.time_boot_ms went back from {last_ms} to {time_boot_ms}"

    def _newest(self) -> tuple[int, float] | None:
        """The boot clock heard last, of any message."""
        return max(self.clocks.values(), key=lambda clock: clock[1], default=None)

    def _waited_in_a_buffer(self, time_boot_ms: int, last_ms: int, quiet_s: float) -> bool:
        """After a silence: a frame of the same life that waited in our socket or UART
        buffer while the daemon's loop stalled (its clock is where it was sent, behind
        ``expected``). A new life booted within the silence, so its clock cannot be past
        the silence (the jump allowed for a late last frame), nor, unless the last life
        was shorter than that, past the last life's value: a clock past both is the same
        life (tests/test_px4_reboot.py, the stall)."""
        return time_boot_ms >= last_ms and time_boot_ms > quiet_s * 1000 + self.jump_ms

    def _kept_time(self, time_boot_ms: int, expected: int) -> bool:
        """After a silence: did this clock run on through it? The same life's is near
        ``expected`` (the wrap allowed for); a new life's counts from its boot, which began
        during the silence, so it is behind by the last life's uptime."""
        if time_boot_ms + self.jump_ms >= expected:
            return True
        wrapped = time_boot_ms + BOOT_CLOCK_WRAP  # the same life, past 2^32 meanwhile
        if expected + self.jump_ms >= BOOT_CLOCK_WRAP and abs(wrapped - expected) <= self.jump_ms:
            self.counts["wraps"] += 1
            return True
        return False
