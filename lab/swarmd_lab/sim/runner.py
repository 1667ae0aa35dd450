"""One simulated run: N drones, one protocol, one seed, a 60 s window of virtual time.

``run(scenario)`` is a pure function of the scenario: the same scenario (seed included)
gives the same result dictionary, and ``json.dumps(result, sort_keys=True)`` the same bytes.
Wall-clock time is measured by the caller (``__main__``), never inside the run.
"""

from __future__ import annotations

import gc
import math
import random
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field
from typing import Any, Final

import numpy as np

from swarmd.dataplane.seal import NET_OVERHEAD_BYTES
from swarmd.discovery.config import MODES
from swarmd_lab.sim.channel import Channel, ChannelConfig, Datagram, Kind
from swarmd_lab.sim.clock import VirtualClock
from swarmd_lab.sim.node import Ledger, NodeContext, SimNode
from swarmd_lab.sim.placement import PLACEMENTS, place
from swarmd_lab.sim.protocols import PROTOCOLS, build_nodes
from swarmd_lab.sim.workload import Workload

WINDOW_S: Final = 60.0
_DATA: Final = Kind.DATA  # bound once (a class-attribute lookup per frame otherwise)
# the oldest generation's threshold during a baseline model's run: never reached
_NO_FULL_COLLECTION: Final = 2**31 - 1
# the protocols whose runs suspend the cyclic collector whole (_collections_for)
_SWARMD: Final = ("swarmd", "swarmd-auth")
Progress = Callable[[float], None]


@dataclass(frozen=True, slots=True)
class Scenario:
    """Everything a run depends on. ``placement``/``spacing_m`` place the drones;
    ``start_spread_s``: drones power up at U(0, spread) (containers never start at once)."""

    protocol: str
    n: int
    seed: int
    window_s: float = WINDOW_S
    placement: str = "grid"
    spacing_m: float = 2.0
    start_spread_s: float = 1.0
    workload: bool = True
    swarmd_mode: str = "adaptive"
    # swarmd's vouching (EngineConfig.vouch; docs/discovery.md "Vouching"); off: plain renewals
    vouch: bool = True
    channel: ChannelConfig = field(default_factory=ChannelConfig)

    def check(self) -> None:
        """Raise ``ValueError`` with one line naming the option and the fix."""
        if self.protocol not in PROTOCOLS:
            raise ValueError(
                f"--protocol {self.protocol!r} is unknown; use one of {', '.join(PROTOCOLS)}"
            )
        if self.n < 2:
            raise ValueError(f"--n {self.n}: discovery needs at least 2 drones")
        if self.placement not in PLACEMENTS:
            raise ValueError(f"--placement {self.placement!r}: use one of {', '.join(PLACEMENTS)}")
        if not self.window_s > 0:
            raise ValueError(f"--window {self.window_s}: use a positive number of seconds")
        if self.start_spread_s < 0:
            raise ValueError(f"--start-spread {self.start_spread_s}: use a value >= 0")
        if self.swarmd_mode not in MODES:
            raise ValueError(f"--swarmd-mode {self.swarmd_mode!r}: use 'paper' or 'adaptive'")


def run(
    scenario: Scenario,
    progress: Progress | None = None,
    *,
    milestones: dict[str, float] | None = None,
    wall: Callable[[], float] | None = None,
) -> dict[str, Any]:
    """Simulate ``scenario`` and return its JSON-ready result (see ``docs/simulator.md``).

    ``progress`` is called with the fraction of virtual time done; ``milestones`` receives
    ``wall()`` when every pair is discovered (the caller's clock; the result never sees it).
    """
    scenario.check()
    with _collections_for(scenario.protocol):
        return _run(scenario, progress, milestones, wall)


