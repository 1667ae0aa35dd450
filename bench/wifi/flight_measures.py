"""The measures of a flight run (issue 20), pure: from the run file's records to numbers.

Inputs (all times in seconds since the go signal, which is the stacks' start release):

- ``truth``: the scenario's ground truth, ``[(t, in_range[i][j])]`` every 0.5 s
  (``bench/wifi/flight.py``);
- ``changes[i]``: what drone i's stack reported, ``(t, peer index, change)`` with change
  ``discovered | regained | lost | restarted`` (swarmd: its ``status.peer_changes``, each
  dated by the daemon's own ``ago_s``);
- ``down[i]``: the intervals during which drone i's stack was not running (reboots);
- ``readiness``: the commander's polled table, ``(t, {member index: samples received})``;
- ``discovery_fps``: discovery-class frames on the channel per second since go.

The readiness measures (``counted_spans``, ``readiness_delivery``,
``readiness_after_returns``) take these, with the swarm's size, the run's end and each
drone's release, as one frozen ``Timeline``; ``timeline(run, truth)`` builds it from a run
file.

Definitions (docs/benchmarks.md, "Flight"):

- a *real loss* of j at i starts when j leaves i's range (or j's stack dies) and lasts at
  least the lease; *loss latency* is from its start to i's first ``lost`` of j in it;
- every ``lost`` report is classed: ``real`` (j unreachable at the report, in a gap that
  lasts at least the lease), ``intermittent`` (j unreachable at the report, but the gap is
  shorter than the lease: a peer flickering at the edge of range), ``dropout`` (j back in
  range at the report, but not for the whole lease before it), or ``false`` (j in range
  during the whole lease before the report: it "stayed in range");
- *re-discovery latency*: from j's return into i's range (or its stack's restart) to i's
  next ``discovered``/``regained``/``restarted`` of j, for pairs i had reported lost (and,
  for restarts, for every pair), counting only the time j was in i's range: when the
  return's window closed before the re-discovery (the fade's windows of about a second at
  the group's far end) its length counts, the seconds out of range after it do not (before
  session 11 they did: ``rediscovery_wall_s`` keeps that clock time, and
  ``rediscovery_windows_closed`` counts such returns);
- *frames per rejoining pair*: the channel's discovery frames from the first return to
  the last re-discovery (+1 s), over the pairs that rejoined; also above the steady rate
  measured in the ``BASELINE_S`` before the first move;
- *readiness delivery*: samples the commander received from members while in its range
  and up, over 1 Hz times that time, counted from the commander's first discovery of each.
  *In range* is the truth's: each of the pair receives the other's frames at -82 dBm or
  more (where ns-3 detects a frame at all), both stacks running. A time in range runs from
  its first truth sample in range to its last (the crossings fall between samples, and
  time out of range is never counted: during a blackout the commander is out of every
  member's range, so nothing is expected of it); the seconds from a member's return to
  the commander's re-discovery of it count, since the protocol is what keeps them empty.
  A span is counted from the commander's first readiness poll on (what it had received
  before is not known) and from the member's own start (``started``, the staggered
  release: on the relay route the commander's graph lists a drone's node from the bundle
  as soon as its swarmd is found, seconds before the node exists). A member missing from
  a poll's table had sent nothing that arrived yet: its count there is 0 (the stock
  stacks' tallies list a member from its first sample on; before session 9 such a span
  was dropped whole, so those stacks were judged on the spans after a return alone). A
  span ends at the commander's last poll in it, where its count does (before session 11
  its last 0-1 s was expected and what arrived in it never counted: up to a sample per
  span-end with the stock tallies' 1 s polls, a quarter of one with swarmd's 0.25 s).
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Final, NamedTuple

BASELINE_S: Final = 10.0
READINESS_HZ: Final = 1.0
TOLERANCE_S: Final = 0.5  # the truth's sampling step

Truth = Sequence[tuple[float, Sequence[Sequence[bool]]]]
Change = tuple[float, int, str]
Interval = tuple[float, float]

UP_KINDS: Final = frozenset({"discovered", "regained", "restarted"})


def _dead(down: Sequence[Interval], t: float) -> bool:
    return any(a <= t < b for a, b in down)


def reachable(
    truth: Truth, down: Mapping[int, Sequence[Interval]], i: int, j: int
) -> list[tuple[float, bool]]:
    """Per truth sample: whether j can be heard by i (in range and both stacks up)."""
    return [
        (t, bool(m[i][j]) and not _dead(down.get(i, ()), t) and not _dead(down.get(j, ()), t))
        for t, m in truth
    ]


def listed_before_return(
    mine: Sequence[tuple[float, str]], lost_at: Sequence[float], gap_start: float, back: float
) -> bool:
    """Whether a pair lost in the gap that began at ``gap_start`` was listed again before
    the truth's return at ``back`` (outside the poll's ``TOLERANCE_S``) and still listed
    then: its last change after the gap's last loss and before ``back - TOLERANCE_S`` is an
    up kind."""
    losses = [t for t in lost_at if gap_start <= t <= back]
    if not losses:
        return False
    last_loss = max(losses)
    between = [c for t, c in mine if last_loss < t < back - TOLERANCE_S]
    return bool(between) and between[-1] in UP_KINDS


def spans(samples: Sequence[tuple[float, bool]]) -> list[tuple[float, float, bool]]:
    """Runs of equal value: ``(start, end, value)``; the last ends at the last sample."""
    out: list[tuple[float, float, bool]] = []
    for t, v in samples:
        if out and out[-1][2] == v:
            out[-1] = (out[-1][0], t, v)
        else:
            if out:
                out[-1] = (out[-1][0], t, out[-1][2])
            out.append((t, t, v))
    return out


def in_range_time(runs: Sequence[tuple[float, float, bool]], start: float, t: float) -> float:
    """Seconds in range (``runs``: ``spans`` of one pair) between ``start`` and ``t``; a
    span in range lasts from its first sample to the next span's first (its ``end``)."""
    return sum(max(0.0, min(b, t) - max(a, start)) for a, b, up in runs if up)


