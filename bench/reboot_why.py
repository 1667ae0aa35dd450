"""Why the rebooted drone takes 2-4 s to list its peers at N = 20 (issue 20, "reboot in
the air"): the stages of a restart, read from an ns-3 run file and reproduced on MemNet.

    .venv/bin/python bench/reboot_why.py runs RUNFILE...
    .venv/bin/python bench/reboot_why.py memnet --run RUNFILE [--seeds 1 2 3] [--startup-s S]

``runs``: for each restart in a flight reboot run file (``bench/wifi/flight.py`` ``reboot``),
the restarted drone's first announcement (the instant its peers first see the new life: one
multicast, so all of them within a few ms), then each peer's answer (the restarted drone's
``discovered`` of it) after that announcement, beside the peer's link quality Q (its last
status poll before the restart) and the holdoff adaptive mode draws a first answer from,
U(W, 2W) with W = N / (B * max(Q, q_floor)) (``Debts.reply_delay``). Also the restarted
drone's own Q and its passive window U(0, W) (``awareness.passive_window_s``).

``memnet``: the same swarm on virtual time (``swarmd_lab.testing.build_swarm``, clean
channel, authenticated as the daemons are), each engine reading the Q its drone read in the
run; the drone N/2 is cut off at 40 s and replaced at 45 s + ``--startup-s`` (the process
start to the engine and its sockets, which MemNet does not have) by a new engine with a
higher epoch. Prints per seed the same stages: first announcement, the peers' answers (p50,
max), and the slowest peer with its Q. Nothing asserted: a reading, not a test.

``--what-if`` (bench only; the engine as shipped is not changed) prices the proposal in
docs/discovery.md, "Proposal: a restarted peer answered at once":

- ``answer-fast``: from the restart on, the peers draw their first answer from
  ``Debts.rejoin_delay()``, U(0, W1) with W1 = N / B (0.4 s at N = 20), instead of
  ``reply_delay()``, U(W, 2W) at their Q (in the steady swarm the restart is the only
  first answer owed, so swapping the draw for that window changes nothing else);
- ``passive-q1``: the restarted drone draws its passive timer at Q = 1, U(0, W1), then
  reads its real Q at once (its renewals and holdoffs as shipped).
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "lab"))

from swarmd_lab.testing import Swarm, build_swarm  # noqa: E402

from swarmd.discovery import EngineConfig, LinkSample  # noqa: E402
from swarmd.discovery.awareness import passive_window_s  # noqa: E402
from swarmd.discovery.debts import Debts  # noqa: E402
from swarmd.discovery.events import PeerDiscovered, PeerRestarted  # noqa: E402

KILL_S = 40.0  # bench/wifi/flight.py reboot: SETTLE_S + 10
DOWN_S = 5.0
# process start to the engine: 0.19-0.47 s in the N = 10 run (first announcement at
# +0.41 / +0.47 s, passive window 0.22 s at its Q 0.906); the middle of that range
STARTUP_S = 0.33


WHAT_IFS = ("answer-fast", "passive-q1")


class _FastAnswers(Debts):
    """``answer-fast``: a first answer after the rejoin delay U(0, W1)."""

    __slots__ = ()

    def reply_delay(self) -> float:
        return self.rejoin_delay()


def window_s(n: int, q: float) -> float:
    """Adaptive mode's W at ``q`` (the passive window and the reply holdoff's lower end)."""
    cfg = EngineConfig()
    return passive_window_s(
        "adaptive",
        q,
        swarm_size=n,
        t_min_s=cfg.t_min_s,
        t_max_s=cfg.t_max_s,
        announce_budget_fps=cfg.announce_budget_fps,
        q_floor=cfg.q_floor,
    )


def q_before(run: Mapping[str, Any], t: float) -> dict[int, float]:
    """Each drone's link Q at its last status poll before ``t`` (run file ``renewals``:
    ``(t, node, renewals, q, period, lease, ...)``)."""
    out: dict[int, float] = {}
    for rec in run["renewals"]:
        if rec[0] < t and isinstance(rec[3], int | float):
            out[int(rec[1])] = float(rec[3])
    return out


def read_run(path: Path) -> None:
    run = json.loads(path.read_text())
    n = int(run["n"])
    changes: dict[int, list[tuple[float, int, str]]] = {
        int(i): [(float(t), int(p), str(c)) for t, p, c in v] for i, v in run["changes"].items()
    }
    up = {"discovered", "regained", "restarted"}
    print(f"{path.name}: N = {n}, engine {run['setup'].get('commit')}")
    for (restart, node), (_, _, _, state) in zip(
        run["restarts"], [e for e in run["events"] if e[2] == "start"], strict=False
    ):
        q = q_before(run, restart)
        seen = [
            min(
                (t for t, p, c in changes[i] if p == node and c in up and t >= restart),
                default=None,
            )
            for i in range(n)
            if i != node
        ]
        announced = min(s for s in seen if s is not None) - restart
        spread = max(s for s in seen if s is not None) - min(s for s in seen if s is not None)
        w_self = window_s(n, q.get(node, 0.0))
        print(
            f"  restart at {restart:.2f} s (state {state}): its Q {q.get(node, 0.0):.3f}, "
            f"passive window U(0, {w_self:.2f}) s; first announcement seen by its peers at "
            f"+{announced:.2f} s (all {n - 1} within {spread * 1000:.0f} ms)"
        )
        rows: list[tuple[float, int, float, float]] = []
        for t, p, c in sorted(changes[node]):
            if t >= restart and c in up and p not in {r[1] for r in rows}:
                w = window_s(n, q.get(p, 0.0))
                rows.append((t - restart, p, q.get(p, 0.0), w))
        finds = [r[0] for r in rows]
        print(
            f"    it lists its peers at +{min(finds):.2f} .. +{max(finds):.2f} s "
            f"(p50 {statistics.median(finds):.2f}); after its announcement: "
            f"+{min(finds) - announced:.2f} .. +{max(finds) - announced:.2f} s"
        )
        inside = sum(1 for a, _, _, w in rows if w - 0.05 <= a - announced <= 2 * w + 0.05)
        print(
            f"    answers inside the answering peer's U(W, 2W) (+-50 ms): {inside} of {len(rows)}"
        )
        for a, p, qp, w in sorted(rows, reverse=True)[:4]:
            print(
                f"    slowest: uav{p + 1} +{a:.2f} s (+{a - announced:.2f} after the "
                f"announcement), its Q {qp:.3f}, U({w:.2f}, {2 * w:.2f})"
            )


def memnet(run_path: Path, seeds: Sequence[int], startup_s: float, what_ifs: Sequence[str]) -> None:
    run = json.loads(run_path.read_text())
    n = int(run["n"])
    q = q_before(run, float(run["restarts"][0][0]))
    print(
        f"MemNet, N = {n}, each drone at its Q of {run_path.name}; uav{n // 2 + 1} cut at "
        f"{KILL_S:g} s, a new life at {KILL_S + DOWN_S:g} + {startup_s:g} s; times from "
        f"{KILL_S + DOWN_S:g} s (the harness's restart); what-if: {', '.join(what_ifs) or 'none'}"
    )
    for seed in seeds:
        print(f"  seed {seed}: {one_restart(n, q, seed, startup_s, what_ifs)}")


def _first_frames(swarm: Swarm) -> int:
    kinds = swarm.tx_kinds()
    return kinds["announce"] + kinds["reply"]


def one_restart(
    n: int, q: Mapping[int, float], seed: int, startup_s: float, what_ifs: Sequence[str]
) -> str:
    """One seeded swarm, drone N/2 restarted; its stages as one line."""
    node = n // 2
    t0 = KILL_S + DOWN_S
    t_back = t0 + startup_s
    q_self = q.get(node, 1.0)
    q_draw = 1.0 if "passive-q1" in what_ifs else q_self
    swarm = build_swarm(n, seed=seed, authenticated=True)

    def read(now: float) -> None:
        for i, engine in enumerate(swarm.engines):
            engine.update_link_quality(LinkSample(q=q.get(i, 1.0), source="static"), now)
            swarm.net.poke(i)

    def reboot(now: float) -> None:
        if "answer-fast" in what_ifs:
            for i, other in enumerate(swarm.engines):
                if i != node:
                    # the same slots, one method more: the engine and its receive path hold
                    # this one object
                    other._debts.__class__ = _FastAnswers  # noqa: SLF001 - a what-if
        swarm.restart(node, now, seed=seed * 1000 + node, q=q_draw)
        if q_draw != q_self:
            swarm.engines[node].update_link_quality(LinkSample(q=q_self, source="static"), now)

    swarm.net.call_at(1.0, read)
    swarm.net.call_at(KILL_S, lambda now: swarm.net.isolate(node))
    swarm.run_until(t_back - 0.01)
    frames_before = _first_frames(swarm)
    swarm.net.call_at(t_back, reboot)
    swarm.run_until(t_back + 10.0)
    seen = [
        t - t0
        for i, events in enumerate(swarm.events)
        for t, e in events
        if i != node and t >= t_back and isinstance(e, PeerRestarted)
    ]
    finds: dict[int, float] = {}
    for t, e in swarm.events[node]:
        if t >= t_back and isinstance(e, PeerDiscovered):
            finds.setdefault(swarm.index_of[e.name], t - t0)
    if not seen or not finds:
        return f"no restart seen ({len(seen)}) or nothing found ({len(finds)})"
    slow = max(finds, key=lambda p: finds[p])
    return (
        f"announcement +{min(seen):.2f} s (passive {min(seen) - startup_s:.2f} of "
        f"U(0, {window_s(n, q_draw):.2f})); lists peers p50 "
        f"+{statistics.median(finds.values()):.2f} max +{finds[slow]:.2f} s "
        f"({len(finds)}/{n - 1}); slowest uav{slow + 1} Q {q.get(slow, 1.0):.3f}, answer "
        f"+{finds[slow] - min(seen):.2f} after the announcement; announce+reply frames "
        f"{_first_frames(swarm) - frames_before}"
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=(__doc__ or "").split("\n\n")[0],
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    sub = parser.add_subparsers(dest="cmd", required=True)
    runs = sub.add_parser("runs", help="the stages of each restart in ns-3 reboot run files")
    runs.add_argument("files", type=Path, nargs="+")
    mem = sub.add_parser("memnet", help="the same restart on MemNet, Q from a run file")
    mem.add_argument("--run", type=Path, required=True, help="an ns-3 reboot run file (its Qs)")
    mem.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3, 4, 5])
    mem.add_argument("--startup-s", type=float, default=STARTUP_S)
    mem.add_argument("--what-if", choices=WHAT_IFS, nargs="*", default=[])
    args = parser.parse_args(argv)
    if args.cmd == "runs":
        for path in args.files:
            if not path.is_file():
                parser.error(f"{path}: no such run file")
            read_run(path)
    else:
        if not args.run.is_file():
            parser.error(f"{args.run}: no such run file")
        memnet(args.run, args.seeds, args.startup_s, args.what_if)
    return 0


if __name__ == "__main__":
    sys.exit(main())
