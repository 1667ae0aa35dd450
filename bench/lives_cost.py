"""What a peer's lives cost a drone, and what their damping costs an honest peer
(docs/security.md, "A captured member's lives"; swarmd/lives.py).

    .venv/bin/python -m bench.lives_cost [--seconds 60] [--rate 20] [--lives 8]

One receiver (``uav0`` of a 3-drone bundle, authenticated) on virtual time, its timers run
between datagrams; ``uav1`` is scripted. Two parts:

* *the captured member*: for ``--seconds`` it sends ``--rate`` datagrams a second, all
  genuine and fresh: its DATA(p) with a new epoch each time (epoch churn), or its signed
  dispose and DATA(p) in turn, in one epoch or a new one each time (leaving and returning).
  Printed: the restarts (``PeerRestarted``), losses and discoveries the receiver had, in all
  and after the first 5 s, and the holds counted.
* *an honest peer* whose lives follow one another as fast as systemd makes them: a crash
  loop (no dispose; ``Restart=on-failure``, ``RestartSec=2s``: each life sends its first
  DATA(p) 2 s plus a start-up, 0.288 s at the fastest, after the last one died) and a series
  of ``systemctl restart`` (a dispose, then the next life a start-up later). Each life lives
  ``--alive`` seconds sending a DATA(p) every 0.1 s (denser than a daemon's renewals, so the
  lateness printed is the hold's, not a renewal's wait); the last one stays. Printed per
  life: when its first DATA(p) came and when the receiver took that life or a newer one
  (``PeerRestarted`` or ``PeerDiscovered`` in its epoch or later).

A third part, *the ROS 2 liveness word* (review 18b): the lead's ROS 2 relay of
``firmware_bundle/missions/swarm3-ros2.yaml`` with drone-1 found; drone-1's captured key
signs a new liveness word (PID 0x8A06: a new restart count of its talker) in each of 4
samples a datagram, ``--rate`` datagrams a second for ``--seconds``. Printed: the lives the
relay acted on (each a dispose and an announcement of the talker at every local node) and
the words held.

A fourth, *an honest swarmd restart at a relay* (h-restartword18): the lead's engine and
relay joined as the daemon joins them; drone-1's talker had restarted twice under its old
swarmd (its count 2), then its swarmd restarts (a new epoch, its relay's word back to all
alive, counts 0). Printed: the talker's disposes at the lead's local nodes for that restart
(each one of a re-match), and how many of the talker's own lives in the new life, 0.5 s
apart, are acted on at once before one is damped.

Nothing asserted (``tests/test_discovery_epoch_churn.py`` and ``tests/test_discovery_lives.py``
assert the bounds). It runs on any commit with ``swarmd_lab.testing``, before and after.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from swarmd_lab.testing import (
    auth_for,
    engine_for,
    leave_or_return_datagram,
    make_bundle,
    node_ipv4,
    peer_datagram,
)

from swarmd.auth.spdp import SpdpAuth
from swarmd.bundle.build import build_dev_bundle
from swarmd.bundle.mission import parse_mission
from swarmd.bundle.ros2 import bundle_ros2_participants
from swarmd.discovery import (
    DiscoveryEngine,
    PeerDiscovered,
    PeerLost,
    PeerRestarted,
    PeerRos2Liveness,
)
from swarmd.lives import FLAP_HOLD_MAX_S
from swarmd.ros2.relay import Ros2Relay
from swarmd.ros2.relay_events import RemoteNodeLiveness, RemoteParticipantsRelayed
from swarmd.rtps.spdp import SpdpDisposed, decode_spdp
from swarmd.rtps.types import GuidPrefix

BUNDLE = make_bundle(3)
SOURCE = (node_ipv4(1), 7412)  # uav1's metatraffic address
RESTART_SEC_S = 2.0  # systemd/swarmd.service
START_UP_S = 0.288  # the fastest start-up to the first SPDP of 60 (bench/daemon_start.py)
SETTLE_S = 5.0  # "after the first few seconds"


@dataclass(slots=True)
class Tally:
    restarts: int = 0
    lost: int = 0
    found: int = 0
    late_restarts: int = 0  # after SETTLE_S
    late_lost: int = 0
    late_found: int = 0


def _step(e: DiscoveryEngine, data: bytes, now: float) -> list[object]:
    timer = e.get_timer()
    while timer is not None and timer < now:
        e.handle_timer(timer)
        timer = e.get_timer()
    e.receive_datagram(data, SOURCE, now)
    out: list[object] = []
    while (event := e.next_event()) is not None:
        out.append(event)
    return out


def churn(
    seconds: float, rate: int, *, leave: bool, new_epoch: bool
) -> tuple[Tally, dict[str, int]]:
    """The captured member's ``seconds`` of churn; the receiver's tally and hold counters."""
    e = engine_for(BUNDLE, 0, auth=auth_for(BUNDLE, 0))
    auth = auth_for(BUNDLE, 1, epoch=10)
    _step(e, peer_datagram(BUNDLE, 1, sequence_number=2, auth=auth), 0.0)  # found once
    tally = Tally()
    count = int(seconds * rate)
    for i in range(1, count + 1):
        now = i / rate
        if new_epoch:
            auth = auth_for(BUNDLE, 1, epoch=10 + i, now=now)
        if leave:
            data = leave_or_return_datagram(BUNDLE, 1, sequence_number=i + 2, auth=auth)
        else:
            data = peer_datagram(BUNDLE, 1, sequence_number=2, auth=auth)
        late = now > SETTLE_S
        for x in _step(e, data, now):
            if isinstance(x, PeerRestarted):
                tally.restarts += 1
                tally.late_restarts += late
            elif isinstance(x, PeerLost):
                tally.lost += 1
                tally.late_lost += late
            elif isinstance(x, PeerDiscovered):
                tally.found += 1
                tally.late_found += late
    counters = e.counters()
    holds = {k: counters.get(k, 0) for k in ("restarts_coalesced", "returns_held", "lives_damped")}
    return tally, holds


def honest(lives: int, alive_s: float, *, dispose: bool) -> list[tuple[int, float, float | None]]:
    """Per life: (its number, its first DATA(p), when the receiver took it or a newer one)."""
    e = engine_for(BUNDLE, 0, auth=auth_for(BUNDLE, 0))
    gap = START_UP_S if dispose else RESTART_SEC_S + START_UP_S  # death to next first DATA(p)
    first = [k * (alive_s + gap) for k in range(lives)]
    end = first[-1] + 60.0  # the last life stays a minute
    taken: dict[int, float] = {}  # epoch -> when taken
    for k, start in enumerate(first):
        epoch = 1 + k
        stop = end if k == lives - 1 else start + alive_s
        sn, now = 1, start
        auth = auth_for(BUNDLE, 1, epoch=epoch, now=now)  # one life: its counter runs on
        while now < stop:
            for x in _step(e, peer_datagram(BUNDLE, 1, sequence_number=sn, auth=auth), now):
                if isinstance(x, PeerRestarted | PeerDiscovered) and x.epoch is not None:
                    taken.setdefault(x.epoch, now)
            sn += 1
            now = round(now + 0.1, 6)
        if dispose and k < lives - 1:
            _step(e, leave_or_return_datagram(BUNDLE, 1, sequence_number=sn | 1, auth=auth), stop)
    assert sum(e.counters()["dropped"].values()) == 0, "the honest peer's datagrams were refused"  # noqa: S101
    out: list[tuple[int, float, float | None]] = []
    for k, start in enumerate(first):
        seen = [t for epoch, t in taken.items() if epoch >= 1 + k and t >= start]
        out.append((k + 1, start, min(seen) if seen else None))
    return out


def ros2_word_churn(seconds: float, rate: int) -> tuple[int, dict[str, int]]:
    """The captured member's ``seconds`` of liveness words at a relay: the lives it acted on
    (``RemoteNodeLiveness``, up: a re-match at every local node) and its hold counters."""
    mission = Path(__file__).resolve().parent.parent / "firmware_bundle/missions/swarm3-ros2.yaml"
    bundle = build_dev_bundle(parse_mission(mission.read_text())).bundle
    relay = Ros2Relay(bundle_ros2_participants(bundle), "lead", domain_id=0, lease_s=8.0)
    relay.peer_discovered("drone-1", "10.42.0.11", 0.0)
    relay.peer_liveness("drone-1", b"\x01\x00", 0.0)  # its first word: the base
    lives = 0

    def run_to(now: float) -> None:
        nonlocal lives
        while (due := relay.get_timer()) is not None and due <= now:
            relay.handle_timer(due)
        while (event := relay.next_event()) is not None:  # its queue is bounded: drain
            lives += isinstance(event, RemoteNodeLiveness) and event.up

    for k in range(int(seconds * rate)):
        now = k / rate
        run_to(now)
        for j in range(4):  # MAX_SPDP_SAMPLES a datagram
            relay.peer_liveness("drone-1", bytes((1, (4 * k + j + 1) & 0xFF)), now)
        run_to(now)
    run_to(seconds)
    held = ("remote_liveness_held", "remote_liveness_damped")
    return lives, {k: relay.counters.get(k, 0) for k in held}


class _Lead:
    """The lead's engine and ROS 2 relay joined as swarmd.daemon_events joins them, hearing
    drone-1 (the fourth and fifth parts)."""

    def __init__(self) -> None:
        mission = Path(__file__).resolve().parent.parent / "firmware_bundle/missions"
        self.bundle = build_dev_bundle(parse_mission((mission / "swarm3-ros2.yaml").read_text()))
        participants = bundle_ros2_participants(self.bundle.bundle)
        self.talker = GuidPrefix(next(p for p in participants if p.drone == "drone-1").guid_prefix)
        self.engine = engine_for(self.bundle.bundle, 0, auth=auth_for(self.bundle.bundle, 0))
        self.relay = Ros2Relay(participants, "lead", domain_id=0, lease_s=8.0)
        self.sn = 0
        self.restarts = 0  # the relay's re-matches for drone-1's restarts
        self.word_lives = 0  # and for the lives its word brought

    def auth(self, epoch: int, now: float) -> SpdpAuth:
        return auth_for(self.bundle.bundle, 1, epoch=epoch, now=now)

    def hear(self, auth: SpdpAuth, word: bytes, now: float) -> int:
        """drone-1's DATA(p) carrying ``word``, its events routed to the relay in their
        order: the talker's disposes the relay sent for it."""
        self.sn += 1
        datagram = peer_datagram(
            self.bundle.bundle, 1, sequence_number=self.sn, auth=auth, ros2_alive=word
        )
        self.engine.receive_datagram(datagram, ("10.42.0.11", 7412), now)
        while (e := self.engine.next_event()) is not None:
            if isinstance(e, PeerDiscovered | PeerRestarted):
                restarted = isinstance(e, PeerRestarted)
                self.relay.peer_discovered(e.name, "10.42.0.11", now, restarted=restarted)
            elif isinstance(e, PeerRos2Liveness):
                self.relay.peer_liveness(e.name, e.alive, now)
        return self.run_to(now)

    def run_to(self, now: float) -> int:
        """The relay's timers due by ``now``; the talker's disposes since the last call."""
        while (due := self.relay.get_timer()) is not None and due <= now:
            self.relay.handle_timer(due)
        while (event := self.relay.next_event()) is not None:  # bounded queue: drain
            self.restarts += isinstance(event, RemoteParticipantsRelayed) and event.restarted
            self.word_lives += isinstance(event, RemoteNodeLiveness) and event.up
        return sum(
            isinstance(s, SpdpDisposed) and s.guid_prefix == self.talker
            for data, _dest in self.relay.datagrams_to_send()
            for s in decode_spdp(data)[1]
        )