def _value_at(samples: Sequence[tuple[float, bool]], t: float) -> bool:
    value = samples[0][1] if samples else False
    for st, v in samples:
        if st > t:
            break
        value = v
    return value


def classify_loss(samples: Sequence[tuple[float, bool]], t: float, lease_s: float) -> str:
    """``real`` | ``intermittent`` | ``dropout`` | ``false`` for a ``lost`` reported at
    ``t`` (module doc). A report up to ``TOLERANCE_S`` before the peer becomes
    unreachable is of that loss: the harness records a kill once it returns, while a stack
    that sees the session close (zenoh: at once) may log it first (zenoh's reboot run: lost
    at 40.003 s and 79.97 s, the kills recorded from 40.045 s and 80.01 s: all 18 such
    reports counted false before). The truth is sampled every 0.5 s, so "unreachable" is
    read at the first sample after ``t + TOLERANCE_S``."""
    if _value_at(samples, t):
        ahead = next((st for st, _ in samples if st > t + TOLERANCE_S), None)
        if ahead is not None and not _value_at(samples, ahead):
            t = ahead
    if not _value_at(samples, t):
        for a, b, up in spans(samples):
            if not up and a <= t <= b:
                last = samples[-1][0] if samples else b
                # a gap still open when the run ends may be longer than we saw
                return "real" if b - a >= lease_s or b >= last else "intermittent"
        return "real"
    window = [v for st, v in samples if t - lease_s <= st <= t]
    return "false" if window and all(window) else "dropout"


def _pct(values: Sequence[float], q: float) -> float | None:
    if not values:
        return None
    s = sorted(values)
    k = min(len(s) - 1, max(0, round(q / 100 * (len(s) - 1))))
    return round(s[k], 3)


