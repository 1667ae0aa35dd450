"""What authenticating user data costs: bytes on the wire and CPU per datagram.

    .venv/bin/python bench/dataplane_auth.py [--repeat 7] [--number 20000] [--json]

Bytes come from the real encoder: two ``DataPlane``s of the shipped 10-node mission
(``firmware_bundle/missions/swarm10.yaml``: a commander and 9 members, dev keys) exchange
the 1 Hz readiness stream and one TAKEOFF with its two outcomes; then a TAKEOFF to every
member at N = 10, 50 and 1000 (one copy per member: the datagram each receives).
"Without" is the same datagram as the data plane sent it before authentication (``Header +
INFO_DST(receiver) + submessages``, rebuilt with the codec from the authenticated one's
submessages); "with" is what it sends now (``Header + submessages + AUTH``, 28-octet
authenticator, no INFO_DST, docs/wire.md). Octets are UDP payload; "+IP/UDP" adds the 28
octets of IPv4 and UDP headers every datagram also carries on the air.

CPU: median of ``--repeat`` timeit runs of ``--number`` calls, microseconds per call, for
``seal`` (HMAC-SHA256 over the datagram) and ``verify`` of a readiness datagram, and for the
data plane's whole ``receive_datagram`` on a forged datagram refused by a cheap check, on
one refused by its tag, and on an authentic one; and on a forgery under the prefix of a
member the receiver has not up (the early hold's case: refused by its tag before it may
take a slot, docs/security-history.md "Network paths end to end").
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from bench.codec import measure  # noqa: E402
from swarmd.auth.freshness import Freshness  # noqa: E402
from swarmd.auth.keys import KeyRing, NodeSecrets  # noqa: E402
from swarmd.bundle.build import build_dev_bundle  # noqa: E402
from swarmd.bundle.mission import parse_mission  # noqa: E402
from swarmd.bundle.model import Bundle, Role  # noqa: E402
from swarmd.dataplane import Command, CommandKind, CommandResult, DataPlane, Readiness  # noqa: E402
from swarmd.dataplane.plane import MAX_DATAGRAM_BYTES  # noqa: E402
from swarmd.dataplane.seal import (  # noqa: E402
    TAG_BYTES,
    protected_part,
    seal,
    user_data_key,
    verify,
)
from swarmd.dataplane.types import MAX_TARGETS, TimeEcho, encode_sample  # noqa: E402
from swarmd.rtps import InfoDst, decode_message, encode_message  # noqa: E402

MISSION = ROOT / "firmware_bundle" / "missions" / "swarm10.yaml"
MISSION_50 = ROOT / "firmware_bundle" / "missions" / "swarm50.yaml"
IP_UDP_BYTES = 28
EPOCH = 1_763_900_000  # a wall-clock epoch, as swarmd.auth.epoch makes them


def plane(bundle: Bundle, name: str) -> DataPlane:
    keys = KeyRing.from_bundle(bundle, name, NodeSecrets.dev(bundle.swarm, name))
    return DataPlane(bundle, name, keys=keys, epoch=EPOCH)


def unauthenticated(datagram: bytes, receiver: DataPlane) -> bytes:
    """The same datagram as the data plane sent it before issue 10."""
    msg = decode_message(protected_part(datagram))
    return encode_message(msg.header, [InfoDst(receiver.prefix), *msg.submessages])


def exchange(bundle: Bundle) -> dict[str, list[tuple[int, int]]]:
    """(with, without) octets of every datagram, by flow, between lead and one member."""
    members = [p.name for p in bundle.participants if p.role == Role.MEMBER]
    lead, member = plane(bundle, "lead"), plane(bundle, members[0])
    lead.peer_up(member.local.name, ("10.42.0.11", 7413), 0.0, epoch=EPOCH)
    member.peer_up("lead", ("10.42.0.10", 7411), 0.0, epoch=EPOCH)
    flows: dict[str, list[tuple[int, int]]] = {}

    def pump(src: DataPlane, dst: DataPlane, flow: str) -> None:
        for payload, _ in src.datagrams_to_send():
            flows.setdefault(flow, []).append((len(payload), len(unauthenticated(payload, dst))))
            dst.receive_datagram(payload, ("10.42.0.1", 7411), 0.0)

    name = member.local.name
    member.publish_readiness(Readiness(name, 1, True, "", False, 1, 3, 14, 87, 800), 0.0)
    pump(member, lead, "readiness (ready)")
    not_ready = Readiness(name, 2, False, "px4_no_heartbeat", False, 0, 0, 255, -1, 800)
    member.publish_readiness(not_ready, 0.0)
    pump(member, lead, "readiness (not ready, reason)")
    # as swarmctl takeoff --only <member> sends it: a 3 s validity and the member's echo
    takeoff = lead.make_command(
        CommandKind.TAKEOFF,
        altitude_m=10.0,
        targets=[name],
        valid_ms=3000,
        echoes=lead.time_echoes([name], 0.0),
    )
    lead.send_command(takeoff, 0.0)
    pump(lead, member, "command: TAKEOFF to one member, validity + echo (DATA + HEARTBEAT)")
    pump(member, lead, "command: member's ACKNACK")
    while (event := member.next_event()) is not None:
        if type(event).__name__ == "CommandReceived":
            cid = event.command.command_id  # type: ignore[union-attr]
            member.report_outcome(cid, CommandResult.ACCEPTED, 0.0)
            member.report_outcome(cid, CommandResult.COMPLETED, 0.0, "ok")
    pump(member, lead, "outcomes: ACCEPTED + COMPLETED")
    pump(lead, member, "outcomes: commander's ACKNACK")
    return flows


def readiness_sizes(bundle: Bundle, member: str) -> tuple[int, int]:
    """(with, without) octets of ``member``'s ready readiness datagram to the commander."""
    lead, plane_m = plane(bundle, "lead"), plane(bundle, member)
    plane_m.peer_up("lead", ("10.42.0.10", 7411), 0.0, epoch=EPOCH)
    plane_m.publish_readiness(Readiness(member, 1, True, "", False, 1, 3, 14, 87, 800), 0.0)
    ((payload, _),) = plane_m.datagrams_to_send()
    return len(payload), len(unauthenticated(payload, lead))


