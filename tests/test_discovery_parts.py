"""The engine's small pure parts: awareness formulas, heard digest, timers, config, memnet."""

from __future__ import annotations

import math
import random
from dataclasses import dataclass

import pytest
from hypothesis import given
from hypothesis import strategies as st
from swarmd_lab.memnet import Channel, MemNet

from swarmd.bundle.model import DiscoveryParams
from swarmd.discovery import received as received_module
from swarmd.discovery.awareness import (
    advertised_lease_s,
    draw_passive_timer_s,
    normalise_q,
    passive_window_s,
    renewal_period_s,
)
from swarmd.discovery.config import EngineConfig, resolve_timing
from swarmd.discovery.digest import bitmap_size, decode_heard, encode_heard, lists
from swarmd.discovery.phases import Phase, TransitionError, Trigger, next_phase
from swarmd.discovery.timers import Backoff, LeaseQueue, MinInterval, Periodic, RetrySchedule
from swarmd.rtps.locator import Locator, LOCATOR_KIND_UDPv4
from swarmd.rtps.spdp import SpdpParticipant
from swarmd.rtps.types import GuidPrefix

WINDOW = {"t_min_s": 8.0, "t_max_s": 20.0, "announce_budget_fps": 50.0, "q_floor": 0.1}


@pytest.mark.parametrize(("q", "expected"), [(1.0, 8.0), (0.5, 14.0), (0.0, 20.0)])
def test_paper_window_is_eq3(q: float, expected: float) -> None:
    assert passive_window_s("paper", q, swarm_size=10, **WINDOW) == pytest.approx(expected)


@pytest.mark.parametrize(
    ("n", "q", "expected"),
    [(10, 1.0, 0.2), (200, 1.0, 4.0), (50, 0.5, 2.0), (10, 0.0, 2.0), (1000, 1.0, 8.0)],
)
def test_adaptive_window_spreads_n_frames_at_the_budget_never_beyond_the_paper(
    n: int, q: float, expected: float
) -> None:
    assert passive_window_s("adaptive", q, swarm_size=n, **WINDOW) == pytest.approx(expected)


@given(st.floats(allow_nan=True), st.integers(1, 500))
def test_adaptive_never_waits_longer_than_the_paper(q: float, n: int) -> None:
    adaptive = passive_window_s("adaptive", q, swarm_size=n, **WINDOW)
    paper = passive_window_s("paper", q, swarm_size=n, **WINDOW)
    assert 0 < adaptive <= paper <= 20.0


def test_normalise_q_clamps_and_treats_nan_as_worst() -> None:
    assert (normalise_q(-1), normalise_q(2), normalise_q(math.nan), normalise_q(0.3)) == (
        0.0,
        1.0,
        0.0,
        0.3,
    )


def test_passive_timer_is_uniform_on_the_window() -> None:
    rng = random.Random(1)
    draws = [draw_passive_timer_s(rng, 14.0) for _ in range(2000)]
    assert 0 <= min(draws) < 0.5 and 13.5 < max(draws) <= 14.0
    assert sum(draws) / len(draws) == pytest.approx(7.0, abs=0.5)


@pytest.mark.parametrize(("q", "period"), [(1.0, 10.0), (0.5, 20 / 3), (0.0, 5.0)])
def test_renewals_get_denser_as_q_drops(q: float, period: float) -> None:
    got = renewal_period_s(q, lease_s=20.0, per_lease_min=2.0, per_lease_max=4.0)
    assert got == pytest.approx(period)


@pytest.mark.parametrize(
    ("n", "q", "period", "lease"),
    [
        (200, 1.0, 10.0, 20.0),  # 200 / 50 = 4 s < lease / 2: the budget does not bind
        (500, 1.0, 10.0, 20.0),  # exactly at the budget
        (1000, 1.0, 20.0, 40.0),  # N / budget, and two renewals per (longer) lease
        (1000, 0.0, 20.0, 80.0),  # Q = 0 still gets four renewals per lease
        (300, 0.0, 6.0, 24.0),
    ],
)
def test_renewal_budget_stretches_the_period_and_the_lease_with_n(
    n: int, q: float, period: float, lease: float
) -> None:
    got = renewal_period_s(
        q,
        lease_s=20.0,
        per_lease_min=2.0,
        per_lease_max=4.0,
        swarm_size=n,
        renewal_budget_fps=50.0,
    )
    assert got == pytest.approx(period)
    # the swarm's renewal load stays within the budget
    assert n / got <= 50.0 + 1e-9
    advertised = advertised_lease_s(
        q, lease_s=20.0, renewal_period_s=got, per_lease_min=2.0, per_lease_max=4.0
    )
    assert advertised == pytest.approx(lease)