def _summary(values: Sequence[float]) -> dict[str, Any]:
    return {
        "count": len(values),
        "p50": _pct(values, 50),
        "p90": _pct(values, 90),
        "max": None if not values else round(max(values), 3),
    }


def measure(
    truth: Truth,
    changes: Mapping[int, Sequence[Change]],
    down: Mapping[int, Sequence[Interval]],
    *,
    n: int,
    lease_s: float,
    restarts: Sequence[tuple[float, int]] = (),
    readiness: Sequence[tuple[float, Mapping[int, int]]] = (),
    discovery_fps: Sequence[int] = (),
    first_move_s: float | None = None,
    started: Sequence[float] = (),
) -> dict[str, Any]:
    """Every measure of one run (module doc); JSON-ready. ``started``: each drone's stack's
    release after go (the run file's ``setup.started_s``; empty: all at go)."""
    loss_latency: list[float] = []
    missed_losses = 0
    classes = {"real": 0, "intermittent": 0, "dropout": 0, "false": 0}
    false_pairs: list[list[Any]] = []
    rediscovery: list[float] = []
    rediscovery_wall: list[float] = []
    windows_closed = 0
    not_rediscovered = 0
    early_relists = 0
    rejoined: set[tuple[int, int]] = set()
    rejoin_times: list[float] = []
    last_rediscovery: float | None = None
    end = truth[-1][0] if truth else 0.0
    for i in range(n):
        own = sorted(changes.get(i, ()))
        for j in range(n):
            if i == j:
                continue
            samples = reachable(truth, down, i, j)
            mine = [(t, c) for t, p, c in own if p == j]
            lost_at = [t for t, c in mine if c == "lost"]
            for t in lost_at:
                kind = classify_loss(samples, t, lease_s)
                classes[kind] += 1
                if kind == "false":
                    false_pairs.append([i, j, round(t, 2)])
            runs = spans(samples)
            for k, (a, b, up) in enumerate(runs):
                if up or _dead(down.get(i, ()), a):
                    continue  # i's own death is not i losing j
                if b - a >= lease_s:
                    hit = [t for t in lost_at if a <= t <= b + 1.0]
                    if hit:
                        loss_latency.append(hit[0] - a)
                    else:
                        missed_losses += 1
                # the return: after a gap i reported (a loss), count the re-discovery
                if k + 1 < len(runs) and any(a <= t <= runs[k + 1][0] for t in lost_at):
                    back = runs[k + 1][0]
                    # the truth is sampled every 0.5 s and the stacks' times are dated by
                    # a poll: a re-discovery up to TOLERANCE_S before the sample counts as 0
                    found = [t for t, c in mine if c in UP_KINDS and t >= back - TOLERANCE_S]
                    rejoined.add((min(i, j), max(i, j)))
                    rejoin_times.append(back)
                    if listed_before_return(mine, lost_at, a, back):
                        # re-listed after its loss but before the truth's return: a frame
                        # got through at the range's edge before the truth's threshold. The
                        # pair is listed at the return, so it took 0 s; counted apart
                        # (session 13: 9 such pairs read "never re-discovered" before)
                        rediscovery.append(0.0)
                        rediscovery_wall.append(0.0)
                        early_relists += 1
                        last_rediscovery = (
                            back if last_rediscovery is None else max(last_rediscovery, back)
                        )
                    elif found:
                        # the time in range from the return to the re-discovery: a window
                        # that closed first (the fade's 1 s returns) adds its length, not
                        # the seconds out of range after it (module doc)
                        rediscovery.append(round(in_range_time(runs, back, found[0]), 6))
                        rediscovery_wall.append(max(0.0, found[0] - back))
                        windows_closed += found[0] > runs[k + 1][1] and k + 2 < len(runs)
                        last = found[0]
                        last_rediscovery = (
                            last if last_rediscovery is None else max(last_rediscovery, last)
                        )
                    else:
                        not_rediscovered += 1
    # restarts: every peer sees the new life; the new life finds every peer in range
    reboot_seen: list[float] = []
    reboot_finds: list[float] = []
    for r, node in restarts:
        # this life's window: from TOLERANCE_S before the harness recorded the start (a
        # stock peer logs its first discoveries on its own clock, before the harness's start
        # call returns: Fast DDS at -0.02 s) to the node's next restart. Unbounded, a life
        # that logged its finds early was credited with the next life's, 40 s on
        lives = [t for t, j in restarts if j == node and t > r]
        a, b = r - TOLERANCE_S, min(lives, default=math.inf)
        for i in range(n):
            if i == node:
                continue
            seen = [
                t for t, p, c in changes.get(i, ()) if p == node and c in UP_KINDS and a <= t < b
            ]
            if seen:
                reboot_seen.append(max(0.0, min(seen) - r))
            finds = [
                t for t, p, c in changes.get(node, ()) if p == i and c in UP_KINDS and a <= t < b
            ]
            if finds:
                reboot_finds.append(max(0.0, min(finds) - r))
    frames: dict[str, Any] = {"pairs": len(rejoined)}
    if rejoined and rejoin_times and last_rediscovery is not None and discovery_fps:
        a, b = int(min(rejoin_times)), min(len(discovery_fps), int(last_rediscovery) + 2)
        spent = sum(discovery_fps[a:b])
        frames.update(window_s=[a, b], frames=spent, per_pair=round(spent / len(rejoined), 2))
        if first_move_s is not None:
            s0 = max(0, int(first_move_s - BASELINE_S))
            base = discovery_fps[s0 : int(first_move_s)]
            if base:
                rate = sum(base) / len(base)
                excess = spent - rate * (b - a)
                frames.update(
                    steady_fps=round(rate, 2),
                    excess_per_pair=round(excess / len(rejoined), 2),
                )
    return {
        "loss_latency_s": _summary(loss_latency),
        "missed_losses": missed_losses,
        "lost_reports": classes,
        "false_losses": classes["false"],
        "false_loss_examples": false_pairs[:10],
        "rediscovery_s": _summary(rediscovery),
        "rediscovery_wall_s": _summary(rediscovery_wall),
        "rediscovery_windows_closed": windows_closed,
        "not_rediscovered": not_rediscovered,
        "rediscovered_before_return": early_relists,
        "reboot_seen_by_peers_s": _summary(reboot_seen),
        "reboot_finds_peers_s": _summary(reboot_finds),
        "frames_per_rejoining_pair": frames,
        "readiness_delivery": readiness_delivery(
            Timeline(truth, down, changes, readiness, n, end, started)
        ),
    }


