"""The testbed's *fade* on virtual time: the real discovery engines on MemNet, each pair's
link cut exactly when the ns-3 scenario has it out of range (issue 20; docs/benchmarks.md,
"Flight", "The fade's slow re-discovery").

    .venv/bin/python bench/flight_fade.py [--n 10 20] [--seeds 1 .. 10] [--engine-root DIR] \
        [--periodic]

The scenario is ``bench/wifi/flight.fade(n, 1)`` (the runs' seed: uav<n> swings 30-110 m
from the group from 30 s for 120 s, each swing 6-10 s as the seed draws it; ``--periodic``:
every 8 s exactly, the fade of the runs and figures before the irregular one); the ground
truth it defines (a pair is in range at -82 dBm or more, a step every 0.5 s) decides every
datagram: delivered in range, lost out of it. As on the channel:

- each drone reads its link quality every second, eq. 2 from the mean signal of the drones
  in its range (``flight_cpp``'s windowed link file; none in range: SNR 0, Q = 0), so the
  fading drone reads Q = 0 throughout and the group 0.5-0.85, as the runs' ``renewals`` say;
- each member that has the commander discovered reports readiness to it at 1 Hz while they
  are in range (``peer_traffic``: the commander's vouches rest on it); ``--prompt-readiness``
  adds the report sent at once when a member finds the commander again (the swarm core
  since ``e2d09ed``).

The seed drives the engines' ``random.Random`` (``build_swarm``); the scenario is the same
for all. The measures are the testbed's own (``bench/wifi/flight_measures.measure`` on the
engines' events), printed per seed with the slowest re-discovery (observer <- peer, the
return into range, the re-discovery) and the discovery frames by kind. ``--engine-root``
runs another checkout's engine (a ``git worktree`` of an older commit) under the same
harness: the scenario and the measures always come from this tree. Each seed's line and a
last line per N also count the fading drone's own PeerLost events and their largest burst at
one instant (a vouched lease's end: docs/flight-history.md, "The fading drone's losses at
N = 20 (session 9)").
"""

from __future__ import annotations

import argparse
import importlib.util
import random
import statistics
import sys
from pathlib import Path
from types import ModuleType
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
READ_PERIOD_S = 1.0  # the daemon's link.poll_interval_s
READINESS_PERIOD_S = 1.0
SNR_FLOOR_DB, SNR_SPAN_DB = 25.0, 15.0  # eq. 2: Q = clamp((SNR - 25) / 15, 0, 1)


def _load(name: str, path: Path) -> ModuleType:
    spec = importlib.util.spec_from_file_location(name, path)
    assert spec is not None
    assert spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module


