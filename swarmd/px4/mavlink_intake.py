"""What the MAVLink backend hears from the autopilot, judged before it reaches the vehicle.

Sans-IO: ``receive(data, source, now)`` with the bytes of one datagram (or one read of the
UART) returns the observations to hand the vehicle core, in order. The checks, cheapest
first (docs/px4.md, "Trust on the PX4 link"):

1. the pinned address (UDP): another source is dropped before decoding (``AutopilotPin``);
2. the codec: CRC, and with a signing key the signature and its freshness (``signing``);
3. the sender: only (sysid, component 1), the autopilot; others are counted ``foreign``;
4. before the pin, only the pinning HEARTBEAT; commands and keys the autopilot sends to
   others, and acks addressed to others, are not for us;
5. the boot clock (``boot_watch.BootWatch``): the frames left may be a new PX4 life's.
   Then a ``StateReset`` goes first, as XRCE-DDS's new session hands one over
   (``xrce_translate``), so nothing of the last life is judged with the new one's.

Only step 5 reads frames that passed 1..4: a forged, replayed or foreign frame cannot
reset the vehicle's state. The caller reads the time for signing (``codec.advance_clock``);
this module reads no clock.
"""

from __future__ import annotations

from swarmd.px4.boot_watch import BootWatch
from swarmd.px4.constants import COMP_ID_AUTOPILOT1, MavCmd
from swarmd.px4.linkguard import AutopilotPin
from swarmd.px4.mavlink_codec import MavlinkCodec, SetupSigning
from swarmd.px4.messages import (
    BootClock,
    CommandAck,
    Heartbeat,
    HomePosition,
    Observation,
    StateReset,
    VehicleCommand,
)


class MavlinkIntake:
    """One link's received frames -> observations for vehicle ``sysid`` (module docstring)."""

    def __init__(
        self,
        codec: MavlinkCodec,
        *,
        sysid: int,
        compid: int,
        pin: AutopilotPin | None,
        datagrams: bool,
        boot_watch: BootWatch | None = None,
    ) -> None:
        self.codec = codec
        self.sysid = sysid
        self.compid = compid
        self.pin = pin  # UDP only: a UART has one peer by wiring
        self.datagrams = datagrams  # UDP: frames never span datagrams
        self.boot = boot_watch or BootWatch()
        self.foreign = 0  # well-formed messages from other systems/components
        self.seen_autopilot = False
        self.have_home = False  # the backend asks for HOME_POSITION until one arrives

    def receive(self, data: bytes, source: str | None, now: float) -> list[Observation]:
        """The observations in ``data`` from ``source`` (None: the UART), in order."""
        pin = self.pin if source is not None else None
        if pin is not None and source is not None and not pin.admit_datagram(source, now):
            return []  # not the autopilot's address: dropped before decoding, counted
        out: list[Observation] = []
        clocks: list[tuple[str, int]] = []
        trusted = 0
        for frame in self.codec.feed(data, datagram=self.datagrams):
            msg = frame.msg
            if frame.src_system != self.sysid or frame.src_component != COMP_ID_AUTOPILOT1:
                self.foreign += 1
                continue
            if pin is not None and source is not None:
                if not pin.admit_frame(source, isinstance(msg, Heartbeat), now):
                    continue  # not pinned yet and not the pinning heartbeat
            trusted += 1
            if (clock := frame.boot_clock) is not None:
                clocks.append(clock)
            if isinstance(msg, BootClock):
                continue  # read for its clock alone
            if isinstance(msg, VehicleCommand | SetupSigning):
                self.foreign += 1  # the autopilot commanding or keying someone: not for us
                continue
            if isinstance(msg, CommandAck):
                if msg.target_system not in (0, self.sysid) or msg.target_component not in (
                    0,
                    self.compid,
                ):
                    self.foreign += 1  # an answer to the GCS or another companion
                    continue
                if msg.command == MavCmd.REQUEST_MESSAGE:
                    continue  # our own home request
            out.append(msg)
        if not trusted:
            return []
        verdict = self.boot.batch(clocks, len(out), now)
        if not verdict.deliver:
            return []
        if verdict.reset is not None:
            # the new life has no home until it says so: ask again (MavlinkBackend)
            self.have_home = False
            out.insert(0, StateReset(verdict.reset))
        for msg in out:
            if isinstance(msg, Heartbeat):
                self.seen_autopilot = True
            elif isinstance(msg, HomePosition):
                self.have_home = True
        return out