class CountedSpan(NamedTuple):
    """A member's span in the commander's range as readiness counts it (module doc):
    ``start_s``..``end_s`` (the end at its last poll), the member's count at each end."""

    member: int
    start_s: float
    end_s: float
    count_start: int
    count_end: int

    @property
    def expected(self) -> float:
        """Samples expected in the span: one a period."""
        return (self.end_s - self.start_s) * READINESS_HZ

    @property
    def delivered(self) -> float:
        """Samples counted in the span, capped at ``expected``: a member also reports at once
        when the commander finds it again (swarm core), so a span can hold a sample more than
        its seconds; that extra sample must not hide samples missing in another span."""
        return min(max(0, self.count_end - self.count_start), self.expected)


def _last_in_range(samples: Sequence[tuple[float, bool]], b: float) -> float:
    """The end of an in-range span ending at ``b`` (``spans``' end, the first sample out of
    range unless the run ended in range): the pair parted somewhere in the step before
    ``b``, so the span ends at its last sample in range (time unreachable is never counted)."""
    return max(t for t, _ in samples if t < b) if b < samples[-1][0] else b


@dataclass(frozen=True, slots=True)
class Timeline:
    """One run's timeline as the readiness measures read it (module doc, "Inputs"): the
    ground truth, each stack's down intervals and reported changes, the commander's polls,
    the swarm's size, the run's end and each drone's release (seconds since go)."""

    truth: Truth
    down: Mapping[int, Sequence[Interval]]
    changes: Mapping[int, Sequence[Change]]
    readiness: Sequence[tuple[float, Mapping[int, int]]]
    n: int
    end: float
    started: Sequence[float] = ()  # each drone's release after go (empty: all at go)


