"""How long a restarted daemon takes to start before discovery can answer (issue 20, the
reboot at N = 20: a restarted drone must be listed again within 2 s).

    .venv/bin/python bench/daemon_start.py [--tree NAME=PATH|NAME=git:REV ...]
        [--repeats R] [--n N] [--q Q] [--json]
    .venv/bin/python bench/daemon_start.py --table FILE   # a saved --json document

For each tree (a checkout; ``git:REV`` is ``git archive REV`` of this repository unpacked into
a temporary folder, so ``main`` is measured without touching another worktree) the real
daemon is started R times the way systemd and the testbed start it: ``swarmd run --config
FILE`` (the console script's two lines, ``swarmd.cli.swarmd_main.main``), in a network
namespace of its own (``swarmd_lab.netns.Lan``: two hosts on a bridge, removed on every exit
path), as a restart: its state folders kept from the run before (one uncounted warm-up run
per tree first writes the bundle floor and compiles the ``.pyc`` files). The config is the
flight's (``bench/wifi/contenders.daemon_config``: the data plane, a PX4 link
``udpin:127.0.0.1:14540`` with no vehicle behind it, adaptive discovery, the link file
source), an N-member bundle, the link file holding a fixed Q (0.415: the drone restarted in
the N = 20 reboot runs, W = 0.96 s). Trees alternate run by run, so host load falls on both.

Measured from just before ``exec`` (the bench's ``time.monotonic()``), each with the process's
CPU time (user + sys of all its threads, ``/proc/PID/task/*/schedstat``, which a loaded host
inflates far less than the wall time):

- ``engine``: the discovery engine constructed, which starts its passive clock (paper section
  4.1: T ~ U(0, W) from the first link sample). Reported by the launcher, which wraps
  ``DiscoveryEngine.__init__`` to print the time, ``time.process_time()``, and the drawn T
  and W on stderr (instrumentation of the bench, not the daemon: the same on every tree);
- ``ready``: ``READY=1`` on the bench's ``NOTIFY_SOCKET`` (systemd's start finished);
- ``first_spdp``: the daemon's first SPDP datagram on the wire, received on the other host
  of the bridge (its multicast group). The engine sends it at max(engine + T, the moment its
  timer is armed at the end of the start); ``first_spdp - T`` is the start-up without the
  passive window.

Prints a table (median and p90 per tree, ratio to the first tree); ``--json`` the document.
Needs root (namespaces). Nothing is asserted: a measurement.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import selectors
import shutil
import signal
import socket
import statistics
import struct
import subprocess
import sys
import tarfile
import tempfile
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "lab"))

from swarmd_lab.netns import Lan, Namespace, unavailable_reason  # noqa: E402

from bench.wifi.bundle import write_bundle  # noqa: E402
from bench.wifi.contenders import daemon_config  # noqa: E402
from bench.wifi.flight_commands import px4_section  # noqa: E402
from swarmd.rtps.ports import spdp_multicast_port  # noqa: E402

SPDP_GROUP: Final = "239.255.0.1"
WAIT_S: Final = 20.0  # one start; far above any start seen here
STOP_S: Final = 5.0
ENGINE_TAG: Final = "bench-engine "
# the console script's two lines, plus the engine's timestamp (see the module docstring)
LAUNCHER: Final = f"""\
import json, sys, time
sys.modules.update(dict.fromkeys({{without!r}}))  # --without: as if not installed
import swarmd.discovery.engine as _engine
_init = _engine.DiscoveryEngine.__init__
def _timed(self, *args, **kwargs):
    _init(self, *args, **kwargs)
    sys.stderr.write("{ENGINE_TAG}" + json.dumps({{{{"at": time.monotonic(),
        "cpu": time.process_time(), "passive_timer_s": self.passive_timer_s,
        "passive_window_s": self.passive_window_s}}}}) + "\\n")
    sys.stderr.flush()