@contextmanager
def _collections_for(protocol: str) -> Iterator[None]:
    """Suspend CPython's cyclic garbage collector for a swarmd run, and its full
    (oldest-generation) collections for a baseline model's; reference counting goes on, and
    the collector's state is restored afterwards.

    A 1000-drone run builds ~10^6 long-lived objects (every engine's peer table) and many
    more that live a while (retry heap entries), and the collector traverses each container
    that survives a young collection again in the next generation. Full collections were the
    first cost (18 passes, ~7.5 s of a ~55 s run, ``gc.callbacks``; suspended since issue
    13). The young collections that remained, with the full one at the interpreter's
    exit, took 15.9 % of the instructions, 31.5 % of the L1 read misses and 58.0 % of the
    read misses of a 2 MB cache in a process simulating the first 8 s of the 1000-drone
    window (cachegrind; docs/simulator.md, "Session 18"), and a swarmd run leaves almost
    nothing for them: ~40 objects in two 150-drone runs, beyond the imports' ~1,000
    (``gc.get_stats``). Nothing in a run has a finaliser and no result depends on when memory
    is freed. The baseline models do leave cycles (~10,000-30,000 objects in a 20-drone
    run), so their young collections go on."""
    enabled = gc.isenabled()
    thresholds = gc.get_threshold()
    if protocol in _SWARMD:
        gc.disable()
    else:
        gc.set_threshold(thresholds[0], thresholds[1], _NO_FULL_COLLECTION)
        gc.enable()  # even under a caller that turned it off (the CLI: __main__.py)
    try:
        yield
    finally:
        gc.set_threshold(*thresholds)
        if enabled:
            gc.enable()
        else:
            gc.disable()


def _run(
    scenario: Scenario,
    progress: Progress | None,
    milestones: dict[str, float] | None,
    wall: Callable[[], float] | None,
) -> dict[str, Any]:
    n, seed = scenario.n, scenario.seed
    clock = VirtualClock()
    ledger = Ledger(n)
    if milestones is not None and wall is not None:
        clock_fn = wall
        marks = milestones

        def mark(_now: float) -> None:
            marks["all_discovered"] = clock_fn()

        ledger.on_all_discovered(mark)
    layout_rng = random.Random(f"{seed}/layout")  # noqa: S311 - seeded simulation
    positions = place(scenario.placement, n, scenario.spacing_m, layout_rng)
    nodes: list[SimNode] = []
    workload: Workload | None = None

    def deliver(j: int, dgram: Datagram, now: float) -> None:
        if dgram.kind == Kind.DATA:
            if workload is not None:
                workload.receive(j, dgram, now)
                nodes[j].data_received(dgram.src, now)
            return
        nodes[j].receive(dgram, now)

    def deliver_many(receivers: list[int], dgram: Datagram, now: float) -> None:
        if dgram.kind is _DATA:
            for j in receivers:
                deliver(j, dgram, now)
            return
        nodes[receivers[0]].receive_each(nodes, receivers, dgram, now)

    channel = Channel(
        clock, positions, scenario.channel, seed=seed, deliver=deliver, deliver_many=deliver_many
    )
    contexts = [NodeContext(i, n, clock, channel.send, ledger, seed) for i in range(n)]
    nodes.extend(build_nodes(scenario, contexts, channel))
    if scenario.workload:
        # swarmd-auth: the user data is authenticated too (+12 octets net per datagram,
        # docs/wire.md "User data"); same datagrams, same schedule
        extra = NET_OVERHEAD_BYTES if scenario.protocol == "swarmd-auth" else 0
        workload = Workload(clock, ledger, channel.send, n, extra_bytes=extra)
    start_rng = random.Random(f"{seed}/start")  # noqa: S311 - seeded simulation
    starts = [start_rng.uniform(0.0, scenario.start_spread_s) for _ in range(n)]
    for i, t0 in enumerate(starts):
        clock.call_at(t0, _starter(nodes[i], workload, i, clock))

    window = scenario.window_s
    next_report = 1.0
    while True:
        te = clock.next_time()
        ta = channel.next_access()
        if ta is not None and (te is None or ta < te):
            if ta >= window:
                break
            channel.access()
        elif te is not None:
            if te >= window:
                break
            clock.run_next()
        else:
            break
        if progress is not None and clock.now >= next_report:
            progress(min(1.0, clock.now / window))
            next_report = math.floor(clock.now) + 1.0
    if progress is not None:
        progress(1.0)
    return _result(scenario, channel, ledger, workload, starts)


