"""Flight scenarios on the emulated 802.11 testbed (issue 20): one run per scenario, N,
repeat and contender, measured against the scenario's ground truth.

    sudo .venv/bin/python -m bench.wifi.flight_run --scenarios split --n 10 --repeat 1 \\
        --contenders swarmd [--dilation 2] [--stagger-s 8] [--out bench/results/flight]

Each run is a fresh testbed as in ``bench/wifi/run.py`` (namespaces, taps, the stacks
behind the start barrier, the same validity rule: lag p99 above ``--max-lag-ms`` marks
the run invalid), with the channel process ``bench.wifi.flight_channel``: the scenario's
waypoints move the nodes from the release on and the link files are windowed. While it
runs the harness polls every daemon's ``status`` (round robin) for its ``peer_changes``,
each dated by the daemon's own ``ago_s``, and the commander's readiness table; it kills and
restarts daemons at the scenario's reboot events. The barrier releases each drone's stack
at its own offset after the release, U(0, ``--stagger-s``) (``flight.start_offsets``,
docs/testbed.md, "Staggered start"; 0: all at once); the offsets go into the run file's
``setup``. Written: ``OUT/runs/flight-<scenario>-
<contender>-n<N>-r<k>.json`` (records, ground truth, measures: ``bench/wifi/flight_measures.py``)
and a timeline figure per run (``bench/wifi/flight_report.py``).

The stock contenders (``cyclonedds``, ``fastdds``, ``fastdds-server``, ``zenoh``, ``ros2``)
and ``ros2-swarmd`` (the same rclpy node, its discovery served by swarmd's relay on each
drone, the daemons reading the flight link files; a reboot restarts both) run their
workload peers with ``--events 1``: each reports, by its own clock, what its
stack's discovery API says of every other drone (``bench/wifi/peers/common.py``), and the
harness reads those lines from the peers' logs after the run into the same ``changes`` and
``readiness`` records (``bench/wifi/flight_events.py``). Their ``lease_s`` is the stack's
default loss timer (``LOSS_TIMER_S``), since "time to report a loss" is mostly that timer.
They boot with a discovery flood: run them dilated (``--dilation 5:2,10:3``, the testbed's
k=3 at N=10) so that the run stays valid by the lag rule.
"""

from __future__ import annotations

import argparse
import contextlib
import itertools
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any, Final

from bench.wifi import contenders as contenders_mod
from bench.wifi import (
    flight,
    flight_commands,
    flight_events,
    flight_measures,
    flight_report,
    metrics,
)
from bench.wifi.barrier import RUN_NICE, Process, StartBarrier, set_priority
from bench.wifi.dilation import Dilation, scale_kernel_timers
from bench.wifi.ns3_loader import unavailable_reason
from bench.wifi.run import (
    BARRIER_TIMEOUT_S,
    SETTLE_S,
    Interrupted,
    _on_sigterm,
    _wait_ready,
    hub_channel,
    parse_dilation,
    realtime_channel,
    source_commit,
)
from bench.wifi.topology import BASE, Testbed
from swarmd.control import DaemonUnreachable, RequestError, request