_engine.DiscoveryEngine.__init__ = _timed
from swarmd.cli.swarmd_main import main
sys.exit(main())
"""
MEASURES: Final = (
    "engine_s",
    "ready_s",
    "first_spdp_s",
    "spdp_minus_passive_s",
    "cpu_engine_s",
    "cpu_ready_s",
    "cpu_first_spdp_s",
    "passive_timer_s",
)


@dataclass
class Tree:
    """A checkout the daemon is run from (``PYTHONPATH``), its own work folder."""

    name: str
    path: Path
    work: Path
    commit: str  # HEAD of the checkout, or the commit git:REV named when measured
    runs: list[dict[str, Any]] = field(default_factory=list)


def cpu_s(pid: int) -> float:
    """The CPU time of every thread of ``pid`` so far (schedstat's first field, ns)."""
    total = 0
    with contextlib.suppress(FileNotFoundError, ProcessLookupError):
        for task in os.listdir(f"/proc/{pid}/task"):
            with contextlib.suppress(FileNotFoundError, ProcessLookupError):
                total += int(Path(f"/proc/{pid}/task/{task}/schedstat").read_text().split()[0])
    return total / 1e9


def unpack(rev: str, into: Path) -> Path:
    """``git archive rev`` of this repository unpacked into ``into``."""
    into.mkdir(parents=True)
    data = subprocess.run(
        ["git", "-C", str(ROOT), "archive", "--format=tar", rev, "swarmd"],
        capture_output=True,
        check=True,
        timeout=60,
    ).stdout
    archive = into / "tree.tar"
    archive.write_bytes(data)
    with tarfile.open(archive) as tar:
        tar.extractall(into, filter="data")
    archive.unlink()
    return into


def config_text(tree: Tree, index: int, bundle: Path, key: Path, q: float) -> str:
    """The flight's daemon config for drone ``index`` (``contenders.daemon_config`` with the
    flight's ``px4:`` section), its link file holding the static quality ``q``."""
    link = tree.work / "link.json"
    link.write_text(json.dumps({"q": q}))
    return daemon_config(
        index,
        bundle,
        key,
        tree.work / "ctl.sock",
        aware=True,
        link_file=link,
        mode="adaptive",
        state_dir=tree.work / "state",
        sections=px4_section(),
    )


def listener(host: Namespace, port: int) -> socket.socket:
    """A socket on ``host`` that receives the SPDP multicast group on its interface."""
    sock = host.socket()
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    sock.bind(("", port))
    mreq = struct.pack("4s4s", socket.inet_aton(SPDP_GROUP), socket.inet_aton(host.address))
    sock.setsockopt(socket.IPPROTO_IP, socket.IP_ADD_MEMBERSHIP, mreq)
    sock.setblocking(False)
    return sock


def drain(sock: socket.socket) -> None:
    with contextlib.suppress(BlockingIOError):
        while True:
            sock.recv(65536)


def one_start(
    tree: Tree,
    host: Namespace,
    config: Path,
    spdp: socket.socket,
    source: str,
    without: Sequence[str] = (),
) -> dict[str, Any]:
    """Start the daemon once from ``tree`` and time its stages (see the module docstring)."""
    notify_path = tree.work / "notify.sock"
    notify_path.unlink(missing_ok=True)
    notify = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    notify.bind(str(notify_path))
    notify.setblocking(False)
    drain(spdp)
    env = {
        "PATH": os.environ.get("PATH", "/usr/bin:/bin"),
        "PYTHONPATH": str(tree.path),
        "NOTIFY_SOCKET": str(notify_path),
    }
    out: dict[str, Any] = {"load_avg_at_start": os.getloadavg()[0]}
    t0 = time.monotonic()
    proc = subprocess.Popen(  # noqa: S603 - argv list, no shell
        host.command(
            [
                sys.executable,
                "-c",
                LAUNCHER.format(without=list(without)),
                "run",
                "--config",
                str(config),
            ]
        ),
        env=env,
        cwd=tree.path,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
    )
    assert proc.stderr is not None  # noqa: S101 - PIPE above
    os.set_blocking(proc.stderr.fileno(), False)
    sel = selectors.DefaultSelector()
    sel.register(notify, selectors.EVENT_READ, "notify")
    sel.register(spdp, selectors.EVENT_READ, "spdp")
    sel.register(proc.stderr, selectors.EVENT_READ, "log")
    pending = b""
    log: list[str] = []
    try:
        deadline = t0 + WAIT_S
        while ("ready_s" not in out or "first_spdp_s" not in out) and proc.poll() is None:
            left = deadline - time.monotonic()
            if left <= 0:
                out["error"] = "timeout"
                break
            for key, _ in sel.select(left):
                now = time.monotonic()
                if key.data == "notify":
                    msg = notify.recv(4096).decode(errors="replace")
                    if msg.startswith("READY=1") and "ready_s" not in out:
                        out["ready_s"], out["cpu_ready_s"] = now - t0, cpu_s(proc.pid)
                elif key.data == "spdp":
                    with contextlib.suppress(BlockingIOError):
                        while True:
                            data, (addr, _port) = spdp.recvfrom(65536)
                            if addr == source and data[:4] == b"RTPS" and "first_spdp_s" not in out:
                                out["first_spdp_s"] = now - t0
                                out["cpu_first_spdp_s"] = cpu_s(proc.pid)
                else:
                    with contextlib.suppress(BlockingIOError, TypeError):
                        pending += proc.stderr.read() or b""
                    *lines, pending = pending.split(b"\n")
                    log.extend(line.decode(errors="replace") for line in lines)
                    for line in lines:
                        if line.startswith(ENGINE_TAG.encode()):
                            seen = json.loads(line[len(ENGINE_TAG) :])
                            out["engine_s"] = seen["at"] - t0
                            out["cpu_engine_s"] = seen["cpu"]
                            out["passive_timer_s"] = seen["passive_timer_s"]
                            out["passive_window_s"] = seen["passive_window_s"]
        if proc.poll() is not None and "error" not in out and "first_spdp_s" not in out:
            out["error"] = f"exited {proc.returncode}: " + " | ".join(log[-3:])
    finally:
        sel.close()
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout=STOP_S)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(timeout=STOP_S)
        proc.stderr.close()
        notify.close()
        notify_path.unlink(missing_ok=True)
    if "first_spdp_s" in out and "passive_timer_s" in out:
        out["spdp_minus_passive_s"] = out["first_spdp_s"] - out["passive_timer_s"]
    return out


