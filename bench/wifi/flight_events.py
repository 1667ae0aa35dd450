"""The stock contenders' flight events (issue 20), pure: peer log lines to per-pair changes.

Every stock peer run with ``--events 1`` writes one JSON line per event on its stdout, which
the harness points at ``peer-<i>.log`` (``bench/wifi/peers/common.py``, ``FlightEvents``):

    {"flight": "hello", "t": T, "self": I}                       a new life of peer I
    {"flight": "up", "t": T, "peer": J, "key": K}                remote instance K (drone J) alive
    {"flight": "down", "t": T, "peer": J, "key": K}              remote instance K gone
    {"flight": "readiness", "t": T, "counts": {"J": C, ...}}     the commander's tally

``T`` is the peer's own wall clock, which under time dilation reads the run's experiment
clock as the harness's ``Dilation.exp`` does. ``PeerEvents`` turns them into the records
swarmd's status polls give (``flight_run.SwarmdObserver``): per observer ``(t, peer,
change)`` with change ``discovered`` (first time in this life), ``regained`` (after a
``lost``) or ``lost``, and the commander's readiness ``(t, {member: count})``. A drone is
listed while at least one of its instances is up: after a reboot its new participant comes
up while the old one's lease runs out, and that late ``down`` is not a loss of the drone.

The peer lines are read from files the stacks also log into, so they are untrusted: a line
that names a drone outside the run or the observer itself, or is not a well-formed event,
is counted and dropped, never raised (``counts``). Every table is bounded by N and
``MAX_KEYS_PER_PAIR``.

A second instance of a listed drone is its new life: ``restarted``, as swarmd's observer
says of a new epoch (before this, the stock reboot runs of 2026-11-26 up to Cyclone's,
Fast DDS's, zenoh's and ROS 2's at N = 10 folded it silently, so "seen by peers" has no
figure for them).
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any, Final

TAG: Final = "flight"  # bench/wifi/peers/common.py EVENT_TAG
MAX_KEYS_PER_PAIR: Final = 64  # instances of one drone an observer tracks (one per reboot)
MAX_LINE: Final = 4096  # an event line is < 200 bytes; longer is junk
KINDS: Final = frozenset({"hello", "up", "down", "readiness"})


@dataclass(frozen=True)
class PeerEvent:
    """One well-formed event of observer ``own``; ``peer``/``key``/``counts`` by kind."""

    t: float
    kind: str
    peer: int = -1
    key: str = ""
    counts: tuple[tuple[int, int], ...] = ()


@dataclass
class Rejected:
    """Lines dropped, by reason (the run file's ``observer`` block)."""

    other: int = 0  # not an event line: the stack's own log output
    junk: int = 0  # an event line that is not well-formed
    foreign: int = 0  # names a drone outside 0..N-1, or the observer itself
    unmatched: int = 0  # a down of an instance never up, or past the per-pair cap

    def as_json(self) -> dict[str, int]:
        return {
            "other_lines": self.other,
            "junk": self.junk,
            "foreign": self.foreign,
            "unmatched": self.unmatched,
        }


def _number(v: Any) -> float | None:
    if isinstance(v, bool) or not isinstance(v, int | float):
        return None
    f = float(v)
    return f if math.isfinite(f) else None


def _index(v: Any) -> int | None:
    return v if isinstance(v, int) and not isinstance(v, bool) else None


def parse_line(line: str, own: int, n: int, rejected: Rejected) -> PeerEvent | None:
    """The event on ``line`` of observer ``own`` in a run of ``n`` drones, or None
    (counted in ``rejected``)."""
    text = line.strip()
    if not text.startswith("{") or f'"{TAG}"' not in text:
        rejected.other += 1
        return None
    try:
        raw = json.loads(text) if len(text) <= MAX_LINE else None
    except ValueError:
        raw = None
    kind = raw.get(TAG) if isinstance(raw, dict) else None
    t = _number(raw.get("t")) if isinstance(raw, dict) else None
    if not isinstance(raw, dict) or kind not in KINDS or t is None:
        rejected.junk += 1
        return None
    if kind == "hello":
        if _index(raw.get("self")) != own:
            rejected.foreign += 1
            return None
        return PeerEvent(t, kind)
    if kind == "readiness":
        counts = raw.get("counts")
        if own != 0 or not isinstance(counts, dict):
            rejected.junk += 1
            return None
        table: list[tuple[int, int]] = []
        for k, v in counts.items():
            c = _index(v)
            digits = isinstance(k, str) and k.isascii() and k.isdigit() and len(k) <= 6
            if not (digits and c is not None and c >= 0):
                rejected.junk += 1
                return None
            m = int(str(k))
            if not 0 < m < n:
                rejected.foreign += 1
                return None
            table.append((m, c))
        return PeerEvent(t, kind, counts=tuple(sorted(table)))
    peer, key = _index(raw.get("peer")), raw.get("key")
    if peer is None or not isinstance(key, str) or not key or len(key) > 128:
        rejected.junk += 1
        return None
    if not 0 <= peer < n or peer == own:
        rejected.foreign += 1
        return None
    return PeerEvent(t, kind, peer, key)


@dataclass
class _Life:
    """One observer life's view: the live instance keys of each drone it heard."""

    live: dict[int, set[str]] = field(default_factory=dict)
    ever: set[int] = field(default_factory=set)


class PeerEvents:
    """Per-pair ``changes`` and the commander's ``readiness`` from every peer's lines."""

    def __init__(self, n: int) -> None:
        self.n = n
        self.changes: dict[int, list[tuple[float, int, str]]] = {i: [] for i in range(n)}
        self.readiness: list[tuple[float, dict[int, int]]] = []
        self.rejected = Rejected()
        self.events = 0
        self._life: dict[int, _Life] = {i: _Life() for i in range(n)}

    def feed(self, own: int, lines: Iterable[str]) -> None:
        """Observer ``own``'s log lines, in the order it wrote them (its lives in turn)."""
        for line in lines:
            ev = parse_line(line, own, self.n, self.rejected)
            if ev is not None:
                self.events += 1
                self._apply(own, ev)

    def _apply(self, own: int, ev: PeerEvent) -> None:
        if ev.kind == "hello":  # a restarted peer: its stack knows nobody yet
            self._life[own] = _Life()
            return
        if ev.kind == "readiness":
            self.readiness.append((ev.t, dict(ev.counts)))
            return
        life = self._life[own]
        keys = life.live.setdefault(ev.peer, set())
        if ev.kind == "up":
            if ev.key in keys or len(keys) >= MAX_KEYS_PER_PAIR:
                self.rejected.unmatched += int(ev.key not in keys)
                return
            keys.add(ev.key)
            if len(keys) == 1:
                change = "regained" if ev.peer in life.ever else "discovered"
                life.ever.add(ev.peer)
                self.changes[own].append((ev.t, ev.peer, change))
            else:
                # another instance of a drone still listed: its new life, seen while the old
                # one's lease runs (swarmd's observer reports a new epoch the same way), so
                # the reboot measure has when each peer saw the restarted drone
                self.changes[own].append((ev.t, ev.peer, "restarted"))
        else:
            if ev.key not in keys:
                self.rejected.unmatched += 1
                return
            keys.discard(ev.key)
            if not keys:
                self.changes[own].append((ev.t, ev.peer, "lost"))

    def summary(self) -> dict[str, Any]:
        return {"events": self.events, **self.rejected.as_json()}