REPO: Final = Path(__file__).resolve().parents[2]
DEFAULT_OUT: Final = REPO / "bench" / "results" / "flight"
LEASE_S: Final = 20.0  # the testbed bundle's lease (bench/wifi/bundle.py)
# the stock contenders with a flight observer, and each stack's default loss timer: the
# participant lease after which a silent remote is dropped (docs/benchmarks.md, "Flight")
STOCK: Final = ("cyclonedds", "fastdds", "fastdds-server", "zenoh", "ros2")
LOSS_TIMER_S: Final[dict[str, float]] = {
    **{name: LEASE_S for name in contenders_mod.SWARMD_VARIANTS},
    "cyclonedds": 10.0,  # Cyclone DDS Discovery/LeaseDuration default "10 s"
    "fastdds": 20.0,  # Fast DDS 2.9 discovery_config leaseDuration default 20 s
    "fastdds-server": 20.0,  # the same lease, checked by the server and its clients
    "zenoh": 10.0,  # zenoh transport lease default 10 000 ms (keep-alive every 2.5 s)
    "ros2": 20.0,  # rmw_fastrtps on Fast DDS 3.2: leaseDuration default 20 s
    # ROS 2 on swarmd: swarmd's lease decides. The relay renews every drone swarmd has to its
    # nodes on [::1] every relay lease / 4 (Ros2Relay._renew_all: loopback, never lost), so
    # the node's own lease of the synthesized participant never runs out while swarmd has
    # the drone; swarmd's peer_lost (its lease, the bundle's 20 s) makes the relay send
    # DATA(p[UD]) at once (Ros2Relay.peer_lost) and rmw drops the node from the graph
    "ros2-swarmd": LEASE_S,
}
PEER_TAIL_S: Final = 5.0  # a stock peer's window past the scenario's end (run_flight)
# ROS 2 on swarmd (issue 20): the drones run swarmd with the relay and the rclpy node, and
# the node's graph is the observer, as for stock ros2 (bench/wifi/ros2_contenders.py)
ROS2_ON_SWARMD: Final = ("ros2-swarmd",)
# the contenders observed through their workload peers' event lines (PeerLogObserver)
PEER_OBSERVED: Final = (*STOCK, *ROS2_ON_SWARMD)
FLIGHT_CONTENDERS: Final = (*contenders_mod.SWARMD_VARIANTS, *PEER_OBSERVED)
POLL_S: Final = 0.25  # real seconds between harness steps
STATUS_PER_STEP: Final = 2  # daemons polled per step: every daemon every N/2 steps
_runs = itertools.count(1)


@contextlib.contextmanager
def flight_channel(
    tb: Testbed, out: Path, stop: Path, waypoints: Path, flight_dir: Path, go: Path,
    log: Path, env: Mapping[str, str],
) -> Iterator[subprocess.Popen[bytes]]:  # fmt: skip
    """ns-3 with the flight additions, in the hub namespace (as run.channel_process)."""
    args = ["--waypoints", str(waypoints), "--flight-dir", str(flight_dir), "--go-file", str(go)]
    with hub_channel(tb, "bench.wifi.flight_channel", out, stop, args, log, env) as proc:
        yield proc