def scaling(bundle10: Bundle) -> list[dict[str, int]]:
    """The 1 Hz readiness stream at N = 10, 50 and 1000 (N - 1 members, one datagram each per
    second to the commander, so bytes/s = members x one datagram). 10 and 50: the shipped
    missions; 1000 (beyond MAVLink's 255 system ids, so no mission ships it): a two-node
    bundle whose member is named like the 1000th drone, ``drone-0999``."""
    bundle50 = build_dev_bundle(parse_mission(MISSION_50.read_text())).bundle
    big = parse_mission(
        "swarm: scale-1000\ndomain_id: 0\nparticipants:\n"
        "  - {name: lead, index: 0, role: commander, mavlink_sysid: 1}\n"
        "  - {name: drone-0999, index: 1, role: member, mavlink_sysid: 2}\n"
        "topics:\n"
        "  - {name: swarm/ready, type: 'swarmd::Readiness', reliability: best_effort,\n"
        "     history_depth: 1, writers: member, readers: commander}\n"
    )
    rows = []
    for n, bundle, member in (
        (10, bundle10, bundle10.participants[-1].name),
        (50, bundle50, bundle50.participants[-1].name),
        (1000, build_dev_bundle(big).bundle, "drone-0999"),
    ):
        with_auth, without = readiness_sizes(bundle, member)
        rows.append({"nodes": n, "datagram_with": with_auth, "datagram_without": without})
    return rows


def _mission_1000() -> Bundle:
    """A commander and 999 members ``drone-0001`` .. ``drone-0999`` with every topic of the
    shipped missions (MAVLink's 254 vehicle ids reused past 254, as the parser allows)."""
    topics = MISSION.read_text().split("\ntopics:", 1)[1]
    lines = ["swarm: scale-1000", "domain_id: 0", "participants:"]
    lines.append("  - {name: lead, index: 0, role: commander, mavlink_sysid: 1}")
    lines += [
        f"  - {{name: drone-{i:04d}, index: {i}, role: member, mavlink_sysid: {i % 254 + 1}}}"
        for i in range(1, 1000)
    ]
    return build_dev_bundle(parse_mission("\n".join(lines) + "\ntopics:" + topics)).bundle