def run(
    n: int,
    seed: int,
    *,
    prompt_readiness: bool,
    loss: float,
    flight: Any,
    measures: Any,
    periodic: bool = False,
) -> dict[str, Any]:
    from swarmd_lab.testing import build_swarm

    from swarmd.discovery import LinkSample
    from swarmd.discovery.events import PeerDiscovered, PeerLost, PeerRestarted
    from swarmd.discovery.peers import PeerState

    scenario = flight.fade(n, 1, period_spread_s=0.0) if periodic else flight.make("fade", n, 1)
    step = flight.STEP_S
    truth = scenario.truth(step)
    in_range: list[list[list[bool]]] = [m for _, m in truth]
    last = len(in_range) - 1
    swarm = build_swarm(n, seed=seed)
    net = swarm.net

    def now_range() -> list[list[bool]]:
        return in_range[min(last, int(net.now / step + 1e-9))]

    commander_to_fader: list[float] = []  # the commander's frames in the fader's range

    def link_loss(a: int, b: int) -> float:
        if not now_range()[a][b]:
            return 1.0
        if a == 0 and b == n - 1:
            commander_to_fader.append(net.now)
        return loss

    net.link_loss = link_loss
    report_rng = random.Random(seed)  # noqa: S311 - seeded simulation
    commander = 0
    names = [p.name for p in swarm.bundle.participants]
    prefixes = [p.guid_prefix for p in swarm.bundle.participants]

    def read_q(i: int) -> Any:
        def tick(now: float) -> None:
            if i < len(swarm.engines):
                pos = scenario.positions_at(now)
                heard = [j for j in range(n) if now_range()[i][j]]
                if heard:
                    signal = statistics.fmean(flight.rx_dbm(_dist(pos[i], pos[j])) for j in heard)
                    snr = signal - flight.NOISE_DBM
                else:
                    snr = 0.0
                q = min(1.0, max(0.0, (snr - SNR_FLOOR_DB) / SNR_SPAN_DB))
                swarm.engines[i].update_link_quality(
                    LinkSample(q=q, snr_db=snr, source="file"), now
                )
                net.poke(i)
            if now + READ_PERIOD_S <= scenario.duration_s:
                net.call_at(now + READ_PERIOD_S, tick)

        return tick

    def discovered(observer: int, peer: int) -> bool:
        view = swarm.engines[observer].peer(names[peer])
        return view is not None and view.state is PeerState.DISCOVERED

    def report(m: int, now: float) -> None:
        lost = loss and report_rng.random() < loss
        if now_range()[m][commander] and discovered(m, commander) and not lost:
            swarm.engines[commander].peer_traffic(prefixes[m], now)
            net.poke(commander)

    def readiness(m: int) -> Any:
        def tick(now: float) -> None:
            if len(swarm.engines) == n:
                report(m, now)
            if now + READINESS_PERIOD_S <= scenario.duration_s:
                net.call_at(now + READINESS_PERIOD_S, tick)

        return tick

    for i in range(n):
        net.call_at(0.05 + 0.9 * i / n, read_q(i))
        if i != commander:
            net.call_at(1.0 + 0.9 * i / n, readiness(i))
    if prompt_readiness:
        on_event = net.on_event
        assert on_event is not None

        def with_prompt(node: int, event: object, now: float) -> None:
            on_event(node, event, now)
            name = getattr(event, "name", None)
            if node != commander and isinstance(event, PeerDiscovered) and name == names[0]:
                net.call_at(now, lambda t: report(node, t))

        net.on_event = with_prompt

    swarm.run_until(scenario.duration_s)
    changes: dict[int, list[tuple[float, int, str]]] = {i: [] for i in range(n)}
    for i, events in enumerate(swarm.events):
        seen: set[int] = set()
        for t, e in events:
            j = swarm.index_of[str(getattr(e, "name", ""))] if hasattr(e, "name") else -1
            if isinstance(e, PeerDiscovered):
                changes[i].append((t, j, "regained" if j in seen else "discovered"))
                seen.add(j)
            elif isinstance(e, PeerLost):
                changes[i].append((t, j, "lost"))
            elif isinstance(e, PeerRestarted):
                changes[i].append((t, j, "restarted"))
    result: dict[str, Any] = measures.measure(truth, changes, {}, n=n, lease_s=20.0)
    result["slowest"] = _slowest(truth, changes, n, measures)
    result["back_to_found"] = _back_to_found(in_range, step, changes, n)
    result["losses"] = [
        (round(t, 2), i, j, next((round(u, 2) for u, q, c in changes[i] if q == j and u > t), None))
        for i in range(n)
        for t, j, c in changes[i]
        if c == "lost"
    ]
    result["commander_to_fader"] = commander_to_fader
    kinds = swarm.tx_kinds()
    result["tx_kind"] = {k: kinds[k] for k in ("announce", "reply", "probe", "renewal")}
    return result


def fader_losses(
    losses: list[tuple[float, int, int, float | None]], fader: int
) -> tuple[int, int, float | None]:
    """The fading drone's (``fader``) PeerLost count in ``result["losses"]`` (t, observer,
    peer, found again), its largest burst (peers lost at one instant: a vouched lease's end
    loses every member the commander's last vouch listed) and that burst's time."""
    at_once: dict[float, int] = {}
    for t, i, _, _ in losses:
        if i == fader:
            at_once[t] = at_once.get(t, 0) + 1
    if not at_once:
        return 0, 0, None
    t_max = max(at_once, key=lambda t: (at_once[t], -t))
    return sum(at_once.values()), at_once[t_max], t_max


def _back_to_found(
    in_range: list[list[list[bool]]],
    step: float,
    changes: dict[int, list[tuple[float, int, str]]],
    n: int,
) -> list[float]:
    """For every ``lost`` (intermittent or in range: a dropout), from the first moment at or
    after it that the peer is in range again to its re-discovery (the run's end if never)."""
    out = []
    for i in range(n):
        for t, j, c in changes[i]:
            if c != "lost":
                continue
            k = int(t / step)
            while k < len(in_range) and not in_range[k][i][j]:
                k += 1
            back = max(t, k * step)
            found = next(
                (u for u, q, c2 in changes[i] if q == j and u > t and c2 != "lost"),
                (len(in_range) - 1) * step,
            )
            out.append(round(found - back, 2))
    return out


def _dist(a: tuple[float, float, float], b: tuple[float, float, float]) -> float:
    return float(sum((x - y) ** 2 for x, y in zip(a, b, strict=True)) ** 0.5)


