"""The engine's phases and every transition between them, in one table (h11 style).

BOOT     waiting for the first link-quality sample (paper section 4.1: the passive timer
         is drawn from it); a timeout falls back to the configured default Q.
PASSIVE  the passive timer runs: listen, never multicast; answer bundle peers that do not
         list us yet with a directed (INFO_DST) DATA(p).
ANNOUNCE the timer expired and someone still needs to hear us: staged announcements with
         backoff, multicast when several peers need it, directed otherwise.
STEADY   every bundle peer lists us (or gave up answering): lease renewals only, plus
         single directed answers to peers that come back.
STOPPED  DATA(p[UD]) queued; the engine ignores all further input.

Any transition not in ``TRANSITIONS`` is a bug in the engine, not bad input.
"""

from __future__ import annotations

from enum import StrEnum
from typing import Final


class Phase(StrEnum):
    BOOT = "boot"
    PASSIVE = "passive"
    ANNOUNCE = "announce"
    STEADY = "steady"
    STOPPED = "stopped"


class Trigger(StrEnum):
    LINK_READ = "link_read"  # first link sample, or the boot timeout with the default Q
    TIMER_EXPIRED_NEEDED = "timer_expired_needed"  # passive timer over, someone needs us
    TIMER_EXPIRED_SETTLED = "timer_expired_settled"  # passive timer over, nothing left to do
    SETTLED = "settled"  # every bundle peer lists us, or we gave up on the rest
    SHUTDOWN = "shutdown"


TRANSITIONS: Final[dict[tuple[Phase, Trigger], Phase]] = {
    (Phase.BOOT, Trigger.LINK_READ): Phase.PASSIVE,
    (Phase.PASSIVE, Trigger.TIMER_EXPIRED_NEEDED): Phase.ANNOUNCE,
    (Phase.PASSIVE, Trigger.TIMER_EXPIRED_SETTLED): Phase.STEADY,
    (Phase.ANNOUNCE, Trigger.SETTLED): Phase.STEADY,
    (Phase.BOOT, Trigger.SHUTDOWN): Phase.STOPPED,
    (Phase.PASSIVE, Trigger.SHUTDOWN): Phase.STOPPED,
    (Phase.ANNOUNCE, Trigger.SHUTDOWN): Phase.STOPPED,
    (Phase.STEADY, Trigger.SHUTDOWN): Phase.STOPPED,
}


class TransitionError(RuntimeError):
    """Raised for a (phase, trigger) pair the table lacks: always an engine bug."""


def next_phase(phase: Phase, trigger: Trigger) -> Phase:
    try:
        return TRANSITIONS[(phase, trigger)]
    except KeyError:
        raise TransitionError(f"no transition from {phase} on {trigger}") from None