def timeline(run: Mapping[str, Any], truth: Truth) -> Timeline:
    """A run file's records (``bench/wifi/flight_run.py`` writes them), keys made ints, on
    the scenario's ``truth`` (``flight.of_run(run).truth()``); the run ends at its last
    sample."""
    return Timeline(
        truth=truth,
        down={int(i): [(a, b) for a, b in v] for i, v in run.get("down", {}).items()},
        changes={int(i): [(t, p, c) for t, p, c in v] for i, v in run["changes"].items()},
        readiness=[(t, {int(k): v for k, v in table.items()}) for t, table in run["readiness"]],
        n=int(run["n"]),
        end=truth[-1][0] if truth else 0.0,
        started=[float(s) for s in (run.get("setup") or {}).get("started_s") or ()],
    )


def counted_spans(tl: Timeline) -> Iterator[CountedSpan]:
    """The spans ``readiness_delivery`` counts, member by member in order, each member's in
    time order."""
    truth, down, changes, readiness, started = (
        tl.truth,
        tl.down,
        tl.changes,
        tl.readiness,
        tl.started,
    )
    if not readiness:
        return
    first_poll = readiness[0][0]
    for m in range(1, tl.n):
        first = [t for t, p, c in changes.get(0, ()) if p == m and c in UP_KINDS]
        if not first:
            continue
        released = started[m] if m < len(started) else 0.0
        start = max(min(first), first_poll, released)
        samples = reachable(truth, down, 0, m)
        for a, b, up in spans(samples):
            if up:
                b = _last_in_range(samples, b)
            a, b = max(a, start), min(b, tl.end, readiness[-1][0])
            if not up or b - a < 2.0:
                continue
            # the span's time ends where its count does, at the last poll at or before b:
            # what arrived after that poll is not known, so its time is not expected
            # either (before session 11 a span's last 0-1 s was expected and its samples
            # never counted: up to one per span-end with the stock tallies' 1 s polls,
            # a quarter of one with swarmd's 0.25 s)
            b = last_poll(readiness, b)
            ca, cb = count_at(readiness, m, a), count_at(readiness, m, b)
            if ca is None or cb is None or b <= a:
                continue
            yield CountedSpan(m, a, b, ca, cb)


def readiness_delivery(tl: Timeline) -> dict[str, Any]:
    """Samples received by the commander (node 0) from members in its range (module doc)."""
    if not tl.readiness:
        return {"expected": 0, "delivered": 0, "ratio": None}
    expected = delivered = 0.0
    for span in counted_spans(tl):
        expected += span.expected
        delivered += span.delivered  # capped per span (CountedSpan.delivered)
    ratio = None if expected == 0 else round(min(delivered / expected, 1.0), 4)
    return {"expected": round(expected), "delivered": round(delivered), "ratio": ratio}


def last_poll(readiness: Sequence[tuple[float, Mapping[int, int]]], t: float) -> float:
    """The time of the last poll at or before ``t`` (``t`` itself before the first)."""
    best = t
    for pt, _ in readiness:
        if pt > t:
            break
        best = pt
    return best


def count_at(readiness: Sequence[tuple[float, Mapping[int, int]]], m: int, t: float) -> int | None:
    """Member m's received-sample count in the last poll at or before ``t``: 0 where that
    poll does not list m (nothing of it arrived yet), None before the first poll."""
    best = None
    for pt, table in readiness:
        if pt > t:
            break
        best = table.get(m, 0)
    return best