def p90(values: Sequence[float]) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, round(0.9 * (len(ordered) - 1)))]


def summary(runs: Sequence[dict[str, Any]]) -> dict[str, dict[str, float]]:
    out: dict[str, dict[str, float]] = {}
    for name in MEASURES:
        values = [r[name] for r in runs if r.get(name) is not None and "error" not in r]
        if values:
            out[name] = {
                "median": round(statistics.median(values), 4),
                "p90": round(p90(values), 4),
                "n": len(values),
            }
    return out


@contextlib.contextmanager
def trees(specs: Sequence[str], scratch: Path) -> Iterator[list[Tree]]:
    made: list[Tree] = []
    for spec in specs:
        name, _, where = spec.partition("=")
        if not where:
            raise SystemExit(f"--tree {spec}: expected NAME=PATH or NAME=git:REV")
        work = scratch / name
        if where.startswith("git:"):
            rev, path = where[4:], unpack(where[4:], scratch / f"{name}-src")
        else:
            rev, path = "HEAD", Path(where).resolve()
        commit = subprocess.run(
            ["git", "-C", str(path if rev == "HEAD" else ROOT), "rev-parse", "--short", rev],
            capture_output=True,
            text=True,
            check=False,
            timeout=30,
        ).stdout.strip()
        work.mkdir(parents=True)
        made.append(Tree(name, path, work, commit or "unknown"))
    yield made


