"""What a contender puts on the air, frame by frame, on a wired twin of the testbed.

``python -m bench.wifi.frames --n 10 --window 40`` (root; docs/testbed.md, "What swarmd's
frames are"). The ns-3 channel counts frames per class and second; it cannot say *which*
frames they are. This tool runs the same contender (``bench.wifi.contenders``: the bench's
bundle, configs, start barrier) in N namespaces with the testbed's addresses, MACs and
sysctls (IPv6 off, rp_filter 0), joined by one Linux bridge instead of ns-3, and captures
every frame each drone sends (``dumpcap`` on the bridge port facing it, filtered on the
drone's source MAC). On the testbed's channel each such frame is one PHY transmission, and
each unicast one is answered by an 802.11 ACK, which ``channel_cpp.py`` counts in the class
of the frame it acknowledges (``metrics.class_series``); retries are the channel's own and
not modelled here (``retx_ratio`` in the run JSON: 0.17 % for swarmd at N = 10).

It prints, per second after the release, the frames by the channel's classes (``rtps_
discovery``, ``rtps_user``, ``zenoh``, ``other``; RTPS split by the writer/reader entity
kind, as ``RtpsClass`` does; zenoh as TCP or UDP 7446/7447), the ACKs the channel would
add, then what the frames are: RTPS by (sender -> receiver, submessage ids) and the rest by
kind (ARP request broadcast/unicast, ARP reply, IGMP report, ...). Kernel timers run
undilated here (the dilated testbed scales the neighbour timers by k, so ARP timing in
experiment seconds is the same; IGMP's retransmission delay, up to 1 s real, is not scaled
there).

Lab tooling: it does I/O and needs root; nothing in ``swarmd/`` imports it. Run it under
``nice -n 19``: the daemons keep the priority they inherit (the bench raises them to 0 at
the release; a wired bridge needs no real-time fairness).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from collections import Counter, defaultdict
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Final

from swarmd_lab.netns import Namespace, NamespaceRecord, add_veth, configure_host

from bench.docblock import head_commit
from bench.wifi import contenders as contenders_mod
from bench.wifi.barrier import StartBarrier
from bench.wifi.topology import _ip, _sysctls, ns3_mac

BASE: Final = "swfr"  # namespaces <BASE>-<pid>-*; distinct from the testbed's "swf"
BRIDGE: Final = "br0"
BARRIER_TIMEOUT_S: Final = 180.0
SUBMESSAGE_NAMES: Final = {
    0x06: "ACKNACK",
    0x07: "HEARTBEAT",
    0x08: "GAP",
    0x09: "INFO_TS",
    0x0E: "INFO_DST",
    0x12: "NACK_FRAG",
    0x13: "HEARTBEAT_FRAG",
    0x15: "DATA",
    0x16: "DATA_FRAG",
}


@dataclass(frozen=True)
class Frame:
    """One frame a drone sent, as the capture saw it."""

    t: float  # wall time
    src: int  # drone index
    dst: str  # drone name, "bcast" or a multicast group
    unicast: bool
    cls: str  # the channel's class: rtps_discovery, rtps_user, other
    what: str  # e.g. "DATA+0x80", "ARP request", "IGMPv3 report"


def rtps_class(payload: bytes, dport: int) -> tuple[str, str]:
    """(channel class, submessage ids) of an RTPS datagram, by ``RtpsClass``'s rule."""
    off = 20
    ids: list[str] = []
    cls = ""
    while off + 4 <= len(payload):
        sm = payload[off]
        le = payload[off + 1] & 1
        size = int.from_bytes(payload[off + 2 : off + 4], "little" if le else "big")
        ids.append(SUBMESSAGE_NAMES.get(sm, f"0x{sm:02X}"))
        writer_at = 8 if sm in (0x15, 0x16) else 4 if sm in (6, 7, 8, 0x12, 0x13) else -1
        if not cls and writer_at >= 0 and off + 4 + writer_at + 4 <= len(payload):
            kind = payload[off + 4 + writer_at + 3]
            cls = "rtps_discovery" if kind & 0xC0 == 0xC0 else "rtps_user"
        if size == 0:
            break
        off += 4 + size
    if not cls:
        port = (dport - 7400) % 250
        metatraffic = dport >= 7400 and (port == 0 or (port >= 10 and port % 2 == 0))
        cls = "rtps_discovery" if metatraffic else "rtps_user"
    return cls, "+".join(ids)


