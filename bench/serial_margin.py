"""Is a UART to PX4 inside the fresh-state margin (docs/px4.md, "Fresh state")?

    .venv/bin/python bench/serial_margin.py [BAUD ...]     (default: 57600 921600)

Only a message received one ack timeout (``SenderConfig.ack_timeout_s``, 0.5 s) after a
command's first send may confirm it, on the assumption that by then PX4 has received the
command, acted on it, and sent that message after. On a UART that is: our command's
transfer up, PX4's handling, then the wait of PX4's message down behind what PX4 queued
before it. Frame sizes are what swarmd's codec writes (MAVLink 2, signed: 13 B of
signature); the rest is arithmetic from PX4's source, cited beside each constant. A
reading, not a test: nothing asserted.
"""

from __future__ import annotations

import sys
from typing import Final

from swarmd.px4.command_sender import SenderConfig
from swarmd.px4.constants import MavCmd, MavResult, MavState
from swarmd.px4.mavlink_codec import MavlinkCodec
from swarmd.px4.messages import MODE_LOITER, CommandAck, Heartbeat, VehicleCommand

BITS_PER_BYTE: Final = 10  # 8N1: start, 8 data, stop
MAX_FRAME_B: Final = 280  # MAVLink 2's longest frame, signature included (mavlink.io)
# PX4 mavlink_main.cpp: with MAV_X_RATE = 0 "use 1/2 of bandwidth by default"
# (_datarate = _baudrate / 20, bytes/s); its main loop runs at least at 100 Hz
PX4_SHARE: Final = 0.5
PX4_LOOP_S: Final = 0.010
# commander's cycle, which turns a vehicle_command into vehicle_status, and the mavlink
# loop that next reads it: one period each (Commander::run, mavlink_main.cpp)
PX4_HANDLING_S: Final = 0.010 + PX4_LOOP_S


def frame_sizes() -> dict[str, int]:
    ours = MavlinkCodec(1, 191, signing_key=bytes(range(32)))
    px4 = MavlinkCodec(1, 1, signing_key=bytes(range(32)))
    arm = VehicleCommand.make(MavCmd.COMPONENT_ARM_DISARM, p1=1.0)
    heartbeat = Heartbeat(12, 2, 1 | 128, MODE_LOITER.custom_mode, MavState.ACTIVE)
    return {
        "COMMAND_LONG (ARM)": len(ours.encode(arm)),
        "COMMAND_ACK": len(px4.encode(CommandAck(400, MavResult.ACCEPTED, 0, 1, 191))),
        "HEARTBEAT": len(px4.encode(heartbeat)),
    }


def main() -> None:
    bauds = [int(a) for a in sys.argv[1:]] or [57600, 921600]
    margin = SenderConfig().ack_timeout_s
    sizes = frame_sizes()
    print("frames (signed):", ", ".join(f"{k} {v} B" for k, v in sizes.items()))
    cmd = sizes["COMMAND_LONG (ARM)"]
    for baud in bauds:
        link = baud / BITS_PER_BYTE  # bytes/s each way
        up = 2 * cmd / link  # one of our frames in progress, then the command
        # PX4 at its default rate: one loop's share queued ahead, plus one longest frame
        # in progress, then the heartbeat itself
        queued = link * PX4_SHARE * PX4_LOOP_S + MAX_FRAME_B + sizes["HEARTBEAT"]
        down = queued / link
        total = up + PX4_HANDLING_S + down
        # PX4 asked for more than the link carries (MAV_X_RATE above baud/10, streams raised
        # by SET_MESSAGE_INTERVAL): its UART buffer stays full; this much queued uses the
        # whole margin
        full = (margin - up - PX4_HANDLING_S) * link
        print(
            f"{baud} baud: {link:.0f} B/s; command up {up * 1e3:.1f} ms, PX4 "
            f"{PX4_HANDLING_S * 1e3:.0f} ms, heartbeat down {down * 1e3:.1f} ms "
            f"(PX4 at MAV_X_RATE=0: {link * PX4_SHARE:.0f} B/s) = {total * 1e3:.0f} ms of "
            f"{margin * 1e3:.0f} ms; overloaded, a TX queue of {full:.0f} B spends it all"
        )


if __name__ == "__main__":
    main()