class SwarmdObserver:
    """Reads the daemons during a flight: peer changes (by daemon life) and readiness."""

    def __init__(
        self, socks: Sequence[Path], names: Sequence[str], *, readiness: bool = True
    ) -> None:
        self.socks = list(socks)
        self.ask_readiness = readiness  # False: swarmd under ROS 2 (the node counts it)
        self.index = {name: i for i, name in enumerate(names)}
        self.changes: dict[int, list[tuple[float, int, str]]] = {i: [] for i in range(len(socks))}
        self.readiness: list[tuple[float, dict[int, int]]] = []
        # per status poll: (t, node, renewals sent, link Q, renewal period, advertised lease,
        # renewals sent / vouches sent / vouches received per s: status "rates")
        self.renewals: list[tuple[Any, ...]] = []
        self._seen: dict[int, tuple[int, int]] = {}  # daemon -> (pid, last seq)
        self._next = itertools.cycle(range(len(socks)))
        self.polls = self.failures = 0

    def _ask(self, i: int, cmd: str) -> Any:
        try:
            return request(str(self.socks[i]), cmd)
        except (DaemonUnreachable, RequestError, OSError, ValueError):
            self.failures += 1
            return None

    def poll(self, now: float) -> None:
        """One harness step: a few daemons' status and the commander's readiness."""
        for _ in range(STATUS_PER_STEP):
            i = next(self._next)
            st = self._ask(i, "status")
            if isinstance(st, dict):
                self.polls += 1
                self._take(i, st, now)
        if not self.ask_readiness:
            return
        table = self._ask(0, "readiness")
        if isinstance(table, dict):
            counts = {
                self.index[k]: int(v["count"])
                for k, v in table.items()
                if k in self.index and isinstance(v, dict) and isinstance(v.get("count"), int)
            }
            self.readiness.append((now, counts))

    def summary(self) -> dict[str, Any]:
        return {"status_polls": self.polls, "failed_requests": self.failures}

    def _take(self, i: int, st: Mapping[str, Any], now: float) -> None:
        pc = st.get("peer_changes")
        pid = (st.get("daemon") or {}).get("pid")
        if not isinstance(pc, dict) or not isinstance(pid, int):
            return
        life, last = self._seen.get(i, (pid, 0))
        if life != pid:  # a new daemon life numbers its changes from 1 again
            last = 0
        for c in pc.get("changes") or []:
            if not isinstance(c, dict) or not isinstance(c.get("seq"), int) or c["seq"] <= last:
                continue
            peer = self.index.get(str(c.get("peer")))
            ago = c.get("ago_s")
            if peer is None or not isinstance(ago, int | float):
                continue
            self.changes[i].append((now - float(ago), peer, str(c.get("change"))))
        self._seen[i] = (pid, max(last, int(pc.get("last_seq") or 0)))
        kinds = (st.get("counters") or {}).get("tx_kind")
        timing, link = st.get("timing") or {}, st.get("link") or {}
        rates = st.get("rates") or {}
        if isinstance(kinds, dict):
            self.renewals.append(
                (
                    now,
                    i,
                    kinds.get("renewal"),
                    link.get("q"),
                    timing.get("renewal_period_s"),
                    timing.get("advertised_lease_s"),
                    rates.get("renewals_sent_per_s"),
                    rates.get("vouches_sent_per_s"),
                    rates.get("vouches_received_per_s"),
                )
            )


class PeerLogObserver:
    """The stock peers' own reports (``bench/wifi/flight_events.py``), read from their logs
    once the run is over: each line is dated by the peer, so nothing is lost by reading late."""

    def __init__(self, n: int) -> None:
        self.events = flight_events.PeerEvents(n)
        self.renewals: list[tuple[float, int, Any, Any, Any, Any]] = []  # swarmd's only

    @property
    def changes(self) -> dict[int, list[tuple[float, int, str]]]:
        return self.events.changes

    @property
    def readiness(self) -> list[tuple[float, dict[int, int]]]:
        return self.events.readiness

    def poll(self, now: float) -> None:
        """Nothing to ask during the run."""

    def collect(self, work: Path) -> None:
        for i in range(self.events.n):
            log = work / f"peer-{i}.log"
            if log.exists():
                self.events.feed(i, log.read_text(errors="replace").splitlines())

    def summary(self) -> dict[str, Any]:
        return {"source": "peer event lines", **self.events.summary()}


Observer = SwarmdObserver | PeerLogObserver


def swarmd_under(c: contenders_mod.Contender, n: int) -> SwarmdObserver:
    """Status polls of the swarmd daemons a ROS 2 on swarmd contender runs beside its nodes
    (their control sockets: ``ros2_contenders.swarmd_socket``); no readiness asked."""
    from bench.wifi.ros2_contenders import Ros2Contender, swarmd_socket

    assert isinstance(c, Ros2Contender)
    socks = [swarmd_socket(c, i) for i in range(n)]
    return SwarmdObserver(socks, [f"uav{i + 1}" for i in range(n)], readiness=False)


def _restart(c: contenders_mod.Contender, node: int, state: str, env: Mapping[str, str]) -> None:
    """Start node's daemon again (no barrier), its state dir deleted for ``lost``."""
    if state == "lost":
        shutil.rmtree(c.work / f"state-uav{node + 1}", ignore_errors=True)
    cfg = c.work / f"uav{node + 1}.yaml"
    log = (c.work / f"uav{node + 1}.log").open("ab")
    c._logs.append(log)
    c.procs[node] = c.drones[node].popen(
        [sys.executable, "-m", "swarmd_lab.start_barrier", "run", "--config", str(cfg)],
        env={k: v for k, v in env.items() if k != "SWARMD_START_BARRIER"},
        stdout=log,
        stderr=subprocess.STDOUT,
    )