def parse_capture(pcap: Path, macs: Sequence[str]) -> list[Frame]:
    """Every frame of ``pcap`` sent by one of the drones (by source MAC)."""
    fields = [
        "frame.time_epoch",
        "eth.src",
        "eth.dst",
        "eth.type",
        "arp.opcode",
        "ip.proto",
        "ip.dst",
        "igmp.version",
        "udp.dstport",
        "udp.srcport",
        "udp.payload",
    ]
    argv = ["tshark", "-r", str(pcap), "-n", "-T", "fields", "-E", "separator=\t"]
    for f in fields:
        argv += ["-e", f]
    out = subprocess.run(argv, capture_output=True, text=True, check=True, timeout=300).stdout
    index = {m.lower(): i for i, m in enumerate(macs)}
    frames = []
    for line in out.splitlines():
        t, src, dst, etype, arp, proto, ipdst, igmp, dport, sport, payload = (
            line.split("\t") + [""] * 11
        )[:11]
        if src.lower() not in index:
            continue
        unicast = not int(dst.split(":")[0], 16) & 1
        to = f"uav{index[dst.lower()] + 1}" if dst.lower() in index else "bcast"
        if not unicast and ipdst:
            to = ipdst
        cls, what = "other", f"ethertype {etype}"
        if arp:
            what = "ARP request" if arp == "1" else "ARP reply"
        elif proto == "6" or (proto == "17" and {dport, sport} & {"7446", "7447"}):
            cls, what = "zenoh", "TCP" if proto == "6" else f"UDP to {ipdst}:{dport}"
        elif proto == "2":
            what = f"IGMPv{igmp or '?'} report to {ipdst}"
        elif proto == "17" and payload:
            data = bytes.fromhex(payload.replace(":", ""))
            if data[:4] == b"RTPS" and len(data) >= 20:
                cls, what = rtps_class(data, int(dport))
            else:
                what = f"UDP to {ipdst}:{dport}"
        elif proto:
            what = f"IP proto {proto} to {ipdst}"
        frames.append(Frame(float(t), index[src.lower()], to, unicast, cls, what))
    return frames


def report(frames: Iterable[Frame], launch: float, window_s: int, steady_from: int) -> str:
    """The per-second table and the breakdown (see the module docstring)."""
    classes = ("rtps_discovery", "rtps_user", "zenoh", "other")
    per_s: dict[int, Counter[str]] = defaultdict(Counter)
    kinds: dict[str, Counter[str]] = defaultdict(Counter)  # second bucket -> what
    pairs: Counter[str] = Counter()
    steady_s = max(1, window_s - steady_from)
    for f in frames:
        s = int(f.t - launch)
        if not 0 <= s < window_s:
            continue
        per_s[s][f.cls] += 1
        if f.unicast:
            per_s[s][f"{f.cls}_ack"] += 1
        bucket = str(s) if s < steady_from else f"{steady_from}..{window_s - 1}"
        kinds[bucket][f"{f.cls}: {f.what}{' (unicast)' if f.unicast else ''}"] += 1
        if s >= steady_from:
            pairs[f"{f.cls}: uav{f.src + 1} -> {f.dst} {f.what}"] += 1
    lines = ["second  " + "  ".join(f"{c}(+ACK)" for c in classes) + "  channel_total"]
    for s in range(window_s):
        c = per_s[s]
        cells = [f"{c[k]:>{len(k) - 2}}+{c[k + '_ack']:<3}" for k in classes]
        total = sum(c[k] + c[k + "_ack"] for k in classes)
        lines.append(f"{s:>6}  " + "  ".join(cells) + f"  {total:>5}")
    lines.append("")
    for bucket in sorted(kinds, key=lambda b: int(b.split(".")[0])):
        lines.append(f"second {bucket}:")
        for what, n in sorted(kinds[bucket].items()):
            lines.append(f"  {n:>5}  {what}")
    lines.append("")
    lines.append(f"seconds {steady_from}..{window_s - 1}, per sender and kind (frames/s):")
    for what, n in sorted(pairs.items()):
        lines.append(f"  {n / steady_s:7.2f}  {what}")
    return "\n".join(lines)


