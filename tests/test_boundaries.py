"""The rooms of swarmd and the arrows between them (design.md, docs/architecture.md).

Dependencies point inward: cli -> daemon/driver -> swarm, px4, dataplane, discovery ->
bundle, rtps; lab tools (``swarmd_lab``) use the cores and are never imported by swarmd.
``ALLOWED`` is that picture as a table: for every room (a package or top-level module of
``swarmd``), the other rooms its modules may import. A new room must be placed in it.

The sans-IO rooms (style.md rule 1) must not touch the event loop, sockets, threads or the
clock: each is imported in a fresh interpreter and ``sys.modules`` is checked for
``asyncio``/``socket``/``selectors``; ``time`` (always preloaded by the interpreter) and
``threading`` (preloaded by third-party codecs: pymavlink via ``logging``, cyclonedds-idl)
cannot be seen that way, so the rooms' own import statements are read as well.
"""

from __future__ import annotations

import ast
import json
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PKG = ROOT / "swarmd"

CORE = frozenset({"rtps", "bundle", "yamldoc", "exitcodes"})
# room -> the other rooms it may import (its own modules are always allowed)
ALLOWED: dict[str, frozenset[str]] = {
    # the wire codecs and shared facts: import nothing of swarmd
    "rtps": frozenset(),
    "xrce": frozenset({"rtps", "tokenbucket", "loopback"}),
    "yamldoc": frozenset(),
    "exitcodes": frozenset(),
    "bundle": frozenset({"rtps", "yamldoc", "exitcodes"}),
    # stock ROS 2 nodes' Fast DDS profiles from the bundle (text only, no ROS 2) and the
    # sans-IO SPDP relay the daemon runs for them on loopback (its unknown-participant
    # reports take a token bucket: review 16)
    "ros2": CORE | {"tokenbucket", "lives"},
    # authentication lives beside the codec, used by discovery and the data plane
    "auth": CORE | {"tokenbucket"},
    # the sans-IO cores
    "discovery": CORE | {"auth", "tokenbucket", "lives"},
    "dataplane": CORE | {"auth"},
    # the driving protocol, declared once (swarmd/sansio.py): a leaf
    "sansio": frozenset(),
    # the token bucket every budget is made of (auth, discovery, swarm, XRCE key checks, the
    # ROS 2 relay's reports): a leaf
    "tokenbucket": frozenset(),
    # a peer's lives damped over time (RFC 2439): discovery's restarts and returns, and the
    # ROS 2 relay's acting on a drone's liveness word (review 18b): a leaf
    "lives": frozenset(),
    # which of a peer's changes reach the log, a token bucket per key (the commander's
    # readiness lines, the daemon's peer moves and ROS 2 liveness: session 16; the ROS 2
    # relay's lines: review 18)
    "changereports": frozenset({"tokenbucket"}),
    # the one asyncio driver: it knows the driving protocol and no core
    "driver": frozenset({"sansio"}),
    # px4's asyncio adapter (bridge) runs its core through the driver; its sans-IO modules
    # cannot (the driver imports asyncio: test_sans_io_rooms)
    "px4": CORE | {"xrce", "driver", "senderuid", "loopback"},
    "swarm": CORE | {"auth", "dataplane", "discovery", "px4", "tokenbucket", "changereports"},
    # adapters and the daemon tier
    "link": frozenset({"discovery", "exitcodes"}),  # produces discovery's LinkSample
    # remote strings made safe for a terminal: swarmctl's views and the daemon's console log
    "terminal": frozenset(),
    "logs": frozenset({"terminal"}),
    "sdnotify": frozenset(),
    # the daemon's event loop on CLOCK_MONOTONIC_RAW, the clock validity rests on (a leaf)
    "rawclock": frozenset(),
    # sd_listen_fds(3): the sockets systemd bound for us (swarmd-px4.socket)
    "sdlisten": frozenset(),
    # the daemon's ring of peer changes for swarmctl watch (sans-IO, a leaf)
    "peerlog": frozenset(),
    # batched UDP reads (daemon tier): the SPDP sockets' and the user-data socket's
    "udp": frozenset(),
    # who sent a loopback datagram: its socket's uid by sock_diag or /proc/net/udp{,6} (daemon
    # tier, used by the ROS 2 relay's and the XRCE agent's adapters; the cores get the uid)
    "senderuid": frozenset({"sockdiag", "tokenbucket", "loopback"}),
    # loopback addresses and /proc/net/udp{,6} rows, read one way for senderuid, px4's
    # portowner and xrce's key-check origins (sans-IO: text in, values out; a leaf)
    "loopback": frozenset(),
    # the kernel's UDP socket table by netlink sock_diag: senderuid's first source (a leaf)
    "sockdiag": frozenset(),
    # the user-data UDP socket SwarmApp hands to the driver (daemon tier, not the swarm core)
    "userdata": CORE | {"udp"},
    # the state file: a member's boot count and decisions, read and written through one
    # judged folder descriptor (daemon tier; it reads the wall clock its kept times are
    # judged against, so it cannot be the swarm core's)
    "statefile": CORE | {"dataplane", "swarm"},
    # the daemon's file writes on one thread, off the loop: the state file and the replay
    # windows, coalesced (daemon tier; a leaf)
    "filewriter": frozenset(),
    "config": CORE | {"discovery", "px4", "link", "dataplane", "swarm"},
    # the nftables table (and iptables chain) of swarmd's loopback ports, generated from the
    # config (text only; swarmd local-firewall runs nft or iptables-restore: cli); a
    # v4-mapped address read as loopback reads it
    "localfirewall": CORE | {"config", "px4", "ros2", "loopback"},
    # a systemd unit's text read and its file-system sandbox judged (text in, values out;
    # swarmd check-config finds the unit: cli; a leaf)
    "unitsandbox": frozenset(),
    "control": CORE,
    # the swarm's wiring: its core, socket, state file and PX4 bridge (SwarmApp)
    "swarmapp": CORE
    | {"auth", "dataplane", "discovery", "px4", "swarm", "xrce"}
    | {"config", "control", "driver", "logs", "userdata", "statefile", "filewriter"}
    | {"swarmapp_status", "swarmapp_px4", "swarmapp_saves", "swarmapp_events"}
    | {"swarmapp_requests"},
    # SwarmApp's concerns, its base classes (split from swarmapp.py at 773 lines): each may
    # import what it uses of swarmapp's rooms and the concerns below it, never swarmapp
    "swarmapp_status": CORE
    | {"dataplane", "px4", "swarm", "config", "driver", "userdata", "statefile"},
    "swarmapp_px4": CORE | {"auth", "dataplane", "px4", "swarm", "swarmapp_status"},
    "swarmapp_saves": CORE
    | {"dataplane", "px4", "swarm", "statefile", "filewriter", "swarmapp_status"},
    "swarmapp_events": CORE | {"px4", "swarm", "swarmapp_status", "swarmapp_saves"},
    "swarmapp_requests": CORE | {"swarm", "control", "swarmapp_status"},
    # what the daemon derives before it starts: secrets, address, engine settings, link
    # sources, SPDP sockets, the systemd socket name (daemon tier, split from daemon.py)
    "daemon_setup": CORE | {"auth", "discovery", "link", "px4", "config", "udp", "sdlisten"},
    # the daemon's shared state and status (healthy, the watchdog, STATUS=), and its routing
    # of discovery's events to the log, the peer history, SwarmApp and the ROS 2 relay:
    # Daemon's base classes, split from daemon.py by concern (daemon tier)
    "daemon_status": CORE
    | {"auth", "discovery", "link", "config", "control", "driver", "peerlog", "sdnotify"}
    | {"swarmapp", "ros2app", "udp", "changereports", "filewriter"},
    "daemon_events": CORE | {"discovery", "peerlog", "daemon_status", "changereports"},
    # the ROS 2 relay's wiring: its core, its [::1] socket, its driver, its lines' budget
    # (review 18) (daemon tier)
    "ros2app": CORE | {"ros2", "config", "driver", "udp", "senderuid", "changereports"},
    "daemon": CORE
    | {"auth", "dataplane", "discovery", "px4", "swarm", "xrce", "link"}
    | {
        "rawclock",
        "config",
        "control",
        "daemon_events",
        "daemon_setup",
        "daemon_status",
        "driver",
        "logs",
        "peerlog",
        "sdnotify",
        "swarmapp",
        "ros2app",
        "udp",
        "filewriter",
    },
    "cli": CORE
    | {"auth", "dataplane", "discovery", "px4", "swarm", "xrce", "link"}
    | {"config", "control", "daemon", "driver", "logs", "sdnotify", "swarmapp", "terminal"}
    | {"daemon_setup", "ros2", "rawclock", "localfirewall", "unitsandbox"},
}
# Imports that break the table today, each with the work that removes it. An entry that no
# longer occurs fails the test too, so the list only shrinks.
KNOWN_OUTWARD: frozenset[tuple[str, str]] = frozenset()


