"""The emulated 802.11 benchmark: real stacks, one namespace per drone, one ns-3 channel.

    sudo .venv/bin/python bench/wifi/run.py --n 5,10,20 --repeat 5 \\
        --contenders swarmd,cyclonedds,zenoh

For every N, repeat and contender (in that order, so the contenders of one repeat run
back to back under the same machine load) one *run*: a fresh testbed (namespaces,
bridges, taps), a fresh ns-3 channel process, the contender's stack on every drone, a
``--window-s`` measurement window, then everything is torn down. The stacks start behind a
barrier (bench/wifi/barrier.py): all N processes are launched at low priority, finish
their imports and wait; then they are released at one instant, from which the window and
every "discovered" time count. Each run
writes ``<out>/runs/<contender>-n<N>-r<k>.json``; at the end ``report`` writes the
summary, the plots and the markdown table (docs/testbed.md explains every field).

A run whose real-time lag p99 exceeds ``--max-lag-ms`` is kept but marked
``"valid": false``; the report leaves it out of every figure.
"""

from __future__ import annotations

import argparse
import contextlib
import itertools
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import FrameType
from typing import Any, Final, TextIO

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from bench.wifi import contenders as contenders_mod  # noqa: E402
from bench.wifi import metrics, report  # noqa: E402
from bench.wifi.barrier import RUN_NICE, StartBarrier, set_priority  # noqa: E402
from bench.wifi.dilation import Dilation, scale_kernel_timers  # noqa: E402
from bench.wifi.ns3_loader import unavailable_reason  # noqa: E402
from bench.wifi.topology import BASE, Testbed  # noqa: E402

REPO: Final = Path(__file__).resolve().parents[2]
DEFAULT_OUT: Final = REPO / "bench" / "results" / "wifi"
READY_TIMEOUT_S: Final = 180.0
SETTLE_S: Final = 2.0  # experiment seconds between ns-3 under SCHED_RR and the release
BARRIER_TIMEOUT_S: Final = 240.0  # 20+ Python processes importing at nice 10 on 2 cores
_runs = itertools.count(1)


@dataclass(frozen=True)
class Options:
    window_s: int = 60
    messages: int = 20
    spacing_m: float = 1.0
    layout: str = "line"
    standard: str = "g"
    mcast_mode: str = ""
    max_lag_ms: float = 20.0
    ns3_rt_priority: int = 10
    # time dilation factor per swarm size (bench/wifi/dilation.py); sizes not listed: 1
    dilation: tuple[tuple[int, float], ...] = ()

    def dilation_for(self, n: int) -> float:
        return dict(self.dilation).get(n, 1.0)


def parse_dilation(text: str) -> tuple[tuple[int, float], ...] | float:
    """``--dilation``: one factor for every N (``"3"``) or per N (``"10:3,20:4"``)."""
    if ":" not in text:
        return float(text)
    pairs = []
    for item in _csv(text):
        n, _, k = item.partition(":")
        pairs.append((int(n), float(k)))
    return tuple(pairs)


class Interrupted(Exception):
    """SIGTERM arrived; unwinds like Ctrl-C so every ``finally`` tears down."""


def _on_sigterm(signum: int, frame: FrameType | None) -> None:
    # once: a second SIGTERM (e.g. from `timeout` and a shell at once) must not abort the
    # teardown the first one started
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    raise Interrupted()


class Progress:
    """One status line on stderr: a bar over all runs plus the current run's clock."""

    def __init__(self, total: int, out: TextIO = sys.stderr) -> None:
        self.total = total
        self.done = 0
        self.out = out
        self.tty = out.isatty()
        self._last_plain = 0.0

    def show(self, label: str) -> None:
        width = 24
        filled = int(width * self.done / max(1, self.total))
        line = f"[{'#' * filled}{'.' * (width - filled)}] {self.done}/{self.total} {label}"
        if self.tty:
            self.out.write("\r\x1b[2K" + line)
        elif time.monotonic() - self._last_plain >= 10.0:  # a log file: a line per 10 s
            self._last_plain = time.monotonic()
            self.out.write(line + "\n")
        self.out.flush()

    def step(self) -> None:
        self.done += 1

    def close(self) -> None:
        if self.tty:
            self.out.write("\n")