def command_by_n(bundle10: Bundle) -> list[dict[str, Any]]:
    """A TAKEOFF to every member at N = 10, 50 and 1000, as ``swarmctl takeoff`` sends it
    (3 s validity, an echo per member): the datagram each member receives (DATA + HEARTBEAT
    + AUTH, one copy per member, docs/dataplane.md "One copy per member"), and what issue
    18's one sample with every target and echo would have made it (None past the IDL's 255
    targets, where it cannot even be encoded)."""
    bundle50 = build_dev_bundle(parse_mission(MISSION_50.read_text())).bundle
    rows: list[dict[str, Any]] = []
    for n, bundle in ((10, bundle10), (50, bundle50), (1000, _mission_1000())):
        members = [p.name for p in bundle.participants if p.role == Role.MEMBER]
        lead = plane(bundle, "lead")
        for i, name in enumerate(members):
            lead.peer_up(name, (f"10.1.{i // 250}.{i % 250 + 1}", 7411), 0.0, epoch=EPOCH)
        # a report received 250 ms before the issue, stamped by a member's clock at 4e9 ms
        echoes = [TimeEcho(name, 4_000_000_000 + i, 250, EPOCH) for i, name in enumerate(members)]
        takeoff = lead.make_command(
            CommandKind.TAKEOFF, altitude_m=10.0, targets=members, valid_ms=3000, echoes=echoes
        )
        lead.send_command(takeoff, 0.0)
        sizes = [len(payload) for payload, _ in lead.datagrams_to_send()]
        one_copy = encode_sample(
            Command(takeoff.command_id, takeoff.kind, 10.0, members[:1], 3000, echoes[:1])
        )
        whole: int | None = None
        if len(members) <= MAX_TARGETS:
            whole = max(sizes) - len(one_copy) + len(encode_sample(takeoff))
        rows.append(
            {
                "nodes": n,
                "members": len(members),
                "datagrams": len(sizes),
                "datagram_min": min(sizes),
                "datagram_max": max(sizes),
                "copy_sample": len(one_copy),
                "one_sample_for_all": whole,
            }
        )
    return rows