def _slowest(
    truth: Any, changes: dict[int, list[tuple[float, int, str]]], n: int, measures: Any
) -> tuple[float, int, int, float, float] | None:
    """(latency, observer, peer, return, re-discovery) of the slowest re-discovery, by the
    same rule as ``measures.measure``."""
    worst: tuple[float, int, int, float, float] | None = None
    for i in range(n):
        for j in range(n):
            if i == j:
                continue
            mine = [(t, c) for t, p, c in sorted(changes[i]) if p == j]
            lost_at = [t for t, c in mine if c == "lost"]
            runs = measures.spans(measures.reachable(truth, {}, i, j))
            for k, (a, _b, up) in enumerate(runs):
                if up or k + 1 >= len(runs) or not any(a <= t <= runs[k + 1][0] for t in lost_at):
                    continue
                back = runs[k + 1][0]
                found = [
                    t
                    for t, c in mine
                    if c in measures.UP_KINDS and t >= back - measures.TOLERANCE_S
                ]
                if found:
                    lat = max(0.0, found[0] - back)
                    if worst is None or lat > worst[0]:
                        worst = (round(lat, 3), i, j, back, round(found[0], 3))
    return worst


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--n", type=int, nargs="+", default=[10, 20])
    parser.add_argument("--seeds", type=int, nargs="+", default=list(range(1, 11)))
    parser.add_argument("--engine-root", type=Path, default=ROOT)
    parser.add_argument("--prompt-readiness", action="store_true")
    parser.add_argument(
        "--loss",
        type=float,
        default=0.0,
        help="each datagram and readiness report in range lost with this p",
    )
    parser.add_argument("--verbose", action="store_true", help="every loss and its end")
    parser.add_argument(
        "--periodic", action="store_true", help="the old fade: every swing exactly 8 s"
    )
    args = parser.parse_args(argv)
    root = args.engine_root.resolve()
    sys.path[:0] = [str(root), str(root / "lab")]
    flight = _load("fade_flight", ROOT / "bench" / "wifi" / "flight.py")
    measures = _load("fade_measures", ROOT / "bench" / "wifi" / "flight_measures.py")
    for n in args.n:
        worst_all: list[float] = []
        worst_measured: list[float] = []
        fader_all: list[int] = []  # the fading drone's PeerLost per seed
        bursts: list[int] = []  # its largest burst per seed
        for seed in args.seeds:
            r = run(
                n,
                seed,
                prompt_readiness=args.prompt_readiness,
                loss=args.loss,
                flight=flight,
                measures=measures,
                periodic=args.periodic,
            )
            red, lost = r["rediscovery_s"], r["lost_reports"]
            back = r["back_to_found"]
            worst_all.append(max([red["max"] or 0.0, *back]))
            worst_measured.append(red["max"] or 0.0)
            fader_lost, burst, burst_at = fader_losses(r["losses"], n - 1)
            # the commander's last frame that reached the fader (sure only at --loss 0): a
            # vouched lease ends lease - w - 0.5 = 17 s after it (docs/discovery.md, "Vouching")
            vouch_at = max(
                (t for t in r["commander_to_fader"] if t < (burst_at or 0.0)), default=None
            )
            since = None if vouch_at is None or burst_at is None else round(burst_at - vouch_at, 2)
            fader_all.append(fader_lost)
            bursts.append(burst)
            print(
                f"fade N={n} seed {seed}: lost {lost} re-discovery n={red['count']} "
                f"p50 {red['p50']} max {red['max']} slowest {r['slowest']} "
                f"not re-discovered {r['not_rediscovered']} {r['tx_kind']}; every loss, from the "
                f"return to re-discovery: max {max(back, default=None)} "
                f"over 2 s {sum(1 for b in back if b > 2.0)}/{len(back)}; uav{n} lost "
                f"{fader_lost} (largest burst {burst} at {burst_at}, {since} s after the "
                f"commander's last frame in its range)"
                + (
                    f"\n    lost (t, observer, peer, found again): {r['losses']}"
                    if args.verbose
                    else ""
                )
            )
        over = sum(1 for w in worst_measured if w > 2.0)
        over_all = sum(1 for w in worst_all if w > 2.0)
        print(
            f"fade N={n}: re-discovery max per seed (the testbed's measure) {worst_measured}, "
            f"over 2 s in {over} of {len(worst_measured)} seeds; counting every loss "
            f"(dropouts too) {worst_all}, over 2 s in {over_all}"
        )
        ranked = sorted(fader_all)
        big = sum(1 for b in bursts if b >= 13)
        print(
            f"fade N={n}: uav{n}'s PeerLost per seed {fader_all} (sum {sum(fader_all)}, "
            f"min {ranked[0]}, p50 {ranked[len(ranked) // 2]}, max {ranked[-1]}; at most 1 in "
            f"{sum(1 for k in fader_all if k <= 1)} seeds); a burst of 5+ at one instant in "
            f"{sum(1 for b in bursts if b >= 5)} seeds, of 13+ in {big}"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