@contextlib.contextmanager
def channel_process(
    tb: Testbed, out: Path, stop_file: Path, opts: Options, log: Path, env: dict[str, str]
) -> Iterator[subprocess.Popen[bytes]]:
    """The ns-3 process inside the hub namespace; killed by PID on any exit."""
    args = [
        "--spacing", str(opts.spacing_m), "--layout", opts.layout,
        "--standard", opts.standard, "--mcast-mode", opts.mcast_mode,
    ]  # fmt: skip
    with hub_channel(tb, "bench.wifi.channel", out, stop_file, args, log, env) as proc:
        yield proc


@contextlib.contextmanager
def hub_channel(
    tb: Testbed, module: str, out: Path, stop_file: Path, args: Sequence[str], log: Path,
    env: Mapping[str, str],
) -> Iterator[subprocess.Popen[bytes]]:  # fmt: skip
    """ns-3 channel ``module`` in the hub namespace with the testbed's common arguments and
    ``args``; on any exit it is asked to stop (``stop_file``), then killed by PID."""
    # nice -10: on a shared host the stacks may be slowed (like a slow drone CPU), the
    # channel must not be (lag distorts the physics); still far from starving anyone
    argv = [
        "ip", "netns", "exec", tb.hub, "nice", "-n", "-10", sys.executable, "-m", module,
        "--n", str(tb.size), "--out", str(out), "--taps", tb.tap_prefix,
        "--stop-file", str(stop_file), *args,
    ]  # fmt: skip
    with log.open("wb") as f:
        proc = subprocess.Popen(
            argv, cwd=REPO, stdout=f, stderr=subprocess.STDOUT, env={**os.environ, **env}
        )
        try:
            yield proc
        finally:
            if proc.poll() is None:
                stop_file.touch()
                try:
                    proc.wait(timeout=10)
                except subprocess.TimeoutExpired:
                    proc.kill()
                    proc.wait(timeout=10)


def _wait_ready(proc: subprocess.Popen[bytes], ready: Path, log: Path) -> dict[str, Any]:
    t0 = time.monotonic()
    while not ready.exists():
        if proc.poll() is not None:
            tail = log.read_text(errors="replace")[-800:]
            raise RuntimeError(f"ns-3 channel exited with {proc.returncode}: {tail}")
        if time.monotonic() - t0 > READY_TIMEOUT_S:
            raise RuntimeError(f"ns-3 channel not ready after {READY_TIMEOUT_S:.0f} s")
        time.sleep(0.2)
    data: dict[str, Any] = json.loads(ready.read_text())
    return data


def realtime_channel(pid: int, priority: int) -> str:
    """Put every ns-3 thread under SCHED_RR ``priority``; the scheduling actually used.

    nice -10 alone did not keep ns-3 in real time at N=10 while N stacks burst at the start
    release (lag 170-255 ms in the first seconds): a woken CFS task still waits behind the
    running ones. SCHED_RR runs it the moment its timer or a tap read wakes it. Set only
    after ``ready.json``, so the 10-25 s of ``from ns import ns`` stay ordinary; the
    kernel's RT throttling (95 % of each second) still bounds it.
    """
    if priority <= 0:
        return "nice -10"
    proc = subprocess.run(
        ["chrt", "--all-tasks", "--rr", "--pid", str(priority), str(pid)],
        capture_output=True,
        text=True,
        check=False,
    )
    if proc.returncode != 0:
        print(f"\nwifi bench: chrt failed ({proc.stderr.strip()}); ns-3 stays at nice -10")
        return "nice -10"
    return f"SCHED_RR {priority}"


