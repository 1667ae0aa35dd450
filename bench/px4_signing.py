"""MAVLink 2 signing on the PX4 link (issue 10, attack 6): bytes per frame with and without
the 13-byte signature, and CPU per signed frame sent and per frame received (decode alone,
decode + signature check) through swarmd's codec. Prints markdown.

    .venv/bin/python bench/px4_signing.py [--repeat 7] [--calls 2000]

Timings: ``--repeat`` runs of ``--calls`` calls, microseconds per call, the median and the
spread (min..max). The Jetson Nano column scales by ``bench.auth.NANO_FACTOR`` (its basis is
stated there; SHA-256 is a small share of these figures). Not measured on a Nano.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from bench.auth import NANO_FACTOR, timed  # noqa: E402
from bench.bundle import machine  # noqa: E402
from swarmd.px4.constants import COMP_ID_AUTOPILOT1, COMP_ID_ONBOARD_COMPUTER  # noqa: E402
from swarmd.px4.mavlink_codec import MavlinkCodec, Message  # noqa: E402
from swarmd.px4.messages import (  # noqa: E402
    GlobalPositionInt,
    Heartbeat,
    SysStatus,
    VehicleCommand,
)
from swarmd.px4.signing import derive_key, timestamp_from_unix  # noqa: E402

KEY = derive_key(bytes(range(32)), "bench", "uav1")
T0 = timestamp_from_unix(1_800_000_000.0)
MESSAGES: dict[str, Message] = {
    "HEARTBEAT": Heartbeat(
        autopilot=12, vehicle_type=2, base_mode=129, custom_mode=0x03040000, system_status=3
    ),
    "SYS_STATUS": SysStatus(
        sensors_health=0x9020_002F, battery_remaining=90, voltage_battery_mv=16_200
    ),
    "GLOBAL_POSITION_INT": GlobalPositionInt(
        lat_e7=473_977_420, lon_e7=85_455_940, alt_mm=488_000, relative_alt_mm=0
    ),
    "COMMAND_LONG (ARM)": VehicleCommand.make(400, p1=1.0),
}


def codec(key: bytes | None, component: int) -> MavlinkCodec:
    c = MavlinkCodec(1, component, signing_key=key)
    c.advance_clock(T0)
    return c


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=7)
    parser.add_argument("--calls", type=int, default=2000)
    args = parser.parse_args()

    print("## Bytes per frame\n\n| message | unsigned | signed | + |\n|---|---:|---:|---:|")
    for name, msg in MESSAGES.items():
        plain = len(codec(None, COMP_ID_AUTOPILOT1).encode(msg))
        signed = len(codec(KEY, COMP_ID_AUTOPILOT1).encode(msg))
        print(f"| {name} | {plain} | {signed} | {signed - plain} |")

    hb = MESSAGES["HEARTBEAT"]
    assert isinstance(hb, Heartbeat)
    tx_plain, tx_signed = (
        codec(None, COMP_ID_ONBOARD_COMPUTER),
        codec(KEY, COMP_ID_ONBOARD_COMPUTER),
    )
    ap = codec(KEY, COMP_ID_AUTOPILOT1)
    frames = [ap.encode(hb) for _ in range(args.calls * args.repeat + 1)]
    plain_frame = codec(None, COMP_ID_AUTOPILOT1).encode(hb)
    rx_plain = codec(None, COMP_ID_ONBOARD_COMPUTER)
    rx_signed = codec(KEY, COMP_ID_ONBOARD_COMPUTER)
    it = iter(frames)  # each signed frame once: a replayed one would be refused early

    cases = {
        "encode HEARTBEAT, unsigned": lambda: tx_plain.encode(hb),
        "encode HEARTBEAT, signed": lambda: tx_signed.encode(hb),
        "receive HEARTBEAT (decode), unsigned": lambda: rx_plain.feed(plain_frame, datagram=True),
        "receive HEARTBEAT (verify + decode), signed": lambda: rx_signed.feed(
            next(it), datagram=True
        ),
        "refuse an unsigned HEARTBEAT (signing on)": lambda: rx_signed.feed(
            plain_frame, datagram=True
        ),
    }
    low, high = NANO_FACTOR
    print("\n## CPU per frame\n")
    print("| operation | here, µs (min..max) | Jetson Nano estimate, µs |\n|---|---:|---:|")
    for name, fn in cases.items():
        med, lo, hi = timed(fn, args.calls, args.repeat)
        print(f"| {name} | {med:.1f} ({lo:.1f}..{hi:.1f}) | {med * low:.0f}..{med * high:.0f} |")
    assert rx_signed.signing_counts is not None
    print(f"\nverifier counts: {rx_signed.signing_counts}")
    print(f"\n```\n{machine()}\n```")
    return 0


if __name__ == "__main__":
    sys.exit(main())