@dataclass(frozen=True)
class SansIO:
    room: str
    io_modules: frozenset[str] = frozenset()  # the room's asyncio/serial/socket adapters


# Every module of these rooms is sans-IO except the adapters named; a new module is sans-IO
# unless it is added here with its reason.
SANS_IO = [
    SansIO("rtps"),
    SansIO("discovery"),
    # plane.py and what was split out of it by concern (sessions, pairs, received, commands)
    SansIO("dataplane"),
    SansIO("auth"),
    SansIO("xrce"),
    SansIO("ros2"),
    # transport: udp/serial byte links; mavlink_backend, bridge: the asyncio MAVLink backend
    # xrce_backend: the asyncio XRCE-DDS backend; provision: swarmctl px4 setup-signing's link
    # portowner: reads /proc to name who holds the PX4 link's port
    SansIO(
        "px4",
        frozenset(
            {"transport", "mavlink_backend", "bridge", "xrce_backend", "provision", "portowner"}
        ),
    ),
    # every module: core.py and its two sides, issuer.py and member.py; the swarm's I/O is
    # the daemon tier's (swarmd/statefile.py, swarmd/userdata.py)
    SansIO("swarm"),
]
NO_LOOP = ("asyncio", "socket", "selectors")
NO_IO = frozenset({"asyncio", "socket", "selectors", "threading", "time", "trio"})