def ros2_honest_restart() -> tuple[int, int]:
    """An honest restart of drone-1's swarmd at the lead (the fourth part): the talker's
    disposes for it, and the talker's next lives acted on at once (of 8, 0.5 s apart)."""
    lead = _Lead()
    lead.hear(lead.auth(5, 0.0), b"\x01\x02", 0.1)  # its old life's word: the base
    life = lead.auth(6, 10.0)  # its new life (a counter of its own)
    disposes = lead.hear(life, b"\x01\x00", 10.0)
    at_once = 0
    for n in range(1, 9):
        if not lead.hear(life, bytes((1, n)), 10.0 + 0.5 * n):
            break
        at_once += 1
    return disposes, at_once


def ros2_restarts_and_words(seconds: float, rate: int) -> tuple[int, int]:
    """The fifth part: drone-1's captured key signs a new restart count in every DATA(p)
    and a new epoch in every 6th (0.3 s apart: past discovery's spacing) for ``seconds``:
    the re-matches of the talker the lead's relay made for its restarts and its words."""
    lead = _Lead()
    epoch = 1
    auth = lead.auth(epoch, 0.0)
    lead.hear(auth, b"\x01\x00", 0.0)
    for k in range(1, int(seconds * rate)):
        now = k / rate
        lead.run_to(now)
        if k % 6 == 0:
            epoch += 1
            auth = lead.auth(epoch, now)
        lead.hear(auth, bytes((1, k & 0xFF)), now)
    lead.run_to(seconds + FLAP_HOLD_MAX_S)
    return lead.restarts, lead.word_lives


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.lives_cost", description=__doc__)
    parser.add_argument("--seconds", type=float, default=60.0, help="the churn (default 60)")
    parser.add_argument("--rate", type=int, default=20, help="its datagrams a second (20)")
    parser.add_argument("--lives", type=int, default=8, help="the honest peer's lives (8)")
    parser.add_argument("--alive", type=float, default=0.5, help="each life's run, s (0.5)")
    args = parser.parse_args(argv)
    print(f"a captured member, {args.rate} genuine datagrams a second for {args.seconds:g} s:")
    for label, leave, new_epoch in (
        ("epoch churn", False, True),
        ("leaving and returning", True, False),
        ("leaving and returning, a new epoch each", True, True),
    ):
        t, holds = churn(args.seconds, args.rate, leave=leave, new_epoch=new_epoch)
        print(
            f"  {label}: restarts {t.restarts}, lost {t.lost}, found {t.found} "
            f"(after {SETTLE_S:g} s: {t.late_restarts}, {t.late_lost}, {t.late_found}); "
            + ", ".join(f"{k} {v}" for k, v in holds.items())
        )
    lives, holds = ros2_word_churn(args.seconds, args.rate)
    print(
        f"  its ROS 2 liveness word, 4 new ones a datagram: lives acted on at a relay {lives}; "
        + ", ".join(f"{k} {v}" for k, v in holds.items())
    )
    restarts, word_lives = ros2_restarts_and_words(args.seconds, args.rate)
    print(
        "  its ROS 2 liveness word in every datagram and a new epoch every 0.3 s: re-matches "
        f"at a relay for its restarts {restarts}, for its words {word_lives}"
    )
    disposes, at_once = ros2_honest_restart()
    print(
        "an honest swarmd restart at a relay, its talker counted 2 before: the talker "
        f"disposed {disposes} times for it; its next lives acted on at once: {at_once}"
    )
    for label, dispose in (
        (f"a crash loop (RestartSec={RESTART_SEC_S:g}s)", False),
        ("systemctl restart over and over", True),
    ):
        print(f"an honest peer, {label}, each life {args.alive:g} s, start-up {START_UP_S} s:")
        for k, start, seen in honest(args.lives, args.alive, dispose=dispose):
            late = "never" if seen is None else f"{seen:.2f} s ({seen - start:+.2f} s)"
            print(f"  life {k}: first DATA(p) at {start:.2f} s, taken at {late}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