def run_one(
    contender: str, n: int, run: int, opts: Options, progress: Progress, keep: Path | None
) -> dict[str, Any]:
    """One run; the result dict (also the per-run JSON)."""
    prefix = f"{BASE}-{os.getpid()}-{next(_runs)}"
    label = f"{contender} n={n} run {run}"
    # one experiment clock for every process of the run; the harness maps its own readings
    dil = Dilation.start(opts.dilation_for(n))
    if dil.active:
        label += f" (dilated {dil.describe()})"
    with tempfile.TemporaryDirectory(prefix="swbw-") as tmp, Testbed(prefix, n) as tb:
        work = Path(tmp)
        subnet = tb.drones[0].address.rsplit(".", 1)[0] + ".0/24"
        scale_kernel_timers(tb.drones, dil.k, subnet)
        chan = work / "channel"
        chan.mkdir()
        stop = work / "stop"
        log = work / "channel.log"
        progress.show(f"{label}: starting ns-3")
        with channel_process(tb, chan, stop, opts, log, dil.env()) as proc:
            ready = _wait_ready(proc, chan / "ready.json", log)
            tb.check_macs(ready["macs"])
            sched = realtime_channel(proc.pid, opts.ns3_rt_priority)
            # the window's first second must not hold ns-3's own start (before SCHED_RR):
            # a C++ contender reaches the barrier at once, and its window began in the
            # second ns-3 became ready, lagging 250-480 ms at N=3 on a loaded host
            settled = time.monotonic() + dil.real_s(SETTLE_S)
            c = contenders_mod.make(
                contender,
                tb.drones,
                work,
                window_s=opts.window_s,
                messages=opts.messages,
                link_dir=chan,
                env=dil.env(),
            )
            try:
                with StartBarrier(work / "barrier.sock") as barrier:
                    c.start(barrier.path)
                    progress.show(f"{label}: {n} stacks starting up (before the barrier)")
                    prepare_s = barrier.wait_all(c.procs, BARRIER_TIMEOUT_S)
                    time.sleep(max(0.0, settled - time.monotonic()))
                    for p in c.procs:
                        set_priority(p.pid, RUN_NICE)
                    launch_real = time.time()
                    barrier.release()
                # every time the contenders and ns-3 record is experiment time: so is launch
                launch = dil.exp(launch_real)
                end_real = launch_real + dil.real_s(opts.window_s)
                while (now_real := time.time()) < end_real:
                    now = dil.exp(now_real)
                    c.poll(now)
                    progress.show(f"{label}: {now - launch:4.0f}/{opts.window_s} s")
                    if proc.poll() is not None:
                        raise RuntimeError(f"ns-3 channel died: {log.read_text()[-800:]}")
                    time.sleep(0.25)
                c.window_end()
                stop.touch()  # counters cover the window, not the teardown
                proc.wait(timeout=60)
                obs = c.finish()
            finally:
                for drone in tb.drones:
                    drone.stop_children()
                c.close()
        stats = json.loads((chan / "stats.json").read_text())
        if keep is not None:
            keep.mkdir(parents=True, exist_ok=True)
            for f in (*work.glob("*.log"), log):
                (keep / f"{contender}-n{n}-r{run}-{f.name}").write_bytes(f.read_bytes())
    result = assemble(contender, n, run, opts, stats, obs, launch)
    result["barrier_wait_s"] = round(prepare_s, 2)
    result["setup"]["ns3_scheduling"] = sched
    result["setup"]["dilation"] = dil.k
    progress.step()
    return result