def _rooms() -> list[str]:
    rooms = [p.name for p in PKG.iterdir() if p.is_dir() and (p / "__init__.py").exists()]
    rooms += [p.stem for p in PKG.glob("*.py") if p.stem != "__init__"]
    return sorted(rooms)


def _imports(source: str, package: str) -> list[tuple[int, str]]:
    """(line, absolute module name) of every import in ``source`` (a module of ``package``),
    ``from swarmd import x`` as ``swarmd.x`` and relative imports resolved."""
    out: list[tuple[int, str]] = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            out += [(node.lineno, a.name) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parent = package.rsplit(".", node.level - 1)[0] if node.level > 1 else package
                base = f"{parent}.{base}" if base else parent
            out += [(node.lineno, f"{base}.{a.name}") for a in node.names]
            out.append((node.lineno, base))
    return out


def _outward(rel: Path, source: str) -> list[tuple[int, str, str]]:
    """(line, target room, module) of each import of the module at ``swarmd/rel`` that the
    table does not allow; the lab is never allowed."""
    room = rel.parts[0].removesuffix(".py")
    package = ".".join(("swarmd", *rel.parts[:-1]))
    out = []
    for lineno, module in _imports(source, package):
        if module.split(".")[0] == "swarmd_lab":
            out.append((lineno, "swarmd_lab", module))
            continue
        target = _room_of(module)
        if target is not None and target != room and target not in ALLOWED[room]:
            out.append((lineno, target, module))
    return out


def _own_imports(path: Path) -> list[tuple[int, str]]:
    rel = path.relative_to(PKG)
    return _imports(path.read_text(), ".".join(("swarmd", *rel.parts[:-1])))


def _room_of(module: str) -> str | None:
    parts = module.split(".")
    if parts[0] != "swarmd" or len(parts) < 2 or parts[1] == "__version__":
        return None
    return parts[1] if parts[1] in set(_rooms()) else None


def _sans_io_modules(spec: SansIO) -> list[Path]:
    return [p for p in sorted((PKG / spec.room).glob("*.py")) if p.stem not in spec.io_modules]


def test_every_room_is_placed_in_the_table() -> None:
    assert set(_rooms()) - set(ALLOWED) == set(), "add the new room to ALLOWED (and design.md)"


def test_dependencies_point_inward() -> None:
    seen: set[tuple[str, str]] = set()
    lines: list[str] = []
    for path in sorted(PKG.rglob("*.py")):
        rel = path.relative_to(PKG)
        for lineno, target, module in _outward(rel, path.read_text()):
            seen.add((str(rel), target))
            if (str(rel), target) not in KNOWN_OUTWARD:
                lines.append(f"{rel}:{lineno} {rel.parts[0]} -> {target} ({module})")
    assert lines == []
    assert KNOWN_OUTWARD - seen == set(), "fixed: delete these from KNOWN_OUTWARD"


@pytest.mark.parametrize("spec", SANS_IO, ids=lambda s: s.room)
def test_sans_io_rooms_load_no_event_loop_or_socket(spec: SansIO) -> None:
    modules = [
        f"swarmd.{spec.room}.{p.stem}".removesuffix(".__init__") for p in _sans_io_modules(spec)
    ]
    code = (
        "import importlib, json, sys\n"
        f"for m in {modules!r}: importlib.import_module(m)\n"
        f"print(json.dumps(sorted(m for m in {NO_LOOP!r} if m in sys.modules)))\n"
    )
    result = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=ROOT
    )
    assert json.loads(result.stdout.strip().splitlines()[-1]) == []