def readiness_after_returns(tl: Timeline) -> list[dict[str, Any]]:
    """Where the readiness missing after a member's return into the commander's range goes:
    one row per member and return (an in-range span after a gap, as ``readiness_delivery``
    bounds it), with

    - ``wait_s``: from the return (the truth's first sample in range) to the member's next
      up-report of the commander: the member has no reader to write to, nothing can leave;
    - ``member_first_s``: the commander's next up-report of the member minus the member's
      (> 0: the member found the commander first, and a report it sent in between reached
      a commander that still had it down: dropped ``peer_not_up``, docs/dataplane.md);
    - ``first_counted_s``: from the return to the first poll whose count moved;
    - ``expected``, ``delivered``, ``missing``: as ``readiness_delivery`` counts the span;
    - ``sendable``: the reports a 1 Hz stream restarted at the member's re-discovery holds
      in the span (capped as ``delivered`` is): ``expected - sendable`` is the wait's
      share of ``missing``, ``sendable - delivered`` the reports sent and not counted.

    A report sent at the member's re-discovery and taken is counted by the next poll (0.25
    s apart in swarmd's runs, 1 s in the stock tallies); one counted only a period later was
    lost, where the polls are close enough to tell (``first_report_lost``); the members'
    release (``started``) plays no part: a return comes after it."""
    truth, down, changes, readiness = tl.truth, tl.down, tl.changes, tl.readiness
    rows: list[dict[str, Any]] = []
    if not readiness:
        return rows
    last = min(tl.end, readiness[-1][0])
    for m in range(1, tl.n):
        samples = reachable(truth, down, 0, m)
        runs = spans(samples)
        for k, (a, b, up) in enumerate(runs):
            if not up or k == 0:
                continue
            b = _last_in_range(samples, b)
            b = last_poll(readiness, min(b, last))  # as readiness_delivery bounds it
            member_up = [t for t, p, c in changes.get(m, ()) if p == 0 and c in UP_KINDS]
            lead_up = [t for t, p, c in changes.get(0, ()) if p == m and c in UP_KINDS]
            t_member = min((t for t in member_up if t >= a - TOLERANCE_S), default=None)
            t_lead = min((t for t in lead_up if t >= a - TOLERANCE_S), default=None)
            ca, cb = count_at(readiness, m, a), count_at(readiness, m, b)
            if t_member is None or t_lead is None or ca is None or cb is None or b - a < 2.0:
                continue
            moved = [t for t, table in readiness if a < t <= b and table.get(m, 0) != ca]
            span = CountedSpan(m, a, b, ca, cb)
            expected, delivered = span.expected, span.delivered
            # the member's stream restarts at its re-discovery (its tick is pulled in there,
            # swarm core) and runs one a period: what it could send in the span
            sendable = min(expected, math.floor((b - max(a, t_member)) * READINESS_HZ) + 1)
            rows.append(
                {
                    "member": m,
                    "return_s": a,
                    "wait_s": round(max(0.0, t_member - a), 3),
                    "member_first_s": round(t_lead - t_member, 3),
                    "first_counted_s": None if not moved else round(moved[0] - a, 3),
                    "expected": round(expected, 3),
                    "delivered": round(delivered, 3),
                    "missing": round(expected - delivered, 3),
                    "sendable": round(sendable, 3),
                }
            )
    return rows


def _pearson(xs: Sequence[float], ys: Sequence[float]) -> float | None:
    n = len(xs)
    if n < 3:
        return None
    mx, my = sum(xs) / n, sum(ys) / n
    sxy = sum((x - mx) * (y - my) for x, y in zip(xs, ys, strict=True))
    sxx = sum((x - mx) ** 2 for x in xs)
    syy = sum((y - my) ** 2 for y in ys)
    if sxx == 0 or syy == 0:
        return None
    return round(float(sxy / (sxx * syy) ** 0.5), 3)


