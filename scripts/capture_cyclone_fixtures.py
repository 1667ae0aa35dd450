#!/usr/bin/env python3
"""Capture live Cyclone DDS SPDP packets into tests/fixtures/cyclone-live/ (needs root).

Builds a two-namespace LAN (10.77.1.0/24), starts a stock Cyclone participant (PyPI
cyclonedds, the venv's version) in 10.77.1.1 and, from 10.77.1.2, records:

  data-p-multicast     its periodic DATA(p) to 239.255.0.1:7400
  data-p-directed      its directed reply (INFO_DST = our prefix) after we announce swarmd
  data-p-ud-multicast  its DATA(p[UD]) to the group when the participant is deleted
  data-p-ud-unicast    the same dispose sent to our metatraffic unicast locator

Each packet is written as ``NAME.bin`` (the UDP payload) and ``NAME.json``: tshark's summary
line and its dissection of every SPDP sample (an implementation independent of swarmd),
plus what Cyclone's own trace says about itself. tests/test_golden_cyclone_live.py checks
swarmd's decoder against these sidecars. Rerun: ``sudo .venv/bin/python
scripts/capture_cyclone_fixtures.py [--out DIR]``; see docs/interop.md.
"""

from __future__ import annotations

import argparse
import json
import re
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from contextlib import closing
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))  # the Cyclone and tshark drivers live in tests/peers

from swarmd_lab.netns import Lan, unavailable_reason  # noqa: E402

from swarmd.rtps import (  # noqa: E402
    BES_SPDP_ONLY,
    DecodeError,
    Duration,
    GuidPrefix,
    Locator,
    SpdpAlive,
    SpdpParticipant,
    decode_spdp,
    encode_spdp,
)
from swarmd.rtps.ports import SPDP_MULTICAST_GROUP, spdp_multicast_port  # noqa: E402
from tests.peers.cyclone import CyclonePeer, own_participant_pattern  # noqa: E402
from tests.peers.tshark import (  # noqa: E402
    Datagram,
    dissect_tree,
    spdp_view,
    tshark_path,
    write_pcap,
)
from tests.peers.udp import group_listener, receive_until, unicast_socket  # noqa: E402

SUBNET = "10.77.1.0/24"
OUR_PREFIX = GuidPrefix(bytes.fromhex("5357ca97e000000000000001"))
META_PORT = 7410
WAIT_S = 5.0
DESCRIPTIONS = {
    "data-p-multicast": "Cyclone's first SPDP DATA(p) to 239.255.0.1:7400 after start",
    "data-p-directed": "Cyclone's directed DATA(p) reply (INFO_DST = swarmd's prefix)",
    "data-p-ud-multicast": "Cyclone's DATA(p[UD]) to 239.255.0.1:7400 on participant delete",
    "data-p-ud-unicast": "Cyclone's DATA(p[UD]) to swarmd's metatraffic unicast locator",
}


Accept = Callable[[bytes, tuple[str, int]], tuple[bytes, tuple[str, int]] | None]


def _first_from(prefix: GuidPrefix, want: str, directed_to: GuidPrefix | None = None) -> Accept:
    """Accept the first datagram from ``prefix`` with a ``want`` ("alive"/"disposed") sample."""

    def accept(data: bytes, source: tuple[str, int]) -> tuple[bytes, tuple[str, int]] | None:
        try:
            header, samples = decode_spdp(data)
        except DecodeError:
            return data, source  # keep it: the golden test will show what swarmd rejects
        if header.guid_prefix != prefix:
            return None
        for s in samples:
            kind = "alive" if isinstance(s, SpdpAlive) else "disposed"
            if kind == want and s.destination == directed_to:
                return data, source
        return None

    return accept


def _tshark() -> str:
    exe = tshark_path()
    if exe is None:
        raise SystemExit("capture: tshark is not installed (apt-get install tshark)")
    return exe


def tshark_version() -> str:
    exe = _tshark()
    out = subprocess.run([exe, "--version"], capture_output=True, text=True, check=True).stdout  # noqa: S603
    match = re.search(r"TShark \(Wireshark\) (\S+)", out)
    return match.group(1) if match else out.splitlines()[0]


def tshark_summary(pcap: Path) -> tuple[str, str]:
    """(summary line "src → dst RTPS len Info", Info column) of the pcap's one frame."""
    fields = ["ip.src", "ip.dst", "_ws.col.Protocol", "frame.len", "_ws.col.Info"]
    argv = [_tshark(), "-n", "-r", str(pcap), "-T", "fields", "-E", "separator=/t"]
    for f in fields:
        argv += ["-e", f]
    out = subprocess.run(argv, capture_output=True, text=True, check=True).stdout  # noqa: S603
    src, dst, proto, length, info = out.rstrip("\n").split("\t")
    return f"{src} \N{RIGHTWARDS ARROW} {dst} {proto} {length} {info}", info


def record_replies(sock: socket.socket, prefix: GuidPrefix, since: float, window: float) -> None:
    """Print when each further directed DATA(p) from ``prefix`` arrives (docs/interop.md)."""
    accept = _first_from(prefix, "alive", directed_to=OUR_PREFIX)
    arrivals = []
    while (remaining := since + window - time.monotonic()) > 0:
        if receive_until(sock, accept, remaining) is not None:
            arrivals.append(f"+{time.monotonic() - since:.3f}s")
    print(f"directed replies after the first, within {window:.1f} s: {', '.join(arrivals)}")