def timings(bundle: Bundle, repeat: int, number: int) -> dict[str, float]:
    members = [p.name for p in bundle.participants if p.role == Role.MEMBER]
    lead, member = plane(bundle, "lead"), plane(bundle, members[0])
    lead.peer_up(members[0], ("10.42.0.11", 7413), 0.0, epoch=EPOCH)
    member.peer_up("lead", ("10.42.0.10", 7411), 0.0, epoch=EPOCH)
    member.publish_readiness(Readiness(members[0], 1, True, "", False, 1, 3, 14, 87, 800), 0.0)
    ((datagram, _),) = member.datagrams_to_send()
    keys = KeyRing.from_bundle(bundle, members[0], NodeSecrets.dev(bundle.swarm, members[0]))
    pair = keys.pair_key(lead.prefix)
    assert pair is not None
    key = user_data_key(pair)
    body = protected_part(datagram)
    fresh = Freshness(EPOCH, 1)
    forged = datagram[:-TAG_BYTES] + bytes(TAG_BYTES)
    # a member the lead has not up: its datagrams may be held (dataplane/early.py)
    down = plane(bundle, members[1])
    down.peer_up("lead", ("10.42.0.10", 7411), 0.0, epoch=EPOCH)
    down.publish_readiness(Readiness(members[1], 1, True, "", False, 1, 3, 14, 87, 800), 0.0)
    ((down_datagram, _),) = down.datagrams_to_send()
    forged_down = down_datagram[:-TAG_BYTES] + bytes(TAG_BYTES)
    missing = body  # no authenticator at all
    source = ("10.42.0.11", 7413)

    def refused(data: bytes) -> Callable[[], None]:
        def run() -> None:
            lead.receive_datagram(data, source, 0.0)
            lead.next_event()

        return run

    cases: dict[str, Callable[[], object]] = {
        "seal (HMAC-SHA256-128 of a readiness datagram)": lambda: seal(
            key, body, fresh, lead.prefix, EPOCH
        ),
        "verify (the same, constant-time compare)": lambda: verify(
            key, datagram, lead.prefix, EPOCH
        ),
        "receive_datagram, refused: no authenticator": refused(missing),
        "receive_datagram, refused: replayed sequence": refused(datagram),
        "receive_datagram, refused: bad tag": refused(forged),
        "receive_datagram, refused: bad tag, sender not up (early hold)": refused(forged_down),
    }
    lead.receive_datagram(datagram, source, 0.0)  # now a replay for the case above
    while lead.next_event() is not None:
        pass
    out = {name: measure(fn, repeat, number) for name, fn in cases.items()}
    # an authentic datagram needs a sequence never seen: seal them all before timing
    fresh_ones = iter(
        [
            seal(key, body, Freshness(EPOCH, 2 + i), lead.prefix, EPOCH)
            for i in range(repeat * number)
        ]
    )

    def authentic() -> None:
        lead.receive_datagram(next(fresh_ones), source, 0.0)
        while lead.next_event() is not None:
            pass

    name = "receive_datagram, authentic readiness (verify, decode, deliver)"
    out[name] = measure(authentic, repeat, number)
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeat", type=int, default=7, help="timeit runs; the median is reported")
    ap.add_argument("--number", type=int, default=20000, help="calls per run")
    ap.add_argument("--json", action="store_true", help="print one JSON object instead")
    args = ap.parse_args()
    bundle = build_dev_bundle(parse_mission(MISSION.read_text())).bundle
    members = sum(1 for p in bundle.participants if p.role == Role.MEMBER)
    flows = exchange(bundle)
    cpu = timings(bundle, args.repeat, args.number)
    with_ready, without_ready = flows["readiness (ready)"][0]
    stream: dict[str, Any] = {
        "nodes": len(bundle.participants),
        "members": members,
        "bytes_per_s_with": members * with_ready,
        "bytes_per_s_without": members * without_ready,
        "bytes_per_s_with_ip_udp": members * (with_ready + IP_UDP_BYTES),
        "bytes_per_s_without_ip_udp": members * (without_ready + IP_UDP_BYTES),
    }
    scale = scaling(bundle)
    commands = command_by_n(bundle)
    result = {
        "machine": {"python": platform.python_version(), "cpu": platform.processor()},
        "datagrams": flows,
        "readiness_stream": stream,
        "readiness_stream_by_n": scale,
        "takeoff_to_all_by_n": commands,
        "cpu_us": cpu,
    }
    if args.json:
        print(json.dumps(result, indent=2))
        return 0
    print(f"mission {MISSION.name}: {len(bundle.participants)} nodes, {members} members\n")
    print("| flow | without | with | change | +IP/UDP without | +IP/UDP with | change |")
    print("|---|---:|---:|---:|---:|---:|---:|")
    for flow, sizes in flows.items():
        w = sum(s[0] for s in sizes)
        wo = sum(s[1] for s in sizes)
        n = len(sizes)
        w_ip, wo_ip = w + n * IP_UDP_BYTES, wo + n * IP_UDP_BYTES
        print(
            f"| {flow} ({n} datagram{'s' if n > 1 else ''}) | {wo} | {w} | {pct(w, wo)} "
            f"| {wo_ip} | {w_ip} | {pct(w_ip, wo_ip)} |"
        )
    s = stream
    print(
        f"\nreadiness stream, 1 Hz x {members} members: {s['bytes_per_s_without']} -> "
        f"{s['bytes_per_s_with']} B/s ({pct(s['bytes_per_s_with'], s['bytes_per_s_without'])}); "
        f"with IP/UDP {s['bytes_per_s_without_ip_udp']} -> {s['bytes_per_s_with_ip_udp']} B/s "
        f"({pct(s['bytes_per_s_with_ip_udp'], s['bytes_per_s_without_ip_udp'])}); "
        "packets unchanged\n"
    )
    print("| N | members | one datagram without / with | B/s without | B/s with | change |")
    print("|---:|---:|---|---:|---:|---:|")
    for row in scale:
        m = row["nodes"] - 1
        wo, w = row["datagram_without"], row["datagram_with"]
        print(f"| {row['nodes']} | {m} | {wo} / {w} | {m * wo} | {m * w} | {pct(w, wo)} |")
    print()
    print(
        "| N | members | TAKEOFF to all: datagrams | octets per member (min-max) "
        f"| a copy's sample | one sample for all (issue 18) | under {MAX_DATAGRAM_BYTES} |"
    )
    print("|---:|---:|---:|---|---:|---|---|")
    for cmd in commands:
        whole = cmd["one_sample_for_all"]
        old = f"over {MAX_TARGETS} targets: not encodable" if whole is None else str(whole)
        fits = "yes" if cmd["datagram_max"] < MAX_DATAGRAM_BYTES else "NO"
        print(
            f"| {cmd['nodes']} | {cmd['members']} | {cmd['datagrams']} "
            f"| {cmd['datagram_min']}-{cmd['datagram_max']} | {cmd['copy_sample']} "
            f"| {old} | {fits} |"
        )
    print()
    print("| case | µs per call |")
    print("|---|---:|")
    for name, us in cpu.items():
        print(f"| {name} | {us:.2f} |")
    return 0


def pct(new: int, old: int) -> str:
    return f"{(new - old) / old * 100:+.1f} %"


if __name__ == "__main__":
    raise SystemExit(main())