def assemble(
    contender: str,
    n: int,
    run: int,
    opts: Options,
    stats: dict[str, Any],
    obs: contenders_mod.Observation,
    launch: float,
) -> dict[str, Any]:
    """The per-run JSON from the channel stats and the contender's observation."""
    m = metrics.run_measures(
        stats, launch_wall=launch, window_s=opts.window_s, family=contenders_mod.family(contender)
    )
    last_up = max(obs.started.values()) if len(obs.started) == n else None
    all_disc = obs.all_discovered
    rate: float | None
    failed: list[int]
    if obs.success_pending:
        rate, failed = None, []
    else:
        rate, failed = metrics.success(obs.received, range(1, n), launch, opts.window_s)
    return {
        "contender": contender,
        "n": n,
        "run": run,
        **metrics.lag_validity(m, opts.max_lag_ms),
        "peak_pps": m["peak_pps"],
        "peak_discovery_pps": m["peak_discovery_pps"],
        "discovery_frames_60s": m["discovery_frames_60s"],
        "frames_60s": m["frames_60s"],
        "success_rate": rate,
        "success": None if rate is None else rate == 1.0,
        "failed_members": failed,
        "all_discovered_s": None
        if all_disc is None or last_up is None
        else round(max(0.0, all_disc - last_up), 3),
        "all_discovered_from_launch_s": None if all_disc is None else round(all_disc - launch, 3),
        "stack_startup_s": None if last_up is None else round(last_up - launch, 3),
        "mac_drop_ratio": m["mac_drop_ratio"],
        "phy_drop_density": m["phy_drop_density"],
        "retx_ratio": m["retx_ratio"],
        "rt_lag_p50_ms": m["rt_lag_p50_ms"],
        "rt_lag_p99_ms": m["rt_lag_p99_ms"],
        "rt_lag_max_ms": m["rt_lag_max_ms"],
        "lag_max_ms_per_second": m["lag_max_ms_per_second"],
        "counters": m["counters"],
        "pps": m["pps"],
        "discovery_pps": m["discovery_pps"],
        "class_pps": m["class_pps"],
        "received": obs.received,
        "tx_counters": obs.tx_counters,
        "discovery_breakdown_60s": metrics.discovery_breakdown(
            stats,
            launch_wall=launch,
            window_s=opts.window_s,
            family=contenders_mod.family(contender),
        ),
        "load_avg_at_start": list(os.getloadavg()),
        "note": obs.note,
        "setup": {
            "window_s": opts.window_s,
            "messages": opts.messages,
            "spacing_m": opts.spacing_m,
            "layout": opts.layout,
            "standard": f"802.11{opts.standard}",
            "group_rate": opts.mcast_mode or "ns-3 default (802.11g: DsssRate1Mbps)",
            "max_lag_ms": opts.max_lag_ms,
            "started_at": launch,
            "commit": source_commit(),
        },
    }


def source_commit() -> str:
    """The checkout's commit (``+dirty`` when the tree differs): which swarmd and which peers
    a run measured, so runs of different code are never averaged unknowingly."""
    try:
        head = subprocess.run(
            ["git", "-C", str(REPO), "rev-parse", "--short=10", "HEAD"],
            capture_output=True,
            text=True,
            check=True,
            timeout=10,
        ).stdout.strip()
        dirty = subprocess.run(
            ["git", "-C", str(REPO), "status", "--porcelain", "--untracked-files=no"],
            capture_output=True,
            text=True,
            check=True,
            timeout=10,
        ).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    return head + ("+dirty" if dirty else "")


def run_file_name(contender: str, n: int, run: int, k: float) -> str:
    """``<contender>-n<N>-r<k>.json``; a dilated run adds ``-k<factor>`` after N."""
    dilated = f"-k{k:g}" if k > 1.0 else ""
    return f"{contender}-n{n}{dilated}-r{run}.json"