def release(
    barrier: StartBarrier, procs: Sequence[Process], offsets_s: Sequence[float], k: float
) -> None:
    """Let the stacks go: all at once when every offset is 0 (the lockstep start), else
    each at its offset on the experiment clock, which runs ``k`` times slower than the
    harness's real one (bench/wifi/dilation.py)."""
    if any(offsets_s):
        barrier.release_staggered(procs, [o * k for o in offsets_s])
    else:
        barrier.release()


def run_flight(
    contender: str,
    scenario: flight.Scenario,
    run: int,
    *,
    dilation: float,
    max_lag_ms: float,
    rt_priority: int,
    keep: Path | None,
    commands: bool = True,
    stagger_s: float = flight.STAGGER_S,
    beside: int = 0,
) -> dict[str, Any]:
    """One flight run; the run file's dict (``commands``: the scenario's operator commands,
    with a vehicle simulator per drone, swarmd variants only: ``bench/wifi/flight_commands.py``;
    ``stagger_s``: each drone's stack starts U(0, ``stagger_s``) after the release;
    ``beside``: other runs in flight at its start, ``--beside``)."""
    if contender not in FLIGHT_CONTENDERS:
        raise ValueError(f"{contender}: no flight observer for this stack; use one of "
                         f"{', '.join(FLIGHT_CONTENDERS)}")  # fmt: skip
    n = scenario.n
    offsets = flight.start_offsets(n, scenario.seed, stagger_s)
    prefix = f"{BASE}-{os.getpid()}-f{next(_runs)}"
    dil = Dilation.start(dilation)
    with tempfile.TemporaryDirectory(prefix="swbf-") as tmp, Testbed(prefix, n) as tb:
        work = Path(tmp)
        subnet = tb.drones[0].address.rsplit(".", 1)[0] + ".0/24"
        scale_kernel_timers(tb.drones, dil.k, subnet)
        chan, fdir = work / "channel", work / "flight"
        chan.mkdir()
        stop, go, log = work / "stop", work / "go", work / "channel.log"
        waypoints = work / "waypoints.txt"
        waypoints.write_text(scenario.waypoint_lines())
        with flight_channel(tb, chan, stop, waypoints, fdir, go, log, dil.env()) as proc:
            ready = _wait_ready(proc, chan / "ready.json", log)
            tb.check_macs(ready["macs"])
            sched = realtime_channel(proc.pid, rt_priority)
            settled = time.monotonic() + dil.real_s(SETTLE_S)
            # a stock peer ends its window with a goodbye, which its peers would report as
            # losses: it outlives the scenario by PEER_TAIL_S (changes after it are cut)
            tail = PEER_TAIL_S if contender in PEER_OBSERVED else 0.0
            c = contenders_mod.make(
                contender, tb.drones, work, window_s=scenario.duration_s + tail, messages=20,
                link_dir=fdir, env=dil.env(),
            )  # fmt: skip
            obs: Observer
            if isinstance(c, contenders_mod.SwarmdContender):
                obs = SwarmdObserver(c.socks, [f"uav{i + 1}" for i in range(n)])
            else:
                assert isinstance(c, contenders_mod.PeerContender)
                c.flight_events = True
                obs = PeerLogObserver(n)
            # ROS 2 on swarmd: swarmd's own peer changes too, under the node's graph, so
            # that a slow re-discovery splits into swarmd's and the relay's share
            # (``python -m bench.flight_slow_pair --parts``; docs/benchmarks.md)
            under = swarmd_under(c, n) if contender in ROS2_ON_SWARMD else None
            env = contenders_mod._clean_env(dil.env())
            cmds = flight_commands.prepare(c, scenario, work, env, dil.real_s) if commands else None
            down: dict[int, list[list[float]]] = {}
            restarts: list[tuple[float, int]] = []
            # open for the whole run: a staggered release sends its last byte up to
            # stagger_s after the release (close() lets whoever still waits go at once)
            barrier = StartBarrier(work / "barrier.sock")
            try:
                c.start(barrier.path)
                barrier.wait_all(c.procs, BARRIER_TIMEOUT_S)
                time.sleep(max(0.0, settled - time.monotonic()))
                for p in c.procs:
                    set_priority(p.pid, RUN_NICE)
                go.touch()
                launch = dil.exp(time.time())
                released_mono = time.monotonic()
                release(barrier, c.procs, offsets, dil.k)
                pending = sorted(scenario.events, key=lambda e: e.t)
                end = launch + scenario.duration_s
                while (now := dil.exp(time.time())) < end:
                    while pending and now - launch >= pending[0].t:
                        ev = pending.pop(0)
                        if ev.action == "kill":
                            if isinstance(c, contenders_mod.PeerContender):
                                c.kill(ev.node)  # ros2-swarmd: the node and its swarmd
                            else:
                                c.procs[ev.node].send_signal(signal.SIGKILL)
                                c.procs[ev.node].wait(timeout=10)
                            down.setdefault(ev.node, []).append([now - launch, scenario.duration_s])
                        elif isinstance(c, contenders_mod.PeerContender):
                            c.restart(ev.node, end - now + PEER_TAIL_S, ev.state)
                            down[ev.node][-1][1] = now - launch
                            restarts.append((now - launch, ev.node))
                        else:
                            _restart(c, ev.node, ev.state, env)
                            down[ev.node][-1][1] = now - launch
                            restarts.append((now - launch, ev.node))
                    if cmds is not None:
                        cmds.tick(now - launch)
                    obs.poll(now)
                    if under is not None:
                        under.poll(now)
                    print(
                        f"\rflight {scenario.name} {contender} n={n}: {now - launch:5.1f}/"
                        f"{scenario.duration_s:.0f} s",
                        end="",
                        file=sys.stderr,
                        flush=True,
                    )
                    if proc.poll() is not None:
                        raise RuntimeError(f"ns-3 channel died: {log.read_text()[-800:]}")
                    time.sleep(POLL_S)
                print(file=sys.stderr)
                if cmds is not None:
                    cmds.finish(time.monotonic)
                c.window_end()
                stop.touch()
                proc.wait(timeout=60)
            finally:
                barrier.close()
                for drone in tb.drones:
                    drone.stop_children()
                c.close()
        # each stack's start as released, on the experiment clock from the release
        started = [
            round((barrier.released_at[i] - released_mono) / dil.k, 3)
            if i in barrier.released_at
            else 0.0
            for i in range(n)
        ]
        if isinstance(obs, PeerLogObserver):
            obs.collect(work)
        stats = json.loads((chan / "stats.json").read_text())
        go_info = json.loads((fdir / "go.json").read_text())
        go_wall = float(go_info.get("go_wall", launch))
        issued = None if cmds is None else (cmds.records(go_wall), cmds.vehicles(go_wall))
        heard = [json.loads(x) for x in (fdir / "heard.jsonl").read_text().splitlines() if x]
        if keep is not None:
            keep.mkdir(parents=True, exist_ok=True)
            for f in (*work.glob("*.log"), log):
                dest = keep / f"flight-{scenario.name}-{contender}-n{n}-r{run}-{f.name}"
                dest.write_bytes(f.read_bytes())
    record = assemble(
        contender, scenario, run, stats, go_info, launch, obs, down, restarts, heard,
        max_lag_ms=max_lag_ms, scheduling=sched, dilation=dil.k, tx_counters=c.obs.tx_counters,
        stagger=(stagger_s, offsets, started), concurrent_runs=beside, under=under,
    )  # fmt: skip
    if issued is not None:
        flight_commands.attach(record, issued[0], scenario, issued[1])
    return record