@dataclass(slots=True)
class _Leased:
    index: int
    lease_until: float | None = None
    lease_queued: float | None = None


_lease_ops = st.lists(
    st.tuples(
        st.sampled_from(["renew", "remove"]),
        st.integers(0, 7),
        st.sampled_from([1.0, 5.0, 20.0, 40.0]),
        st.sampled_from([0.0, 0.5, 3.0]),
    ),
    max_size=80,
)


@given(_lease_ops)
def test_lease_queue_always_yields_the_earliest_live_deadline(
    ops: list[tuple[str, int, float, float]],
) -> None:
    queue, deadlines, now = LeaseQueue(), {}, 0.0
    leased = [_Leased(i) for i in range(8)]
    for op, index, lease_s, step in ops:
        now += step  # non-decreasing, as the engine's now; steps of 0.0 make equal deadlines
        if op == "renew":
            queue.renew(leased[index], lease_s, now)
            deadlines[index] = now + lease_s
        else:
            queue.remove(leased[index])
            deadlines.pop(index, None)
        assert leased[index].lease_until == deadlines.get(index)
        earliest = queue.earliest()
        if not deadlines:
            assert earliest is None
        else:
            assert earliest is not None
            assert earliest[0] == min(deadlines.values())
            assert deadlines[earliest[1]] == earliest[0]


@given(st.sets(st.integers(0, 199)), st.integers(200, 260))
def test_heard_digest_round_trips(indices: set[int], n: int) -> None:
    bitmap = encode_heard(indices, n)
    assert len(bitmap) == bitmap_size(n)
    assert decode_heard(bitmap, n) == indices


def test_heard_digest_layout_and_tolerance() -> None:
    assert encode_heard([0, 9], 10) == bytes([0b1, 0b10])  # LSB of octet 0 = index 0
    assert lists(b"\x01", 0) and not lists(b"\x01", 1)
    assert not lists(b"\x01", 8)  # short bitmap: nobody past its end
    assert not lists(None, 0) and not lists(b"\xff", -1)
    with pytest.raises(ValueError, match="outside the bundle"):
        encode_heard([10], 10)


def test_backoff_doubles_to_the_cap_with_bounded_jitter() -> None:
    rng = random.Random(3)
    backoff = Backoff(1.0, 8.0)
    for attempt, plain in [(1, 1.0), (2, 2.0), (3, 4.0), (4, 8.0), (9, 8.0)]:
        assert plain <= backoff.delay_s(attempt, rng) <= plain * 1.25


def test_retry_schedule_keeps_the_earliest_deadline_and_stops_when_exhausted() -> None:
    retry = RetrySchedule(max_attempts=2)
    retry.arm(5.0)
    retry.arm(7.0)
    assert retry.deadline() == 5.0
    retry.arm(3.0)
    assert retry.deadline() == 3.0
    retry.sent()
    retry.arm(4.0)
    retry.sent()
    assert retry.exhausted
    retry.arm(9.0)
    assert retry.deadline() is None
    retry.reset()
    retry.arm(9.0)
    assert retry.deadline() == 9.0


def test_backoff_plain_is_the_unjittered_delay_and_draws_nothing() -> None:
    backoff = Backoff(1.0, 8.0)
    rng = random.Random(3)
    state = rng.getstate()
    assert [backoff.plain_s(k) for k in (0, 1, 2, 3, 4, 5, 9)] == [1, 1, 2, 4, 8, 8, 8]
    assert rng.getstate() == state  # no draw: the caller's seeded schedule does not move
    for k in range(1, 8):
        assert backoff.plain_s(k) <= backoff.delay_s(k, rng) <= backoff.plain_s(k) * 1.25


