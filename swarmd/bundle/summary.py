"""What ``swarmctl bundle show`` and ``verify`` print: a JSON-able summary and a short table.

The per-node match table is computed by grouping endpoints per topic instead of calling
``Bundle.matches`` for every pair, so a 500-drone bundle is summarised in linear time per
topic; the tests check both give the same pairs.
"""

from __future__ import annotations

from collections import defaultdict
from typing import Any

from swarmd.bundle.encoding import FORMAT_VERSION
from swarmd.bundle.keys import fingerprint
from swarmd.bundle.model import Bundle, EndpointKind


def node_matches(bundle: Bundle, only: str | None = None) -> dict[str, list[dict[str, Any]]]:
    """For each node (or just ``only``): its endpoints and the peers each one matches."""
    holders: dict[tuple[str, EndpointKind], list[str]] = defaultdict(list)
    for p in bundle.participants:
        for e in p.endpoints:
            holders[(e.topic, e.kind)].append(p.name)
    compatible = {t.name: t.qos.compatible_with(t.qos) for t in bundle.topics}
    out: dict[str, list[dict[str, Any]]] = {}
    for p in bundle.participants:
        if only is not None and p.name != only:
            continue
        rows = []
        for e in p.endpoints:
            other = EndpointKind.READER if e.kind == EndpointKind.WRITER else EndpointKind.WRITER
            peers = (
                [n for n in holders[(e.topic, other)] if n != p.name] if compatible[e.topic] else []
            )
            rows.append(
                {
                    "topic": e.topic,
                    "kind": e.kind.value,
                    "guid": str(p.guid(e)),
                    "peers": peers,
                }
            )
        out[p.name] = rows
    return out


def summary(
    bundle: Bundle,
    *,
    file: str,
    size: int,
    dev: bool,
    trust: str,
    matches_for: str | None = None,
    with_matches: bool = True,
) -> dict[str, Any]:
    """The machine-readable view (``--json``); ``trust`` says what the signature was checked
    against: ``trusted-key``, ``pinned-hash`` or ``embedded-key``."""
    writers: dict[str, list[str]] = defaultdict(list)
    readers: dict[str, list[str]] = defaultdict(list)
    for p in bundle.participants:
        for e in p.endpoints:
            (writers if e.kind == EndpointKind.WRITER else readers)[e.topic].append(p.name)
    out: dict[str, Any] = {
        "file": file,
        "size_bytes": size,
        "format_version": FORMAT_VERSION,
        "swarm": bundle.swarm,
        "domain_id": bundle.domain_id,
        "content_sha256": bundle.content_sha256.hex(),
        "signer": fingerprint(bundle.signing_public_key),
        "signer_public_key": bundle.signing_public_key.hex(),
        "dev": dev,
        "trust": trust,
        "serial": bundle.serial,  # null: built before serials
        "discovery": {
            "t_min_s": bundle.discovery.t_min_s,
            "t_max_s": bundle.discovery.t_max_s,
            "lease_s": bundle.discovery.lease_s,
        },
        "participants": [
            {
                "name": p.name,
                "index": p.index,
                "role": p.role.value,
                "mavlink_sysid": p.mavlink_sysid,
                "ipv4": p.ipv4,
                "guid_prefix": str(p.guid_prefix),
                "metatraffic_unicast_port": bundle.metatraffic_port(p),
                "user_unicast_port": bundle.user_port(p),
                "announce_key": fingerprint(p.announce_public_key),
                "x25519_key": fingerprint(p.x25519_public_key),
                "endpoints": len(p.endpoints),
            }
            for p in bundle.participants
        ],
        "topics": [
            {
                "name": t.name,
                "type_name": t.type_name,
                "reliability": t.qos.reliability.value,
                "durability": t.qos.durability.value,
                "history_depth": t.qos.history_depth,
                "liveliness": t.qos.liveliness.value,
                "liveliness_lease_s": t.qos.liveliness_lease_s,
                "writers": writers[t.name],
                "readers": readers[t.name],
            }
            for t in bundle.topics
        ],
    }
    if with_matches:
        out["matches"] = node_matches(bundle, matches_for)
    return out


def _table(headers: list[str], rows: list[list[str]]) -> list[str]:
    widths = [
        max(len(h), *(len(r[i]) for r in rows)) if rows else len(h) for i, h in enumerate(headers)
    ]
    fmt = "  ".join(f"{{:<{w}}}" for w in widths)
    return [fmt.format(*headers).rstrip(), *(fmt.format(*r).rstrip() for r in rows)]


def serial_text(serial: int | None) -> str:
    """A bundle's serial for a person: the number, or what its absence means."""
    return "none (built before serials)" if serial is None else str(serial)


def human(s: dict[str, Any]) -> str:
    """The short human view of ``summary(...)``."""
    d = s["discovery"]
    trust = {
        "trusted-key": "signature valid, signer is the trusted swarm key",
        "pinned-hash": "signature valid, content hash matches the pinned one",
        "embedded-key": "signature valid under the embedded key (no trust anchor given)",
    }[s["trust"]]
    lines = [
        f"bundle     {s['file']} ({s['size_bytes']} bytes, format {s['format_version']})",
        f"swarm      {s['swarm']}  domain {s['domain_id']}  "
        f"{len(s['participants'])} participants, {len(s['topics'])} topics",
        f"sha256     {s['content_sha256']}",
        f"serial     {serial_text(s['serial'])}",
        f"signer     {s['signer']}  {trust}" + ("  [DEV: insecure lab key]" if s["dev"] else ""),
        f"discovery  Tmin {d['t_min_s']:g} s, Tmax {d['t_max_s']:g} s, lease {d['lease_s']:g} s",
        "",
    ]
    matches = s.get("matches", {})
    prow = []
    for p in s["participants"]:
        peers = {n for row in matches.get(p["name"], []) for n in row["peers"]}
        prow.append(
            [
                str(p["index"]),
                p["name"],
                p["role"],
                str(p["mavlink_sysid"]),
                p["ipv4"] or "-",
                p["guid_prefix"],
                f"{p['metatraffic_unicast_port']}/{p['user_unicast_port']}",
                str(p["endpoints"]),
                str(len(peers)) if p["name"] in matches else "-",
            ]
        )
    lines += _table(
        ["IDX", "NAME", "ROLE", "SYSID", "IPV4", "GUID PREFIX", "PORTS M/U", "EPS", "PEERS"], prow
    )
    lines.append("")
    trow = [
        [
            t["name"],
            t["type_name"],
            t["reliability"],
            t["durability"],
            str(t["history_depth"]),
            str(len(t["writers"])),
            str(len(t["readers"])),
        ]
        for t in s["topics"]
    ]
    lines += _table(["TOPIC", "TYPE", "RELIABILITY", "DURABILITY", "DEPTH", "W", "R"], trow)
    return "\n".join(lines)