def assemble(
    contender: str,
    scenario: flight.Scenario,
    run: int,
    stats: Mapping[str, Any],
    go_info: Mapping[str, float],
    launch: float,
    obs: Observer,
    down: Mapping[int, Sequence[Sequence[float]]],
    restarts: Sequence[tuple[float, int]],
    heard: Sequence[Mapping[str, Any]],
    *,
    max_lag_ms: float,
    scheduling: str,
    dilation: float,
    tx_counters: Mapping[str, int],
    stagger: tuple[float, Sequence[float], Sequence[float]] = (0.0, (), ()),
    concurrent_runs: int = 0,
    under: SwarmdObserver | None = None,
) -> dict[str, Any]:
    """The run file's dict. ``stagger``: ``--stagger-s``, each drone's planned start after
    the release and its start as released (experiment seconds; empty: all at the release).
    ``under``: swarmd's own observer under a ROS 2 stack (ROS 2 on swarmd), recorded as
    ``swarmd_changes`` beside the stack's ``changes``. ``concurrent_runs``: other testbed
    runs in flight beside this one (``--beside``; the campaign raises it if one starts
    later; older files lack it: 0, ``flight_cells.beside``).
    Every measure starts at a scenario phase or command cue after ``flight.MAX_STAGGER_S``,
    so none counts a stack that had not started yet as lost or late."""
    stagger_s, offsets, started = stagger
    window = int(scenario.duration_s)
    # the channel's records by simulation second from go; the stacks' by the clock at go
    go_sim = float(go_info["go_sim_s"])
    m = metrics.run_measures(
        stats, launch_wall=float(stats["wall_at_sim0"]) + go_sim, window_s=window, family="rtps"
    )
    classes = metrics.DISCOVERY_CLASSES[contenders_mod.family(contender)]
    disc = metrics.frame_series(stats, int(go_sim), window, classes)
    lease_s = LOSS_TIMER_S[contender]
    go_exp = float(go_info.get("go_wall", launch))
    changes = _since_go(obs.changes, go_exp, window)
    readiness = [(round(t - go_exp, 3), table) for t, table in obs.readiness]
    extra: dict[str, Any] = {}
    if under is not None:
        dated = _since_go(under.changes, go_exp, window)
        extra["swarmd_changes"] = {str(i): v for i, v in dated.items()}
        extra["swarmd_observer"] = under.summary()
    renewals = [[round(t - go_exp, 3), *rest] for t, *rest in obs.renewals]
    truth = scenario.truth()
    first_move = min((t for t, _, _ in scenario.waypoints if t > 0), default=None)
    if first_move is None and scenario.events:
        first_move = min(e.t for e in scenario.events)
    down_t = {i: [(a, b) for a, b in spans] for i, spans in down.items()}
    measures = flight_measures.measure(
        truth, changes, down_t, n=scenario.n, lease_s=lease_s, restarts=restarts,
        readiness=readiness, discovery_fps=disc, first_move_s=first_move,
        started=[float(o) for o in started],
    )  # fmt: skip
    measures["renewal_follows_q"] = flight_measures.renewal_follows_q(renewals, first_move or 0.0)
    return {
        "kind": "flight",
        "scenario": scenario.name,
        "description": scenario.description,
        "contender": contender,
        "n": scenario.n,
        "run": run,
        "seed": scenario.seed,
        "duration_s": scenario.duration_s,
        **metrics.lag_validity(m, max_lag_ms),
        "rt_lag_p50_ms": m["rt_lag_p50_ms"],
        "rt_lag_p99_ms": m["rt_lag_p99_ms"],
        "rt_lag_max_ms": m["rt_lag_max_ms"],
        "measures": measures,
        "lease_s": lease_s,
        "phases": [list(p) for p in scenario.phases],
        "waypoints": [[t, i, *p] for t, i, p in scenario.waypoints],
        "events": [[e.t, e.node, e.action, e.state] for e in scenario.events],
        "down": {str(i): v for i, v in down_t.items()},
        "restarts": [list(r) for r in restarts],
        "changes": {str(i): v for i, v in changes.items()},
        "readiness": [[t, {str(k): v for k, v in table.items()}] for t, table in readiness],
        "heard": flight_report.compact_heard([h for h in heard if h.get("t", -1) >= 0]),
        "renewals": renewals,
        "discovery_fps": disc,
        "pps": m["pps"],
        "tx_counters": dict(tx_counters),
        "observer": obs.summary(),
        **extra,
        "go": {"sim_s": go_sim, "wall": go_exp, "harness_launch": launch},
        "load_avg_at_start": list(os.getloadavg()),
        "concurrent_runs": concurrent_runs,
        "setup": {
            "standard": "802.11g",
            "ns3_scheduling": scheduling,
            "dilation": dilation,
            "max_lag_ms": max_lag_ms,
            "range_m": round(flight.range_m(), 1),
            **stagger_setup(stagger_s, offsets, started, scenario.n),
            "commit": source_commit(),
        },
    }