@pytest.mark.parametrize("spent", [0, 1, 3, 4])
def test_retry_schedule_can_leave_exactly_one_attempt_whatever_was_spent(spent: int) -> None:
    retry = RetrySchedule(max_attempts=4)
    for _ in range(spent):
        retry.arm(1.0)
        retry.sent()
    retry.leave_one_attempt()
    assert retry.attempts == 3  # one of four left
    assert retry.arm(2.0) and retry.deadline() == 2.0  # one more may be armed ...
    retry.sent()
    assert retry.exhausted  # ... and sent, then no more
    assert not retry.arm(3.0) and retry.deadline() is None
    retry.reset()  # the next need starts fresh: all four again
    for _ in range(4):
        assert retry.arm(4.0)
        retry.sent()
    assert retry.exhausted


def test_min_interval_and_periodic() -> None:
    limiter = MinInterval(0.5)
    assert limiter.permits(0.0) and limiter.next_allowed() is None
    limiter.mark(0.0)
    assert not limiter.permits(0.4) and limiter.permits(0.5)
    assert limiter.next_allowed() == 0.5
    periodic = Periodic(10.0, 0.1)
    periodic.restart(100.0, random.Random(1))
    due = periodic.deadline()
    assert due is not None and 109.0 <= due <= 110.0
    periodic.stop()
    assert periodic.deadline() is None


def test_phase_table_rejects_unknown_transitions() -> None:
    assert next_phase(Phase.BOOT, Trigger.LINK_READ) == Phase.PASSIVE
    with pytest.raises(TransitionError):
        next_phase(Phase.STOPPED, Trigger.LINK_READ)
    with pytest.raises(TransitionError):
        next_phase(Phase.STEADY, Trigger.TIMER_EXPIRED_NEEDED)


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("mode", "fast"),
        ("lease_s", 0.0),
        ("t_min_s", -1.0),
        ("announce_budget_fps", 0.0),
        ("q_floor", 0.0),
        ("max_attempts", 0),
        ("renewals_per_lease_min", 1.0),
        ("retry_max_s", 0.5),
        ("renewal_jitter", 1.0),
        ("lease_s", math.inf),
    ],
)
def test_config_rejects_bad_values_with_one_line(field: str, value: object) -> None:
    with pytest.raises(ValueError, match=rf"^discovery\.{field} = .* is invalid; fix: "):
        EngineConfig(**{field: value})  # type: ignore[arg-type]


def test_timing_precedence_defaults_bundle_config() -> None:
    bundle = DiscoveryParams(t_min_s=1.0, t_max_s=3.0, lease_s=9.0)
    timing = resolve_timing(bundle, EngineConfig(lease_s=30.0))
    assert (timing.t_min_s, timing.t_max_s, timing.lease_s) == (1.0, 3.0, 30.0)
    assert dict(timing.sources) == {"t_min_s": "bundle", "t_max_s": "bundle", "lease_s": "config"}
    with pytest.raises(ValueError, match="inconsistent; fix: 0 <= t_min_s <= t_max_s"):
        resolve_timing(bundle, EngineConfig(t_min_s=5.0))


class Echo:
    """A node that answers every datagram once, to its source."""

    def __init__(self) -> None:
        self.got: list[tuple[bytes, tuple[str, int], float]] = []
        self.out: list[tuple[bytes, tuple[str, int]]] = []
        self.timer: float | None = None

    def receive_datagram(self, data: bytes, source: tuple[str, int], now: float) -> None:
        self.got.append((data, source, now))
        if data == b"ping":
            self.out.append((b"pong", source))

    def handle_timer(self, now: float) -> None:
        self.timer = None
        self.out.append((b"tick", ("239.255.0.1", 7400)))

    def datagrams_to_send(self) -> list[tuple[bytes, tuple[str, int]]]:
        out, self.out = self.out, []
        return out

    def get_timer(self) -> float | None:
        return self.timer

    def next_event(self) -> None:
        return None