def _starter(
    node: SimNode, workload: Workload | None, i: int, clock: VirtualClock
) -> Callable[[], None]:
    def start() -> None:
        node.start(clock.now)
        if workload is not None:
            workload.start_member(i, clock.now)

    return start


def _result(
    scenario: Scenario,
    channel: Channel,
    ledger: Ledger,
    workload: Workload | None,
    starts: list[float],
) -> dict[str, Any]:
    n = scenario.n
    c = channel.counters
    bins = int(math.ceil(scenario.window_s / scenario.channel.bin_s))
    disc = (c.bins[Kind.DISCOVERY] + [0] * bins)[:bins]
    data = (c.bins[Kind.DATA] + [0] * bins)[:bins]
    total = [a + b for a, b in zip(disc, data, strict=True)]
    discovery_frames = sum(disc)
    first = ledger.first[~np.eye(n, dtype=np.bool_)]
    found = first[~np.isnan(first)]
    per_s = 1.0 / scenario.channel.bin_s
    return {
        "protocol": scenario.protocol,
        "n": n,
        "seed": scenario.seed,
        "placement": scenario.placement,
        "spacing_m": scenario.spacing_m,
        "window_s": scenario.window_s,
        "success_rate": round(ledger.count / ledger.pairs, 6),
        "all_discovered": ledger.all_discovered_s is not None,
        "all_discovered_s": _round(ledger.all_discovered_s),
        "median_pair_discovery_s": _round(float(np.median(found)) if len(found) else None),
        "pairs_lost_events": ledger.lost_events,
        "delivery_success": round(workload.delivery_success(), 6) if workload else None,
        "frames_per_node_60s": round(discovery_frames / n, 4),
        "discovery_tx_per_node": round(c.tx_by_kind[Kind.DISCOVERY] / n, 4),
        "peak_pps": max(total) * per_s if total else 0.0,
        "peak_discovery_pps": max(disc) * per_s if disc else 0.0,
        "total_frames": sum(total),
        "discovery_frames": discovery_frames,
        "counters": {
            "mac_enqueued": c.mac_enqueued,
            "mac_tx": c.mac_tx,
            "mac_drop_overflow": c.mac_drop_overflow,
            "mac_drop_expired": c.mac_drop_expired,
            "phy_tx": c.phy_tx,
            "phy_retx": c.phy_retx,
            "phy_rx": c.phy_rx,
            "phy_rx_fail_collision": c.phy_rx_fail_collision,
            "phy_rx_fail_error": c.phy_rx_fail_error,
            "phy_drop_retry": c.phy_drop_retry,
            "collisions": c.collisions,
            "tx_discovery": c.tx_by_kind[Kind.DISCOVERY],
            "tx_data": c.tx_by_kind[Kind.DATA],
            "tx_discovery_bytes": c.tx_bytes_by_kind[Kind.DISCOVERY],
            "tx_data_bytes": c.tx_bytes_by_kind[Kind.DATA],
            "ack_discovery": c.ack_by_kind[Kind.DISCOVERY],
            "ack_data": c.ack_by_kind[Kind.DATA],
            "data_sent": workload.sent if workload else 0,
            "data_received": workload.received if workload else 0,
        },
        "series": {"bin_s": scenario.channel.bin_s, "discovery": disc, "data": data},
        "scenario": {
            "start_spread_s": scenario.start_spread_s,
            "swarmd_mode": scenario.swarmd_mode,
            "workload": scenario.workload,
            "last_start_s": _round(max(starts)),
            "channel": _channel_dict(scenario.channel),
            # only when off: runs with the default stay byte-identical to earlier ones
            **({} if scenario.vouch else {"vouch": False}),
        },
    }


def _channel_dict(cfg: ChannelConfig) -> dict[str, Any]:
    d = asdict(cfg)
    return {k: v for k, v in sorted(d.items())}


def _round(x: float | None) -> float | None:
    return None if x is None else round(x, 6)
