"""Discovery frames on the in-memory network: N real engines, virtual time, seeded loss.

    .venv/bin/python bench/discovery.py [--sizes 10 50 200] [--modes adaptive paper]
                                        [--seconds 60] [--seed 1] [--json] [--json-out F]

For each swarm size, engine mode and channel (clean: no loss, Q = 1; lossy: 10 % loss per
receiver, 2 ms jitter, Q = 0.5) it runs ``swarmd_lab.testing.build_swarm`` for
``--seconds`` of virtual time and reports, per node: every frame sent, discovery frames
(announcements and directed replies), lease renewals and last-chance probes; the peak
frames per second on the channel (1 s bins); when every ordered pair had heard each other at
least once ("all met") and when all pairs were discovered at the same instant ("all at
once"); and lease losses.

``cyclone model`` is not a measurement: it is stock Cyclone DDS's SPDP schedule from
docs/benchmarks.md's reference (one DATA(p) every 8 s plus 4 directed replies to each newly
seen peer), i.e. 60 / 8 + 4 (N - 1) frames per node in the first minute.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections import Counter
from pathlib import Path
from typing import Any, cast

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from swarmd_lab.memnet import Channel  # noqa: E402
from swarmd_lab.testing import build_swarm  # noqa: E402

from swarmd.discovery.config import MODES, EngineConfig, Mode  # noqa: E402

CHANNELS: dict[str, tuple[Channel, float]] = {
    "clean": (Channel(loss=0.0, delay_s=0.0005), 1.0),
    "lossy": (Channel(loss=0.1, delay_s=0.0005, jitter_s=0.002), 0.5),
}


def cyclone_model_per_node(n: int, seconds: float) -> float:
    return seconds / 8.0 + 4.0 * (n - 1)


def run(n: int, mode: str, channel_name: str, seconds: float, seed: int) -> dict[str, Any]:
    channel, q = CHANNELS[channel_name]
    started = time.perf_counter()
    config = EngineConfig(mode=cast(Mode, mode))
    swarm = build_swarm(n, seed=seed, config=config, channel=channel, q=q)
    swarm.run_until(seconds)
    tx = [t for t in swarm.net.transmissions if t.time <= seconds]
    kinds = swarm.tx_kinds()
    bins = Counter(int(t.time) for t in tx)
    return {
        "n": n,
        "mode": mode,
        "channel": channel_name,
        "q": q,
        "loss": channel.loss,
        "seconds": seconds,
        "seed": seed,
        "frames_per_node": round(len(tx) / n, 2),
        "discovery_frames_per_node": round((kinds["announce"] + kinds["reply"]) / n, 2),
        "renewals_per_node": round(kinds["renewal"] / n, 2),
        # last-chance probes (docs/discovery.md, "Probing before a lease ends")
        "probes_per_node": round(kinds["probe"] / n, 2),
        "multicast_per_node": round(sum(1 for t in tx if t.multicast) / n, 2),
        "peak_frames_per_s": max(bins.values()) if bins else 0,
        "all_met_s": None if swarm.all_met_at is None else round(swarm.all_met_at, 3),
        "all_at_once_s": None if swarm.full_at is None else round(swarm.full_at, 3),
        "lease_losses": swarm.lost,
        "cyclone_model_per_node": cyclone_model_per_node(n, seconds),
        "wall_s": round(time.perf_counter() - started, 1),
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[10, 50, 200])
    parser.add_argument("--modes", nargs="+", default=["adaptive", "paper"], choices=MODES)
    parser.add_argument("--channels", nargs="+", default=list(CHANNELS), choices=list(CHANNELS))
    parser.add_argument("--seconds", type=float, default=60.0)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--json", action="store_true", help="print one JSON document")
    parser.add_argument("--json-out", type=Path, help="also write the JSON document to this file")
    args = parser.parse_args(argv)
    rows = [
        run(n, mode, ch, args.seconds, args.seed)
        for ch in args.channels
        for mode in args.modes
        for n in args.sizes
    ]
    document = json.dumps({"python": sys.version.split()[0], "rows": rows}, indent=2)
    if args.json_out is not None:
        args.json_out.write_text(document + "\n")
    if args.json:
        print(document)
        return 0
    header = (
        f"{'channel':7} {'mode':8} {'N':>4} {'frames/node':>11} {'disc/node':>9} "
        f"{'renew/node':>10} {'probe/node':>10} {'peak f/s':>8} {'all met s':>9} {'at once s':>9} "
        f"{'losses':>6} {'cyclone model':>13}"
    )
    print(f"first {args.seconds:g} s of virtual time, seed {args.seed}")
    print(header)
    for r in rows:

        def fmt(v: float | None) -> str:
            return "never" if v is None else f"{v:.2f}"

        print(
            f"{r['channel']:7} {r['mode']:8} {r['n']:>4} {r['frames_per_node']:>11.2f} "
            f"{r['discovery_frames_per_node']:>9.2f} {r['renewals_per_node']:>10.2f} "
            f"{r['probes_per_node']:>10.2f} "
            f"{r['peak_frames_per_s']:>8} {fmt(r['all_met_s']):>9} {fmt(r['all_at_once_s']):>9} "
            f"{r['lease_losses']:>6} {r['cyclone_model_per_node']:>13.1f}"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
