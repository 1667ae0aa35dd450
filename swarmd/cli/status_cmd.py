"""``swarmctl status | peers | watch``: ask the local daemon over its control socket.

On the commander the human view ends with the swarm's readiness table (per drone: ready or
the failing reason, reports received, age of the last one), then the commands it sent
(``commands_view``: per command the drones per state and the ones not answered,
unreachable or refused); on a drone, the command its vehicle runs now. ``watch`` adds a
line per command sent and per drone answer, the take-off follow's own lines.

A daemon that is not running gives one line on stderr and exit code 2. ``--json`` prints
the daemon's status object unchanged (schema in docs/operations.md), for scripts and
``ssh drone swarmctl status --json | jq``.

Remote strings (a foreign participant's name, a member's reason) are data, never terminal
input: the human views go through ``terminal.safe_tree`` first, so control characters,
escape sequences and bidi overrides appear as visible escapes (issue 10, attack 8).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from collections.abc import Sequence
from typing import Any, Final, TextIO

from swarmd.cli.commands_view import CommandWatch, render_commands
from swarmd.config import DEFAULT_SOCKET
from swarmd.control import REQUEST_DEADLINE_S, ControlClient, DaemonUnreachable, RequestError
from swarmd.exitcodes import EX_OK, EX_UNREACHABLE
from swarmd.terminal import safe_text, safe_tree

SOCKET_ENV: Final = "SWARMD_SOCKET"
CLEAR_SCREEN: Final = "\x1b[H\x1b[2J"
WATCH_LOG_LINES: Final = 20  # peer changes kept under a redrawn watch screen
RECENT_CHANGES: Final = 5  # peer changes shown at the end of ``status``'s discovery part


def register(sub: Any) -> None:
    status = sub.add_parser("status", help="show this drone's discovery state")
    _common(status)
    status.set_defaults(func=_status)
    peers = sub.add_parser("peers", help="list the bundle's peers and their discovery state")
    _common(peers)
    peers.set_defaults(func=_peers)
    watch = sub.add_parser("watch", help="refresh the status until interrupted")
    _common(watch)
    watch.add_argument(
        "--interval", type=float, default=1.0, metavar="S", help="seconds between refreshes"
    )
    watch.add_argument(
        "--count", type=int, default=0, metavar="N", help="stop after N refreshes (0 = never)"
    )
    watch.set_defaults(func=_watch)


def socket_argument(parser: argparse.ArgumentParser) -> None:
    """``--socket PATH`` (default ``$SWARMD_SOCKET`` or the documented path)."""
    parser.add_argument(
        "--socket",
        default=os.environ.get(SOCKET_ENV, DEFAULT_SOCKET),
        metavar="PATH",
        help=f"daemon control socket (default ${SOCKET_ENV} or {DEFAULT_SOCKET})",
    )


def _common(parser: argparse.ArgumentParser) -> None:
    socket_argument(parser)
    parser.add_argument("--json", action="store_true", help="print JSON instead of a table")


def fail_unreachable(message: str) -> int:
    """One line on stderr (the daemon's words made safe, issue 10 attack 8) and exit 2."""
    print(f"swarmctl: {safe_text(message)}", file=sys.stderr)
    return EX_UNREACHABLE


def _status(args: argparse.Namespace) -> int:
    try:
        with ControlClient(args.socket) as client:
            status = client.request("status")
    except (DaemonUnreachable, RequestError) as exc:
        return fail_unreachable(str(exc))
    _print_status(status, args.json, sys.stdout)
    return EX_OK


def _peers(args: argparse.Namespace) -> int:
    try:
        with ControlClient(args.socket) as client:
            status = client.request("status")
    except (DaemonUnreachable, RequestError) as exc:
        return fail_unreachable(str(exc))
    peers = status.get("peers", []) if isinstance(status, dict) else []
    if args.json:
        print(json.dumps(peers, indent=2))
    else:
        print("\n".join(render_peers(peers if isinstance(peers, list) else [])))
    return EX_OK


def _watch(args: argparse.Namespace) -> int:
    frames = 0
    tty = sys.stdout.isatty()
    shown_seq: int | None = None  # the newest peer change already printed
    commands = CommandWatch()  # each command's sends and verdicts, said once
    log: list[str] = []  # on a terminal the screen is redrawn: keep the changes under it
    try:
        with ControlClient(args.socket) as client:
            while True:
                status = client.request("status")
                wall_now = time.time()
                fresh, shown_seq = new_peer_changes(status, shown_seq, wall_now)
                fresh = [f"peer change: {ln}" for ln in fresh]
                if isinstance(status, dict):
                    # the take-off follow's lines (commands_view), made safe here: drone
                    # names and reasons are data (issue 10, attack 8)
                    at = _clock(0, wall_now)
                    fresh += [f"command: {at}  {safe_text(ln)}" for ln in commands.update(status)]
                if tty and not args.json:
                    sys.stdout.write(CLEAR_SCREEN)
                _print_status(status, args.json, sys.stdout, compact_json=True)
                if not args.json and fresh:
                    log = (log + fresh)[-WATCH_LOG_LINES:]
                    if not tty:  # a pipe or a file: each change once, as it happens
                        sys.stdout.write("".join(f"{ln}\n" for ln in fresh))
                if tty and not args.json and log:
                    sys.stdout.write("changes while watching:\n")
                    sys.stdout.write("".join(f"  {ln}\n" for ln in log))
                sys.stdout.flush()
                frames += 1
                if args.count and frames >= args.count:
                    return EX_OK
                if args.interval >= REQUEST_DEADLINE_S / 2:
                    # the daemon closes a connection idle past its deadline: a slow
                    # refresh reconnects rather than race that close
                    client.close()
                time.sleep(max(0.1, args.interval))
    except (DaemonUnreachable, RequestError) as exc:
        return fail_unreachable(str(exc))
    except KeyboardInterrupt:
        return EX_OK


def new_peer_changes(
    status: Any, shown_seq: int | None, wall_now: float
) -> tuple[list[str], int | None]:
    """The lines of the peer changes newer than ``shown_seq`` and the new high-water mark.

    The first frame (``shown_seq`` None) prints nothing new: ``status`` already lists the
    recent ones. A daemon restarted under the watch numbers from 1 again: its whole ring is
    new."""
    changes = status.get("peer_changes") if isinstance(status, dict) else None
    if not isinstance(changes, dict):
        return [], shown_seq
    last = changes.get("last_seq")
    if isinstance(last, bool) or not isinstance(last, int):
        return [], shown_seq
    if shown_seq is None:
        return [], last
    after = shown_seq if last >= shown_seq else 0
    rows = changes.get("changes")
    lines = render_peer_changes(rows if isinstance(rows, list) else [], wall_now, after_seq=after)
    return lines, last


def _print_status(status: Any, as_json: bool, out: TextIO, *, compact_json: bool = False) -> None:
    if as_json:
        out.write(json.dumps(status, indent=None if compact_json else 2) + "\n")
    else:
        out.write("\n".join(render_status(status if isinstance(status, dict) else {})) + "\n")


# -- rendering (pure: status dict -> lines) ----------------------------------------------


def _num(value: Any, fmt: str, unit: str = "") -> str:
    if isinstance(value, bool) or not isinstance(value, int | float):
        return "-"
    return f"{value:{fmt}}{unit}"


def table(headers: Sequence[str], rows: Sequence[Sequence[str]], indent: str = "  ") -> list[str]:
    """Left-aligned columns, as wide as their widest cell."""
    widths = [
        max(len(h), *(len(r[i]) for r in rows)) if rows else len(h) for i, h in enumerate(headers)
    ]
    lines = [indent + "  ".join(h.ljust(w) for h, w in zip(headers, widths, strict=True)).rstrip()]
    for row in rows:
        cells = (c.ljust(w) for c, w in zip(row, widths, strict=True))
        lines.append(indent + "  ".join(cells).rstrip())
    return lines


def _yes_no(value: Any) -> str:
    return "yes" if value is True else "no" if value is False else "-"


def render_peers(peers: Sequence[Any]) -> list[str]:
    """The peer table: name, state, last heard, locator, matched endpoints (made safe)."""
    return _render_peers(safe_tree(list(peers)))


def _render_peers(peers: Sequence[Any]) -> list[str]:
    rows = []
    for p in peers:
        if not isinstance(p, dict):
            continue
        rows.append(
            [
                str(p.get("name", "?")),
                str(p.get("state", "?")),
                _num(p.get("last_heard_s"), ".1f", " s ago"),
                _num(p.get("link_q"), ".2f"),
                str(p.get("locator") or "-"),
                _num(p.get("matched_endpoints"), "d"),
                _yes_no(p.get("lists_me")),
            ]
        )
    return table(["PEER", "STATE", "LAST HEARD", "Q", "LOCATOR", "ENDPOINTS", "HEARS ME"], rows)


def _clock(ago_s: Any, wall_now: float) -> str:
    """The wall-clock time ``ago_s`` before ``wall_now`` (this host's local time)."""
    if isinstance(ago_s, bool) or not isinstance(ago_s, int | float):
        return "--:--:--"
    return time.strftime("%H:%M:%S", time.localtime(wall_now - ago_s))


def render_peer_changes(
    changes: Sequence[Any], wall_now: float, *, after_seq: int = 0
) -> list[str]:
    """One line per peer change newer than ``after_seq``: when, who, lost/regained/restarted,
    why, the link quality it advertised and how long it had been silent (made safe)."""
    return _render_peer_changes(safe_tree(list(changes)), wall_now, after_seq)


def _render_peer_changes(changes: Sequence[Any], wall_now: float, after_seq: int) -> list[str]:
    lines = []
    for c in changes:
        if not isinstance(c, dict):
            continue
        seq = c.get("seq")
        if isinstance(seq, int) and seq <= after_seq:
            continue
        kind = str(c.get("change", "?"))
        reason = c.get("reason")
        line = f"{_clock(c.get('ago_s'), wall_now)}  {c.get('peer', '?')} {kind.upper()}"
        if reason:
            line += f" ({reason})"
        line += f"  Q {_num(c.get('link_q'), '.2f')}"
        if kind == "lost" and c.get("silent_s") is not None:
            line += f"  last heard {_num(c.get('silent_s'), '.1f', ' s')} before"
        lines.append(line)
    return lines


def render_status(status: dict[str, Any], wall_now: float | None = None) -> list[str]:
    """The human view of ``swarmctl status``; every string in ``status`` is made safe for a
    terminal first (``terminal.safe_tree``). ``wall_now`` dates the peer changes (default:
    this host's clock now)."""
    return _render_status(safe_tree(status), time.time() if wall_now is None else wall_now)


def _render_status(status: dict[str, Any], wall_now: float) -> list[str]:
    link = status.get("link") or {}
    lines = [
        f"node {status.get('node', '?')}  swarm {status.get('swarm', '?')}  "
        f"phase {status.get('phase', '?')}  mode {status.get('mode', '?')}",
        f"link Q {_num(link.get('q'), '.2f')}  SNR {_num(link.get('snr_db'), '.1f', ' dB')}  "
        f"source {link.get('source') or '-'}",
    ]
    rates = status.get("rates")
    if isinstance(rates, dict):
        lines.append(
            f"per s over {_num(rates.get('window_s'), '.0f', ' s')}: "
            f"renewals sent {_num(rates.get('renewals_sent_per_s'), '.3f')}  "
            f"vouches sent {_num(rates.get('vouches_sent_per_s'), '.3f')}  "
            f"received {_num(rates.get('vouches_received_per_s'), '.3f')}"
        )
    timer = status.get("passive_timer_s")
    lines.append(
        "passive timer: " + (f"{_num(timer, '.1f')} s remaining" if timer is not None else "-")
    )
    peers = [p for p in status.get("peers", []) if isinstance(p, dict)]
    found = status.get("peers_discovered", sum(p.get("state") == "discovered" for p in peers))
    total = status.get("peers_total", len(peers))
    lines.append(f"peers discovered {found}/{total}")
    if peers:
        lines += _render_peers(peers)
    foreign = [f for f in status.get("foreign", []) if isinstance(f, dict)]
    lines.append(f"foreign participants {len(foreign)}")
    if foreign:
        rows = [
            [str(f.get("guid", "?")), str(f.get("vendor", "?")), str(f.get("name") or "-")]
            for f in foreign
        ]
        lines += table(["GUID", "VENDOR", "NAME"], rows)
    lines += render_ros2(status.get("ros2"))
    lines.append(render_counters(status.get("counters") or {}))
    changes = status.get("peer_changes")
    if isinstance(changes, dict) and isinstance(changes.get("changes"), list):
        recent = changes["changes"][-RECENT_CHANGES:]
        lines.append(
            f"peer changes: lost {_num(changes.get('lost'), 'd')}, "
            f"regained {_num(changes.get('regained'), 'd')}"
            + (f"; last {len(recent)}:" if recent else "")
        )
        lines += ["  " + ln for ln in _render_peer_changes(recent, wall_now, 0)]
    lines += render_swarm(status)
    lines += render_commands(status)  # already made safe above (terminal.safe_tree)
    return lines


def render_ros2(ros2: Any) -> list[str]:
    """The ROS 2 relay's rows (docs/ros2.md): this drone's nodes as heard on loopback, the
    other drones' nodes as relayed from the bundle, and participants the bundle does not
    hold; a node's endpoints that the bundle lacks are named under it."""
    if not isinstance(ros2, dict):
        return []
    local = [r for r in ros2.get("local", []) if isinstance(r, dict)]
    remote = [r for r in ros2.get("remote", []) if isinstance(r, dict)]
    unknown = [r for r in ros2.get("unknown", []) if isinstance(r, dict)]
    lines = [f"ros2 relay {ros2.get('relay', '?')}  lease {_num(ros2.get('lease_s'), 'g', ' s')}"]
    if ros2.get("alive_bitmap") is not None:
        # what swarmd's signed DATA(p) tells the other drones (PID 0x8A06, docs/ros2.md)
        lines[0] += f"  alive bitmap {ros2['alive_bitmap']}"
    counters = ros2.get("counters")
    foreign = counters.get("rx_foreign_user") if isinstance(counters, dict) else None
    if isinstance(counters, dict) and isinstance(foreign, int) and foreign:
        # ros2.node_users (docs/security.md, "The local user"): other users' datagrams, and
        # how often a node user's port was another user's too (a denial, or a spoof refused)
        lines[0] += f"  dropped {foreign} datagrams of other local users"
        shared = counters.get("sender_port_shared")
        if isinstance(shared, int) and shared:
            lines[0] += f" ({shared} from a node's port another user holds too)"
    graph = ros2.get("graph")
    if isinstance(graph, dict):
        # graph preloading (docs/ros2.md): the other drones' node names, served on loopback
        lines.append(
            f"ros2 graph: {_num(graph.get('samples'), '.0f')} node entries served to "
            f"{_num(graph.get('readers'), '.0f')} local graph readers, "
            f"{_num(graph.get('readers_up_to_date'), '.0f')} up to date"
        )
    rows = []
    for r in local:
        rows.append(
            [
                "this drone",
                str(r.get("node", "?")),
                str(r.get("state", "?")),
                _num(r.get("last_heard_s"), ".1f", " s ago"),
                str(r.get("guid_prefix", "?")),
            ]
        )
        for u in r.get("undeclared_endpoints") or []:
            if isinstance(u, dict):
                rows.append(
                    [
                        "",
                        f"  undeclared {u.get('kind', '?')}",
                        f"id {u.get('user_id', '?')}",
                        f"entity {u.get('entity_id', '?')}",
                        "not in the bundle: matches nothing",
                    ]
                )
        more = r.get("undeclared_not_shown")
        if isinstance(more, int) and more > 0:
            rows.append(["", f"  undeclared: {more} more", "", "", "not shown"])
    for r in remote:
        rows.append(
            [
                str(r.get("drone", "?")),
                str(r.get("node", "?")),
                str(r.get("state", "?")),
                str(r.get("user_locator") or "-"),
                str(r.get("guid_prefix", "?")),
            ]
        )
    for r in unknown:
        rows.append(
            [
                "unknown",
                str(r.get("name") or "-"),
                f"vendor {r.get('vendor', '?')}",
                _num(r.get("last_heard_s"), ".1f", " s ago"),
                str(r.get("guid_prefix", "?")),
            ]
        )
    if rows:
        lines += table(["DRONE", "ROS 2 NODE", "STATE", "HEARD / USER DATA", "GUID PREFIX"], rows)
    return lines


def render_px4_backend(b: dict[str, Any]) -> str:
    """``px4 link: xrce-agent udp:127.0.0.1:888, session established (...), PX4 1.16, refused
    4 clients (last 127.0.0.1:40001 key 0000002a (vehicle_alive))`` or
    ``px4 link: mavlink udpin:127.0.0.1:14540, autopilot 127.0.0.1:14580 (learned), signed
    (ok 5120), refused 3``."""
    line = f"px4 link: {b.get('backend', '?')} {b.get('connection', '')}"
    if "session" in b:  # the XRCE backends
        line += f", session {b.get('session')}"
        if b.get("client"):
            line += f" ({b['client']})"
        line += f", PX4 {b.get('px4_version') or 'version not seen yet'}"
        if b.get("layout_problem"):
            line += f", {b['layout_problem']}"
        # one agent, one vehicle (docs/px4.md): second clients and other vehicles' samples
        clients = _sum_counters(b.get("refused") or {}, "")
        if clients:
            line += f", refused {clients} clients (last {b.get('last_refused') or '?'})"
        unchecked = (b.get("refused") or {}).get("over_budget")
        if isinstance(unchecked, int) and unchecked:  # a key-guessing flood (docs/security.md)
            line += f", {unchecked} of them over the key-check budget (unchecked)"
        if b.get("foreign_samples"):
            line += (
                f", dropped {b['foreign_samples']} samples of system id "
                f"{b.get('foreign_system_id')} (not {b.get('sysid')})"
            )
        # px4.loopback_user (docs/security.md, "The local user"): other users' datagrams,
        # and how often PX4's port was another user's too (a denial, or a spoof refused)
        foreign = (b.get("dropped") or {}).get("foreign_user")
        if isinstance(foreign, int) and foreign:
            line += f", dropped {foreign} datagrams of other local users"
            shared = b.get("sender_port_shared")
            if isinstance(shared, int) and shared:
                line += f" ({shared} from PX4's port another user holds too)"
    pin, signing = b.get("autopilot"), b.get("signing")
    if isinstance(pin, dict):  # MAVLink over UDP: who is heard as the autopilot
        line += f", autopilot {pin.get('pinned') or 'not pinned yet'} ({pin.get('pin', '?')})"
    if isinstance(signing, dict):
        line += f", signed (ok {signing.get('ok', 0)})" if signing.get("enabled") else ", unsigned"
    refused = _sum_counters(pin if isinstance(pin, dict) else {}, "dropped_")
    refused += _sum_counters(signing if isinstance(signing, dict) else {}, "dropped_")
    if refused:  # forged or stray frames on the PX4 link (docs/px4.md "Trust on the PX4 link")
        line += f", refused {refused}"
    boot = b.get("boot_clock")
    resets = boot.get("resets") if isinstance(boot, dict) else None
    if isinstance(resets, int) and resets:  # MAVLink: PX4 lives told apart ("Fresh state")
        line += f", PX4 rebooted {resets} times (boot clock)"
    return line


def render_swarm(status: dict[str, Any]) -> list[str]:
    """The swarm layer: this drone's PX4 verdict, the data plane, the readiness table."""
    lines: list[str] = []
    px4 = status.get("px4")
    if isinstance(px4, dict):
        verdict = px4.get("readiness") or {}
        if not px4.get("enabled"):
            lines.append("px4: disabled")
        elif verdict.get("ready"):
            lines.append(f"px4: ready for take-off  ({verdict.get('landed_state') or '-'})")
        else:
            lines.append(
                f"px4: NOT READY {verdict.get('reason') or '?'}: {verdict.get('detail') or ''}"
            )
        backend = px4.get("backend")
        if px4.get("enabled") and isinstance(backend, dict):
            lines.append(render_px4_backend(backend))
    dp = status.get("dataplane")
    if isinstance(dp, dict):
        if not dp.get("enabled"):
            lines.append("data plane: disabled")
        else:
            c = dp.get("counters") or {}
            line = (
                f"data plane: {status.get('role', '?')}, incarnation {dp.get('incarnation')}, "
                f"peers up {len(dp.get('peers_up') or [])}, datagrams in "
                f"{c.get('rx_datagrams', 0)} out {c.get('tx_datagrams', 0)}, readiness sent "
                f"{dp.get('readiness_published', 0)}"
            )
            refused = _sum_counters(c, "dropped_")
            if refused:  # unauthenticated = forged, replayed, or a peer's restart in progress
                line += f", refused {refused} ({_sum_counters(c, 'dropped_auth_')} unauthenticated)"
            lines.append(line)
    rows = status.get("readiness")
    if isinstance(rows, dict) and rows:
        ready = sum(1 for r in rows.values() if isinstance(r, dict) and r.get("ready"))
        lines.append(f"swarm readiness {ready}/{len(rows)} ready")
        lines += render_readiness(rows)
    return lines


def _sum_counters(counters: dict[str, Any], prefix: str) -> int:
    return sum(v for k, v in counters.items() if k.startswith(prefix) and isinstance(v, int))


def render_readiness(rows: dict[str, Any]) -> list[str]:
    """The commander's table: per drone ready or the reason, reports received, report age."""
    out = []
    for name, r in rows.items():
        if not isinstance(r, dict):
            continue
        out.append(
            [
                name + (" (self)" if r.get("local") else ""),
                "ready" if r.get("ready") else str(r.get("reason") or "not ready"),
                _num(r.get("count"), "d"),
                _num(r.get("age_s"), ".1f", " s"),
                str(r.get("landed_state") or "-"),
                _num(r.get("battery_pct"), "d", " %"),
                _num(r.get("gps_fix"), "d"),
                _num(r.get("link_q"), ".2f"),
            ]
        )
    return table(["DRONE", "READY", "REPORTS", "AGE", "LANDED", "BATTERY", "GPS", "Q"], out)


def render_counters(counters: dict[str, Any]) -> str:
    dropped = counters.get("dropped") or {}
    drops = (
        {k: v for k, v in dropped.items() if isinstance(v, int) and v}
        if isinstance(dropped, dict)
        else {}
    )
    detail = ", ".join(f"{k} {v}" for k, v in sorted(drops.items()))
    return (
        f"packets in {counters.get('rx_datagrams', 0)}  out {counters.get('tx_datagrams', 0)} "
        f"(multicast {counters.get('tx_multicast', 0)}, unicast {counters.get('tx_unicast', 0)})  "
        f"dropped {sum(drops.values())}" + (f" ({detail})" if detail else "")
    )