def _span(values: Sequence[float]) -> list[float]:
    return [round(min(values), 4), round(max(values), 4)]


def renewal_follows_q(polls: Sequence[Sequence[Any]], since_s: float = 0.0) -> dict[str, Any]:
    """Whether each daemon's renewal period followed its link quality: per node the range
    of Q and of the renewal period it reported, and their correlation over its polls from
    ``since_s`` on (``polls``: ``[t, node, renewals sent, q, renewal_period_s,
    advertised_lease_s]``, and from the rate counters on ``renewals_sent_per_s,
    vouches_sent_per_s, vouches_received_per_s``: status ``rates``, over its window). Pass
    the first move: before any frame is heard a flight link file reads Q 0, and those
    start-up polls alone would make a correlation.

    With the rates: the range of the renewal rate and its correlation with Q (negative when
    it follows the link: a poorer link, denser renewals), and the same for the vouch rate,
    the vouches a node sent if it sent any (the commander), else those it received. The
    rates are over a window (60 s in swarmd), so they lag Q by up to that window."""
    by_node: dict[int, list[tuple[float, float]]] = {}
    rates: dict[int, list[tuple[float, float, float, float]]] = {}
    for row in polls:
        t, node, _, q, period = row[:5]
        if t < since_s:
            continue
        if isinstance(q, int | float) and isinstance(period, int | float):
            by_node.setdefault(int(node), []).append((float(q), float(period)))
            extra = list(row[6:9])
            if len(extra) == 3 and all(
                isinstance(v, int | float) and not isinstance(v, bool) for v in extra
            ):
                r_renew, r_sent, r_got = (float(v) for v in extra)
                rates.setdefault(int(node), []).append((float(q), r_renew, r_sent, r_got))
    out: dict[str, Any] = {}
    for node, pairs in sorted(by_node.items()):
        qs, ps = [q for q, _ in pairs], [p for _, p in pairs]
        entry: dict[str, Any] = {
            "q": [round(min(qs), 3), round(max(qs), 3)],
            "renewal_period_s": [round(min(ps), 3), round(max(ps), 3)],
            "corr_q_period": _pearson(qs, ps),
        }
        rows = rates.get(node)
        if rows:
            rq = [r[0] for r in rows]
            renew = [r[1] for r in rows]
            sent = [r[2] for r in rows]
            kind = "sent" if any(sent) else "received"
            vouch = sent if kind == "sent" else [r[3] for r in rows]
            entry["renewals_per_s"] = _span(renew)
            entry["corr_q_renewal_rate"] = _pearson(rq, renew)
            entry["vouch_rate"] = kind
            entry["vouches_per_s"] = _span(vouch)
            entry["corr_q_vouch_rate"] = _pearson(rq, vouch)
        out[str(node)] = entry
    return out


# A daemon's Q "moved" when its polled range spans two or more of the engine's hysteresis
# steps (``EngineConfig.link_report_step``, 0.1): the advertised Q, and with it the renewal
# period, changes only on a reading a step away from the Q it stands at
# (swarmd/discovery/renewals.py, ``Renewals.on_link``), and a range of two steps has one end
# a step or more from wherever it stood. Within less, the period may rightly stay put.
Q_MOVED_MIN: Final = 0.2


def period_follows_q(follows: Mapping[str, Any]) -> tuple[list[float], list[float]]:
    """From ``renewal_follows_q``'s result: the correlation of Q with the renewal period at
    each daemon whose Q moved by ``Q_MOVED_MIN`` or more (0.0 where the period did not move
    at all: it did not follow), and how far Q moved at every other daemon (not judged:
    within the hysteresis, or too few polls for a correlation)."""
    judged: list[float] = []
    others: list[float] = []
    for entry in follows.values():
        low, high = entry["q"]
        moved = round(float(high) - float(low), 3)
        r = entry.get("corr_q_period")
        p_low, p_high = entry["renewal_period_s"]
        if moved >= Q_MOVED_MIN and isinstance(r, int | float):
            judged.append(float(r))
        elif moved >= Q_MOVED_MIN and p_low == p_high:
            judged.append(0.0)
        else:
            others.append(moved)
    return judged, others