def run(args: argparse.Namespace) -> dict[str, Any]:
    reason = unavailable_reason()
    if reason is not None:
        raise SystemExit(f"daemon_start: {reason}")
    node_index = 1  # uav2, a member (the reboot scenario restarts a member)
    with tempfile.TemporaryDirectory(prefix="swds-") as tmp, Lan(2) as lan:
        scratch = Path(tmp)
        host, other = lan[0], lan[1]
        subnet = host.address.rsplit(".", 1)[0]
        addresses = [f"{subnet}.{100 + i}" for i in range(args.n)]
        addresses[node_index] = host.address
        files = write_bundle(scratch / "bundle", addresses)
        spdp = listener(other, spdp_multicast_port(0))
        with trees(args.tree, scratch) as made:
            configs = {}
            for tree in made:
                # node.key's folder holds the epoch, windows and floor: one per tree
                shutil.copytree(files.path.parent, tree.work / "bundle")
                cfg = tree.work / "swarmd.yaml"
                cfg.write_text(
                    config_text(
                        tree,
                        node_index,
                        tree.work / "bundle" / files.path.name,
                        tree.work / "bundle" / files.trusted_key.name,
                        args.q,
                    )
                )
                configs[tree.name] = cfg
                warm = one_start(tree, host, cfg, spdp, host.address, args.without)
                if "error" in warm:
                    raise SystemExit(f"daemon_start: {tree.name}: warm-up failed: {warm['error']}")
            for repeat in range(args.repeats):
                for tree in made if repeat % 2 == 0 else list(reversed(made)):
                    result = one_start(
                        tree, host, configs[tree.name], spdp, host.address, args.without
                    )
                    tree.runs.append(result)
                    if not args.json:
                        shown = ", ".join(
                            f"{k} {result[k]:.3f}" for k in MEASURES if result.get(k) is not None
                        )
                        print(f"{tree.name} #{repeat + 1}: {result.get('error', shown)}")
            spdp.close()
            return {
                "n": args.n,
                "q": args.q,
                "node": f"uav{node_index + 1}",
                "repeats": args.repeats,
                "without": args.without,
                "trees": {
                    t.name: {
                        "path": str(t.path),
                        "commit": t.commit,
                        "summary": summary(t.runs),
                        "runs": t.runs,
                    }
                    for t in made
                },
            }


def table(doc: dict[str, Any]) -> str:
    names = list(doc["trees"])
    first = doc["trees"][names[0]]["summary"]
    lines = [
        f"daemon start-up, N = {doc['n']}, Q = {doc['q']}, {doc['repeats']} starts per tree"
        + (f", without {', '.join(doc['without'])}" if doc.get("without") else "")
        + " (median / p90, seconds from exec; cpu = user+sys of the process)",
        f"{'measure':22}"
        + "".join(f"{n + ' ' + doc['trees'][n].get('commit', ''):>22}" for n in names)
        + "   ratio to "
        + names[0],
    ]
    for m in MEASURES:
        cells, ratios = [], []
        for n in names:
            s = doc["trees"][n]["summary"].get(m)
            cells.append(f"{s['median']:.3f} / {s['p90']:.3f}" if s else "-")
            if s and m in first and first[m]["median"] > 0 and n != names[0]:
                ratios.append(f"{s['median'] / first[m]['median']:.2f}")
        lines.append(f"{m:22}" + "".join(f"{c:>22}" for c in cells) + "   " + " ".join(ratios))
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--tree",
        action="append",
        default=None,
        metavar="NAME=PATH|NAME=git:REV",
        help="a checkout to start the daemon from (repeatable; default: this one)",
    )
    parser.add_argument("--repeats", type=int, default=10, help="starts per tree (default 10)")
    parser.add_argument("--n", type=int, default=20, help="bundle members (default 20)")
    parser.add_argument("--q", type=float, default=0.415, help="static link quality")
    parser.add_argument(
        "--without",
        action="append",
        default=[],
        metavar="MODULE",
        help="start the daemon as if MODULE were not installed (repeatable): --without rich "
        "is the drone's venv (requirements/runtime-aarch64.lock has no rich; this venv has it "
        "for the tests, and structlog imports it when present)",
    )
    parser.add_argument("--json", action="store_true", help="print the JSON document")
    parser.add_argument(
        "--table", metavar="FILE", help="print the table of a saved --json document, run nothing"
    )
    args = parser.parse_args(argv)
    if args.table:
        print(table(json.loads(Path(args.table).read_text())))
        return 0
    if args.tree is None:
        args.tree = [f"this={ROOT}"]
    if not 1 <= args.repeats <= 200 or not 2 <= args.n <= 250:
        parser.error("--repeats 1..200, --n 2..250")
    doc = run(args)
    print(json.dumps(doc, indent=1) if args.json else table(doc))
    return 0


if __name__ == "__main__":
    sys.exit(main())