def capture(
    workdir: Path, reply_window: float
) -> tuple[dict[str, Datagram], CyclonePeer, dict[str, str]]:
    packets: dict[str, Datagram] = {}
    group = (SPDP_MULTICAST_GROUP, spdp_multicast_port(0))
    with Lan(2, subnet=SUBNET) as lan:
        cyclone_ns, our_ns = lan[0], lan[1]
        with (
            closing(group_listener(our_ns)) as listener,
            closing(unicast_socket(our_ns, META_PORT)) as sock,
        ):
            cyclone = CyclonePeer(cyclone_ns, workdir / "cyclone.trace").start()
            try:
                got = receive_until(listener, _first_from(cyclone.prefix, "alive"), WAIT_S)
                if got is None:
                    raise SystemExit("capture: no DATA(p) from Cyclone on the group")
                packets["data-p-multicast"] = Datagram(got[0], got[1], group)

                ours = SpdpParticipant(
                    OUR_PREFIX,
                    metatraffic_unicast_locators=(Locator.udpv4(our_ns.address, META_PORT),),
                    default_unicast_locators=(Locator.udpv4(our_ns.address, META_PORT + 1),),
                    lease_duration=Duration(20),
                    builtin_endpoints=BES_SPDP_ONLY,
                    entity_name="capture/swarmd",
                )
                sent_at = time.monotonic()
                sock.sendto(
                    encode_spdp(
                        ours, sequence_number=1, timestamp=Duration.from_seconds(time.time())
                    ),
                    group,
                )
                got = receive_until(
                    sock, _first_from(cyclone.prefix, "alive", directed_to=OUR_PREFIX), WAIT_S
                )
                if got is None:
                    raise SystemExit("capture: no directed DATA(p) reply from Cyclone")
                packets["data-p-directed"] = Datagram(got[0], got[1], (our_ns.address, META_PORT))
                print(f"first directed reply: +{time.monotonic() - sent_at:.3f}s after our DATA(p)")
                if reply_window > 0:
                    record_replies(sock, cyclone.prefix, sent_at, reply_window)
                own = cyclone.trace.wait_for(
                    own_participant_pattern(cyclone.prefix), WAIT_S, "own PARTICIPANT line"
                )
            finally:
                cyclone.stop()
            for name, s, dst in (
                ("data-p-ud-multicast", listener, group),
                ("data-p-ud-unicast", sock, (our_ns.address, META_PORT)),
            ):
                got = receive_until(s, _first_from(cyclone.prefix, "disposed"), WAIT_S)
                if got is None:
                    raise SystemExit(f"capture: no {name} from Cyclone")
                packets[name] = Datagram(got[0], got[1], dst)
    lease_ns = re.search(r"liveliness=\d+:(\d+)", own["qos"])
    pid = re.search(r'"__Pid":"(\d+)"', own["qos"])
    trace = {
        "participant": f"{cyclone.prefix}:1c1",
        "lease_ns": lease_ns.group(1) if lease_ns else "",
        "pid": pid.group(1) if pid else "",
    }
    return packets, cyclone, trace


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    parser.add_argument("--out", type=Path, default=REPO / "tests" / "fixtures" / "cyclone-live")
    parser.add_argument(
        "--reply-window",
        type=float,
        default=0.0,
        help="also print arrival times of Cyclone's directed replies for this many seconds",
    )
    args = parser.parse_args(argv)
    reason = unavailable_reason()
    if reason is not None:
        print(f"capture: {reason}", file=sys.stderr)
        return 2
    if tshark_path() is None:
        print("capture: tshark is not installed (apt-get install tshark)", file=sys.stderr)
        return 2
    args.out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="swarmd-capture-") as tmp:
        workdir = Path(tmp)
        packets, cyclone, trace = capture(workdir, args.reply_window)
        ts_version = tshark_version()
        for name, dgram in packets.items():
            pcap = workdir / f"{name}.pcap"
            write_pcap(pcap, [dgram])
            (tree,) = dissect_tree(pcap)
            samples = spdp_view(tree)
            summary, info = tshark_summary(pcap)
            version, vendor = (
                int(tree.header["rtps.version"][0], 16),
                int(tree.header["rtps.vendorId"][0], 16),
            )
            header = {
                "protocol_version": f"{version >> 8}.{version & 0xFF}",
                "vendor_id": f"{vendor >> 8:02x}.{vendor & 0xFF:02x}",
                "guid_prefix": tree.header["rtps.guidPrefix.src"][0].replace(":", ""),
            }
            # the trace and the wire must agree before anything is written
            if header["guid_prefix"] != cyclone.prefix.hex():
                raise SystemExit(f"capture: {name} is from {header['guid_prefix']}, not Cyclone")
            sidecar = {
                "file": f"{name}.bin",
                "description": DESCRIPTIONS[name],
                "captured_with": "scripts/capture_cyclone_fixtures.py",
                "cyclonedds_version": cyclone.version,
                "tshark_version": ts_version,
                "length": len(dgram.payload),
                "udp": {
                    "source": f"{dgram.source[0]}:{dgram.source[1]}",
                    "destination": f"{dgram.destination[0]}:{dgram.destination[1]}",
                },
                "tshark_summary": summary,
                "tshark_info": info,
                "header": header,
                "samples": samples,
                "cyclone_trace": trace,
            }
            (args.out / f"{name}.bin").write_bytes(dgram.payload)
            (args.out / f"{name}.json").write_text(
                json.dumps(sidecar, indent=2, ensure_ascii=False) + "\n"
            )
            kinds = ", ".join(str(s["kind"]) for s in samples)
            print(f"{name}: {len(dgram.payload)} B, {sidecar['tshark_summary']} [{kinds}]")
    return 0


if __name__ == "__main__":
    sys.exit(main())