def test_memnet_multicast_fanout_unicast_routing_delay_and_loopback() -> None:
    net = MemNet(random.Random(1), Channel(delay_s=0.01))
    nodes = [Echo() for _ in range(3)]
    nodes[0].timer = 1.0
    for i, node in enumerate(nodes):
        net.add(
            node,
            f"10.0.0.{i + 1}",
            (7410 + i, 7400),
            groups=(("239.255.0.1", 7400),),
            source_port=7410 + i,
        )
    net.run_until(2.0)
    for node in nodes:  # every subscriber, the sender too (loopback), after the delay
        assert [(d, s, round(t, 6)) for d, s, t in node.got] == [
            (b"tick", ("10.0.0.1", 7410), 1.01)
        ]
    net.call_at(3.0, lambda now: nodes[1].out.append((b"ping", ("10.0.0.3", 7412))))
    net.call_at(3.0, lambda now: net.poke(1))
    net.run_until(4.0)
    assert nodes[2].got[-1][:2] == (b"ping", ("10.0.0.2", 7411))
    assert nodes[1].got[-1][:2] == (b"pong", ("10.0.0.3", 7412))
    nodes[1].out.append((b"x", ("10.0.0.3", 9999)))  # nobody listens there
    net.poke(1)
    assert net.stats.unroutable == 1
    assert [t.node for t in net.transmissions] == [0, 1, 2, 1]


def test_memnet_loss_and_duplication_follow_the_seed() -> None:
    def run(seed: int) -> tuple[int, int, int]:
        net = MemNet(random.Random(seed), Channel(loss=0.3, duplicate=0.2))
        sink = Echo()
        src = Echo()
        net.add(sink, "10.0.0.1", (7400,), groups=(("239.255.0.1", 7400),))
        net.add(src, "10.0.0.2", (7402,))
        for k in range(500):
            net.call_at(k * 0.01, lambda now: src.out.append((b"m", ("239.255.0.1", 7400))))
            net.call_at(k * 0.01, lambda now: net.poke(1))
        net.run_until(10.0)
        return len(sink.got), net.stats.lost, net.stats.duplicated

    got, lost, duplicated = run(5)
    assert run(5) == (got, lost, duplicated)
    assert 0.6 * 500 < got < 0.95 * 500 and lost > 100 and duplicated > 50


# addresses that exercise every rule: plain, own, loopback, multicast, unspecified, broadcast
_ADDRS: tuple[str, ...] = ("10.0.0.1", "10.0.0.2", "127.0.0.1", "127.3.0.9", "224.0.0.1")
_ADDRS += ("239.1.1.1", "0.0.0.0", "255.255.255.255", "223.255.0.1", "240.0.0.1")  # noqa: S104


def _usable_by_definition(
    locators: list[tuple[int, str]], source_host: str, own_octets: bytes
) -> bool:
    """docs/security.md, issue 10 attack 7, one locator at a time: the plain definition the
    engine's per-payload precomputation (``_LocatorFacts``) must agree with."""
    own_source = own_octets != b"" and source_host == ".".join(map(str, own_octets))
    for kind, host in locators:
        if kind != LOCATOR_KIND_UDPv4:
            continue
        octets = bytes(int(x) for x in host.split("."))
        if 224 <= octets[0] <= 239 or octets in (bytes(4), b"\xff" * 4):
            return False
        if octets[0] == 127 and not source_host.startswith("127."):
            return False
        if octets == own_octets and not own_source:
            return False
    return True


@given(
    meta=st.lists(st.tuples(st.sampled_from([LOCATOR_KIND_UDPv4, 2]), st.sampled_from(_ADDRS))),
    default=st.lists(st.tuples(st.sampled_from([LOCATOR_KIND_UDPv4]), st.sampled_from(_ADDRS))),
    source=st.sampled_from(_ADDRS),
    own=st.sampled_from((*_ADDRS, "")),
)
def test_locator_check_precomputed_per_payload_agrees_with_its_definition(
    meta: list[tuple[int, str]], default: list[tuple[int, str]], source: str, own: str
) -> None:
    def locs(items: list[tuple[int, str]]) -> tuple[Locator, ...]:
        return tuple(
            Locator(kind, 7410, bytes(12) + bytes(int(x) for x in host.split(".")))
            for kind, host in items
        )

    part = SpdpParticipant(
        GuidPrefix(bytes(12)),
        metatraffic_unicast_locators=locs(meta),
        default_unicast_locators=locs(default),
    )
    own_octets = received_module.ipv4_octets(own)
    own_dotted = ".".join(map(str, own_octets))
    facts = received_module.locator_facts(part)
    expected = _usable_by_definition([*meta, *default], source, own_octets)
    assert facts.usable(source, own_octets, own_dotted) is expected