def _since_go(
    changes: Mapping[int, Sequence[tuple[float, int, str]]], go_exp: float, window: int
) -> dict[int, list[tuple[float, int, str]]]:
    """Observed changes dated from go (the stacks' clock at go), up to the window's end."""
    return {
        i: [(round(t - go_exp, 3), p, c) for t, p, c in sorted(v) if t - go_exp <= window]
        for i, v in changes.items()
    }


def stagger_setup(
    stagger_s: float, offsets: Sequence[float], started: Sequence[float], n: int
) -> dict[str, Any]:
    """The run file's ``setup`` fields of the start: ``stagger_s`` (``--stagger-s``),
    ``start_offsets_s`` (each drone's planned start after the release) and ``started_s``
    (when the barrier let it go), experiment seconds; none given: all at the release."""
    return {
        "stagger_s": stagger_s,
        "start_offsets_s": [float(o) for o in offsets] or [0.0] * n,
        "started_s": [float(o) for o in started] or [0.0] * n,
    }


def run_file_name(scenario: str, contender: str, n: int, run: int, k: float) -> str:
    dilated = f"-k{k:g}" if k > 1.0 else ""
    return f"flight-{scenario}-{contender}-n{n}{dilated}-r{run}.json"


def one_line(r: Mapping[str, Any]) -> str:
    m = r["measures"]
    return (
        f"{r['scenario']:8} {r['contender']:14} n={r['n']:<3} r{r['run']} "
        f"{'valid' if r['valid'] else 'INVALID (' + str(r['invalid_reason']) + ')'}: "
        f"loss p50 {m['loss_latency_s']['p50']} s (missed {m['missed_losses']}), "
        f"false {m['false_losses']}, dropout {m['lost_reports']['dropout']}, "
        f"rediscovery p50 {m['rediscovery_s']['p50']} max {m['rediscovery_s']['max']} s, "
        f"frames/pair {m['frames_per_rejoining_pair'].get('per_pair')}, "
        f"readiness {m['readiness_delivery']['ratio']}"
    )


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    p.add_argument("--scenarios", default="split", help=f"of {', '.join(flight.SCENARIOS)}")
    p.add_argument("--n", default="10")
    p.add_argument("--repeat", type=int, default=1)
    p.add_argument("--first-run", type=int, default=1)
    p.add_argument("--contenders", default="swarmd")
    p.add_argument("--seed", type=int, default=1)
    p.add_argument(
        "--dilation",
        default="1",
        help="time dilation factor: one K for every N, or per N (5:2,10:3); unlisted N: 1",
    )
    p.add_argument("--max-lag-ms", type=float, default=20.0)
    p.add_argument(
        "--stagger-s", type=float, default=flight.STAGGER_S,
        help="each drone's stack starts U(0, S) s after the release (0: all at once, the "
        f"lockstep start; at most {flight.MAX_STAGGER_S:g})",
    )  # fmt: skip
    p.add_argument("--ns3-rt-priority", type=int, default=10)
    p.add_argument("--out", type=Path, default=DEFAULT_OUT)
    p.add_argument("--keep-logs", action="store_true")
    p.add_argument(
        "--beside", type=int, default=0, metavar="B",
        help="other testbed runs in flight at this one's start (flight_campaign --parallel), "
        "kept in the run file as concurrent_runs",
    )  # fmt: skip
    p.add_argument(
        "--no-commands", action="store_true",
        help="no vehicles, no operator commands (discovery measures only, as before)",
    )  # fmt: skip
    args = p.parse_args(argv)
    scenarios = [s.strip() for s in args.scenarios.split(",") if s.strip()]
    sizes = [int(x) for x in args.n.split(",") if x.strip()]
    names = [c.strip() for c in args.contenders.split(",") if c.strip()]
    for s in scenarios:
        if s not in flight.SCENARIOS:
            p.error(f"--scenarios: unknown {s!r}; use {', '.join(flight.SCENARIOS)}")
    for c in names:
        if c not in FLIGHT_CONTENDERS:
            usable = ", ".join(FLIGHT_CONTENDERS)
            p.error(f"--contenders: {c!r} has no flight observer; use {usable}")
        reason = contenders_mod.unavailable(c)
        if reason is not None:
            p.error(f"--contenders: {reason}")
    try:
        dil_spec = parse_dilation(args.dilation)
    except ValueError:
        p.error(f"--dilation: {args.dilation!r} is neither K nor N:K,N:K")
    per_n = dict(dil_spec) if isinstance(dil_spec, tuple) else dict.fromkeys(sizes, dil_spec)
    if any(not k >= 1.0 for k in per_n.values()):
        p.error("--dilation: factors must be >= 1")
    if not 0.0 <= args.stagger_s <= flight.MAX_STAGGER_S:
        p.error(f"--stagger-s: {args.stagger_s} not in [0, {flight.MAX_STAGGER_S:g}]")
    reason = unavailable_reason()
    if reason is not None:
        print(f"flight bench: {reason}", file=sys.stderr)
        return 2
    runs_dir = args.out / "runs"
    runs_dir.mkdir(parents=True, exist_ok=True)
    signal.signal(signal.SIGTERM, _on_sigterm)
    failures = 0
    try:
        for s, n, k, c in itertools.product(
            scenarios, sizes, range(args.first_run, args.first_run + args.repeat), names
        ):
            scenario = flight.make(s, n, args.seed + k - 1)
            try:
                result = run_flight(
                    c, scenario, k, dilation=per_n.get(n, 1.0), max_lag_ms=args.max_lag_ms,
                    rt_priority=args.ns3_rt_priority,
                    keep=args.out / "logs" if args.keep_logs else None,
                    commands=not args.no_commands, stagger_s=args.stagger_s,
                    beside=args.beside,
                )  # fmt: skip
            except (RuntimeError, OSError, ValueError, subprocess.SubprocessError) as exc:
                print(f"\nflight bench: {s} {c} n={n} run {k} failed: {exc}", file=sys.stderr)
                failures += 1
                continue
            path = runs_dir / run_file_name(s, c, n, k, per_n.get(n, 1.0))
            path.write_text(json.dumps(result) + "\n")
            flight_report.timeline(result, path.with_suffix(".png"))
            print(one_line(result), flight_commands.one_line(result["measures"]))
    except (KeyboardInterrupt, Interrupted):
        print("flight bench: interrupted; testbed removed", file=sys.stderr)
        return 130
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