def test_importing_the_core_pulls_in_no_asyncio_or_socket() -> None:
    # the lab's swarm builders and in-memory network drive the cores on virtual time: they
    # must not pull the loop in either (they moved to swarmd_lab, issue 11)
    code = (
        "import sys\n"
        "import swarmd.rtps, swarmd.discovery, swarmd_lab.testing, swarmd_lab.memnet\n"
        "bad = ('asyncio', 'socket', 'selectors')\n"
        "print(','.join(sorted(m for m in bad if m in sys.modules)))\n"
    )
    result = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=ROOT
    )
    assert result.stdout.strip() == ""


def test_no_module_of_the_core_imports_io_or_clock_modules() -> None:
    # `time` is always in sys.modules (the interpreter imports it at start), so the runtime
    # checks above cannot see it; this reads the import statements instead.
    offenders = []
    for spec in SANS_IO:
        for path in _sans_io_modules(spec):
            offenders += [
                f"{spec.room}/{path.name}:{lineno} {name}"
                for lineno, name in _own_imports(path)
                if name.split(".")[0] in NO_IO
            ]
    assert offenders == []


def test_the_table_catches_outward_imports_and_the_lab() -> None:
    # a test that cannot fail is a defect: the checks above, on sources that break the rules
    rel = Path("rtps/bad.py")
    source = (
        "from swarmd.discovery.engine import DiscoveryEngine\n"
        "from swarmd import daemon\n"
        "from ..bundle import model\n"
        "import swarmd_lab.sim\n"
        "from . import message\n"  # its own room: fine
    )
    flagged = _outward(rel, source)
    assert {t for _, t, _ in flagged} == {"discovery", "daemon", "bundle", "swarmd_lab"}
    assert {line for line, _, _ in flagged} == {1, 2, 3, 4}  # not line 5
    names = {m.split(".")[0] for _, m in _imports("import time\nfrom asyncio import sleep", "x")}
    assert names & NO_IO == {"time", "asyncio"}


def test_the_split_cores_stay_sans_io() -> None:
    # swarm/core.py and dataplane/plane.py were split by concern (docs/architecture.md): every
    # part is a module of a sans-IO room, so the checks above read and import it
    covered = {f"{spec.room}/{path.name}" for spec in SANS_IO for path in _sans_io_modules(spec)}
    parts = {
        "swarm/core.py",
        "swarm/issuer.py",
        "swarm/member.py",
        "dataplane/plane.py",
        "dataplane/sessions.py",
        "dataplane/pairs.py",
        "dataplane/received.py",
        "dataplane/commands.py",
    }
    assert parts - covered == set()