# what a report taken at once may take to show in the commander's count besides the poll
# gap: the network's delay and the commander's handling (the runs' links: a few ms)
TAKEN_DELAY_S: Final = 0.25


def first_report_lost(
    row: Mapping[str, Any], poll_gap_s: float = 0.25, period_s: float = 1.0 / READINESS_HZ
) -> bool | None:
    """Whether the report a member sent at its re-discovery of the commander was not taken:
    a taken one moves the count by the first poll after it arrives (within ``poll_gap_s`` +
    ``TAKEN_DELAY_S`` of both having each other up); a lost one's successor comes a
    ``period_s`` later. None where the polls are too far apart to tell the two (the stock
    contenders' tallies are written 1 s apart, a period: swarmd's commander is polled every
    0.25 s)."""
    if poll_gap_s + TAKEN_DELAY_S >= period_s:
        return None
    counted = row["first_counted_s"]
    both_up = row["wait_s"] + max(0.0, row["member_first_s"])
    return counted is not None and counted > both_up + poll_gap_s + TAKEN_DELAY_S


def poll_gap(polls: Sequence[tuple[float, Any]]) -> float:
    """The commander's polls' median spacing (0.0 with fewer than two polls)."""
    gaps = sorted(b[0] - a[0] for a, b in zip(polls, polls[1:], strict=False))
    return gaps[len(gaps) // 2] if gaps else 0.0


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m bench.wifi.flight_measures --readiness-returns RUN.json ...``: per run,
    where the readiness missing after the returns goes (``readiness_after_returns``)."""
    import argparse
    import json
    from pathlib import Path

    from bench.wifi import flight

    p = argparse.ArgumentParser(description=main.__doc__)
    p.add_argument("runs", nargs="+", type=Path)
    p.add_argument("--readiness-returns", action="store_true", required=True)
    p.add_argument("--verbose", action="store_true", help="one line per member and return")
    args = p.parse_args(argv)
    for path in args.runs:
        run = json.loads(path.read_text())
        tl = timeline(run, flight.of_run(run).truth())
        polls = tl.readiness
        rows = readiness_after_returns(tl)
        whole = readiness_delivery(tl)
        missing = sum(r["missing"] for r in rows)
        wait = sum(r["expected"] - r["sendable"] for r in rows)
        unsent = sum(r["sendable"] - r["delivered"] for r in rows)
        wait_s = sum(r["wait_s"] for r in rows)
        first = [r for r in rows if r["member_first_s"] > 0]
        gap_s = poll_gap(polls)
        judged = [first_report_lost(r, gap_s) for r in rows]
        lost = [r for r, j in zip(rows, judged, strict=True) if j]
        lost_text = (
            f"{len(lost)} (member first: {sum(r in first for r in lost)})"
            if all(j is not None for j in judged)
            else f"not known (polls {gap_s:.2f} s apart)"
        )
        print(
            f"{path.name}: readiness {whole['delivered']}/{whole['expected']} "
            f"(missing {whole['expected'] - whole['delivered']}); after {len(rows)} returns "
            f"missing {missing:.1f} = {wait:.1f} in the wait for re-discovery ({wait_s:.1f} s "
            f"in all) + {unsent:.1f} sent, not counted; member found the commander first "
            f"{len(first)}, its first report lost {lost_text}; had every report sent been counted: "
            f"{(whole['delivered'] + unsent) / whole['expected']:.1%}"
        )
        if args.verbose:
            for r in rows:
                print("   ", json.dumps(r))
    return 0


if __name__ == "__main__":
    import sys

    sys.exit(main())