def _csv(text: str) -> list[str]:
    return [t.strip() for t in text.split(",") if t.strip()]


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    p.add_argument("--n", default="5,10", help="swarm sizes, comma separated")
    p.add_argument("--repeat", type=int, default=1)
    p.add_argument(
        "--contenders",
        default="swarmd,cyclonedds,zenoh",
        help=f"comma separated: {', '.join(contenders_mod.CONTENDERS)}",
    )
    p.add_argument("--window-s", type=int, default=60)
    p.add_argument("--messages", type=int, default=20, help="success = the n-th message")
    p.add_argument("--spacing", type=float, default=1.0, help="metres (paper: 1 m)")
    p.add_argument("--layout", choices=("line", "grid"), default="line")
    p.add_argument("--standard", choices=("g", "n"), default="g")
    p.add_argument("--mcast-mode", default="", help="ns-3 WifiMode for group frames")
    p.add_argument("--max-lag-ms", type=float, default=20.0, help="validity bound on lag p99")
    p.add_argument(
        "--ns3-rt-priority",
        type=int,
        default=10,
        help="SCHED_RR priority for ns-3 once it is ready (0: stay at nice -10)",
    )
    p.add_argument(
        "--dilation",
        default="1",
        help="time dilation factor k (every clock of a run k times slower): one value for "
        "every N, or per N as 10:3,20:4 (sizes not listed: 1)",
    )
    p.add_argument("--out", type=Path, default=DEFAULT_OUT)
    p.add_argument("--keep-logs", action="store_true", help="copy stack logs to OUT/logs")
    p.add_argument("--no-report", action="store_true")
    p.add_argument("--first-run", type=int, default=1, help="number of the first repeat")
    args = p.parse_args(argv)
    try:
        sizes = [int(x) for x in _csv(args.n)]
    except ValueError:
        p.error(f"--n: {args.n!r} is not a list of integers (e.g. 5,10,20)")
    names = _csv(args.contenders)
    for name in names:
        if name not in contenders_mod.CONTENDERS:
            p.error(f"--contenders: unknown {name!r}; use {', '.join(contenders_mod.CONTENDERS)}")
        why = contenders_mod.unavailable(name)
        if why is not None:
            p.error(f"--contenders: {why}")
    if any(not 2 <= s <= 250 for s in sizes):
        p.error("--n: each size must be 2..250")
    try:
        dil_spec = parse_dilation(args.dilation)
    except ValueError:
        p.error(f"--dilation: {args.dilation!r} is neither K nor N:K,N:K")
    dilation = tuple((s, dil_spec) for s in sizes) if isinstance(dil_spec, float) else dil_spec
    if any(not k >= 1.0 for _, k in dilation):
        p.error("--dilation: factors must be >= 1")
    reason = unavailable_reason()
    if reason is not None:
        print(f"wifi bench: {reason}", file=sys.stderr)
        return 2
    opts = Options(
        window_s=args.window_s,
        messages=args.messages,
        spacing_m=args.spacing,
        layout=args.layout,
        standard=args.standard,
        mcast_mode=args.mcast_mode,
        max_lag_ms=args.max_lag_ms,
        ns3_rt_priority=args.ns3_rt_priority,
        dilation=dilation,
    )
    runs_dir = args.out / "runs"
    runs_dir.mkdir(parents=True, exist_ok=True)
    signal.signal(signal.SIGTERM, _on_sigterm)
    progress = Progress(len(sizes) * args.repeat * len(names))
    written: list[Path] = []
    failures = 0
    try:
        for n in sizes:
            for run in range(args.first_run, args.first_run + args.repeat):
                for name in names:
                    keep = args.out / "logs" if args.keep_logs else None
                    try:
                        result = run_one(name, n, run, opts, progress, keep)
                    except (RuntimeError, OSError, ValueError, subprocess.SubprocessError) as exc:
                        # one broken run (a stack crashed, ns-3 died) must not lose the matrix
                        progress.step()
                        print(
                            f"\nwifi bench: {name} n={n} run {run} failed: {exc}", file=sys.stderr
                        )
                        failures += 1
                        continue
                    path = runs_dir / run_file_name(name, n, run, opts.dilation_for(n))
                    path.write_text(json.dumps(result, indent=1) + "\n")
                    written.append(path)
    except (KeyboardInterrupt, Interrupted):
        progress.close()
        print("wifi bench: interrupted; testbed removed", file=sys.stderr)
        return 130
    progress.close()
    if not args.no_report:
        report.write_report(args.out)
    for path in written:
        r = json.loads(path.read_text())
        print(report.one_line(r))
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