def run(n: int, window_s: int, contender: str, keep: Path | None) -> tuple[list[Frame], float]:
    """Build the wired twin, run ``contender`` for ``window_s`` s, return (frames, launch)."""
    prefix = f"{BASE}-{os.getpid()}-1"
    hub = f"{prefix}-hub"
    record = NamespaceRecord()
    drones: list[Namespace] = []
    addresses = [f"10.78.0.{i + 1}" for i in range(n)]
    no_v6 = [("net.ipv6.conf.all.disable_ipv6", "1"), ("net.ipv6.conf.default.disable_ipv6", "1")]
    dump: subprocess.Popen[bytes] | None = None
    try:
        record.add(hub)
        _sysctls(hub, no_v6)
        _ip("-n", hub, "link", "add", BRIDGE, "type", "bridge", "mcast_snooping", "0")
        _ip("-n", hub, "link", "set", BRIDGE, "up")
        for i in range(n):
            name = f"{prefix}-{i}"
            record.add(name)
            rp = [("net.ipv4.conf.all.rp_filter", "0"), ("net.ipv4.conf.default.rp_filter", "0")]
            _sysctls(name, [*no_v6, *rp])
            add_veth(hub, f"v{i}", name)
            _ip("-n", name, "link", "set", "eth0", "address", ns3_mac(i))
            _ip("-n", hub, "link", "set", f"v{i}", "master", BRIDGE)
            _ip("-n", hub, "link", "set", f"v{i}", "up")
            configure_host(name, f"{addresses[i]}/24")
            drones.append(Namespace(name, addresses[i], 24))
        with tempfile.TemporaryDirectory(prefix="swfr-") as tmp:
            work = Path(tmp)
            links = work / "links"
            links.mkdir()
            for i in range(n):  # what the channel writes before a node hears anyone
                (links / f"link-{i}.json").write_text(
                    json.dumps({"signal_dbm": -50.0, "noise_dbm": -94.0, "snr_db": 44.0})
                )
            pcap = work / "frames.pcapng"
            argv = ["ip", "netns", "exec", hub, "dumpcap", "-q", "-w", str(pcap)]
            for i in range(n):  # each frame once: on the port of the drone that sent it
                argv += ["-i", f"v{i}", "-f", f"ether src {ns3_mac(i)}"]
            dump = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
            c = contenders_mod.make(
                contender, drones, work, window_s=window_s, messages=window_s, link_dir=links
            )
            try:
                with StartBarrier(work / "barrier.sock") as barrier:
                    c.start(barrier.path)
                    barrier.wait_all(c.procs, BARRIER_TIMEOUT_S)
                    time.sleep(2.0)  # dumpcap listens on every port by now
                    launch = time.time()
                    barrier.release()
                while time.time() < launch + window_s + 1.0:
                    c.poll(time.time())
                    time.sleep(0.5)
                obs = c.finish()
                print(f"readiness at the commander: {obs.received}", file=sys.stderr)
            finally:
                for d in drones:
                    d.stop_children()
                c.close()
            dump.terminate()
            dump.wait(timeout=30)
            if keep is not None:
                keep.write_bytes(pcap.read_bytes())
            return parse_capture(pcap, [ns3_mac(i) for i in range(n)]), launch
    finally:
        if dump is not None and dump.poll() is None:
            dump.kill()
        for d in drones:
            d.stop_children()
        record.close()


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--n", type=int, default=10)
    p.add_argument("--window", type=int, default=40, help="seconds captured after release")
    p.add_argument("--steady-from", type=int, default=2, help="first steady-state second")
    p.add_argument("--contender", default="swarmd", choices=contenders_mod.CONTENDERS)
    p.add_argument("--keep", type=Path, help="write the capture (pcapng) here")
    a = p.parse_args(argv)
    if not 2 <= a.n <= 250 or a.window < 3:
        p.error("--n 2..250, --window >= 3")
    head = head_commit()
    frames, launch = run(a.n, a.window, a.contender, a.keep)
    args = " ".join(sys.argv[1:] if argv is None else argv)
    print(f"# python -m bench.wifi.frames {args}  (commit {head})")
    print(report(frames, launch, a.window, a.steady_from))
    return 0


if __name__ == "__main__":
    sys.exit(main())
