"""The MAVLink backend: pymavlink's codec on an asyncio byte link (UDP or UART).

Identity (reference 1.1): we are component 191 (MAV_COMP_ID_ONBOARD_COMPUTER) of the
vehicle's own system id, and send HEARTBEAT at 1 Hz as MAV_TYPE_ONBOARD_CONTROLLER /
MAV_AUTOPILOT_INVALID / MAV_STATE_ACTIVE from the event loop that does the work, so a wedged
loop stops the heartbeat (MAVLink heartbeat service advice). Only messages from the
autopilot, (sysid, component 1), reach the logic; ACKs must be addressed to us or broadcast
(``mavlink_intake``, which also tells a rebooted PX4 by its boot clock: ``boot_watch``).
Commands always target component 1 explicitly (``mavutil`` sometimes derives 0).

Trust (issue 10, attack 6): on UDP only the autopilot's pinned address is heard and
answered (``linkguard.AutopilotPin``: configured, or the first HEARTBEAT from (sysid, 1));
with a signing key (``signing.py``) every frame we send is signed and every frame we
accept must carry a good MAVLink 2 signature on a fresh timestamp. Everything refused is
counted in ``stats()`` (``swarmctl status --json``, ``px4.backend``).

Like MAVSDK (telemetry_impl ``request_home_position_again``), while no HOME_POSITION has
arrived we ask for one with MAV_CMD_REQUEST_MESSAGE every 2 s instead of waiting up to 2 s
for PX4's 0.5 Hz stream; the ACK of that request is not passed on.
"""

from __future__ import annotations

import asyncio
import socket
import time
from typing import Any, Final

from swarmd.px4.backend import ObservationSink
from swarmd.px4.constants import (
    COMP_ID_AUTOPILOT1,
    COMP_ID_ONBOARD_COMPUTER,
    MAV_AUTOPILOT_INVALID,
    MAV_TYPE_ONBOARD_CONTROLLER,
    MSG_ID_HOME_POSITION,
    MavCmd,
    MavState,
)
from swarmd.px4.linkguard import REPIN_AFTER_S, AutopilotPin
from swarmd.px4.mavlink_codec import MavlinkCodec
from swarmd.px4.mavlink_intake import MavlinkIntake
from swarmd.px4.messages import Heartbeat, VehicleCommand
from swarmd.px4.signing import timestamp_from_unix
from swarmd.px4.transport import (
    ByteLink,
    Endpoint,
    UdpLink,
    open_link,
    parse_address,
    parse_connection,
)

HEARTBEAT_INTERVAL_S: Final = 1.0  # MAVSDK HEARTBEAT_SEND_INTERVAL_S
HOME_REQUEST_EVERY: Final = 2  # heartbeats between HOME_POSITION requests (2 s)


class MavlinkBackend:
    """``VehicleBackend`` over MAVLink 2 for vehicle ``sysid``."""

    name = "mavlink"

    def __init__(
        self,
        connection: str | Endpoint,
        *,
        sysid: int = 1,
        compid: int = COMP_ID_ONBOARD_COMPUTER,
        heartbeat_interval_s: float = HEARTBEAT_INTERVAL_S,
        autopilot: str | None = None,
        signing_key: bytes | None = None,
        repin_after_s: float = REPIN_AFTER_S,
        inherited: socket.socket | None = None,
    ) -> None:
        if not 1 <= sysid <= 255 or not 1 <= compid <= 255:
            raise ValueError("px4.sysid and the companion component id must be 1..255")
        self.endpoint = parse_connection(connection) if isinstance(connection, str) else connection
        self.sysid = sysid
        self.compid = compid
        self.heartbeat_interval_s = heartbeat_interval_s
        self.codec = MavlinkCodec(sysid, compid, signing_key=signing_key)
        self.pin: AutopilotPin | None = None  # UDP only: a UART has one peer by wiring
        if self.endpoint.kind == "udpout":
            target = f"{self.endpoint.host}:{self.endpoint.port}"
            if autopilot is not None and parse_address(autopilot, "px4.autopilot") != target:
                raise ValueError(
                    f"px4.autopilot {autopilot} differs from the udpout target {target}; "
                    "fix: drop px4.autopilot (udpout already pins its target)"
                )
            self.pin = AutopilotPin(configured=target)
        elif self.endpoint.kind == "udpin":
            fixed = None if autopilot is None else parse_address(autopilot, "px4.autopilot")
            self.pin = AutopilotPin(configured=fixed, repin_after_s=repin_after_s)
        # udpin: the socket systemd bound for us (swarmd-px4.socket), else bound at start()
        self._inherited = inherited if self.endpoint.kind == "udpin" else None
        datagrams = self.endpoint.kind != "serial"  # UDP: frames never span datagrams
        self._link: ByteLink | None = None
        self._sink: ObservationSink | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._hb_timer: asyncio.TimerHandle | None = None
        self._hb_count = 0
        # the autopilot's frames judged (pin, signature, sender, PX4's boot clock)
        self.intake = MavlinkIntake(
            self.codec, sysid=sysid, compid=compid, pin=self.pin, datagrams=datagrams
        )
        self.commands_sent = 0
        self.heartbeats_sent = 0

    async def start(self, sink: ObservationSink) -> None:
        self._loop = asyncio.get_running_loop()
        self._sink = sink
        self._link = await open_link(self.endpoint, self._on_bytes, inherited=self._inherited)
        self._sync_remote()
        self._heartbeat()

    @property
    def link(self) -> ByteLink | None:
        return self._link

    def send(self, command: VehicleCommand) -> None:
        cmd = VehicleCommand(
            command.command,
            command.params,
            command.confirmation,
            self.sysid,
            COMP_ID_AUTOPILOT1,  # always explicit (reference 1.5)
        )
        self._write(self._encode(cmd))
        self.commands_sent += 1

    def stats(self) -> dict[str, Any]:
        return {
            "backend": self.name,
            "connection": str(self.endpoint),
            "sysid": self.sysid,
            "compid": self.compid,
            "decoded": self.codec.decoded,
            "bad_frames": self.codec.bad_frames,
            "ignored": self.codec.ignored,
            "foreign": self.intake.foreign,
            # PX4 lives told apart by its boot clock (docs/px4.md, "Fresh state")
            "boot_clock": self.intake.boot.stats(),
            "heartbeats_sent": self.heartbeats_sent,
            "commands_sent": self.commands_sent,
            "link": None if self._link is None else self._link.stats(),
            # refused for who sent it (pinning) and for how it was signed (signing)
            "autopilot": None if self.pin is None else {**self.pin.stats(), **self.pin.counts},
            "signing": self._signing_stats(),
        }

    def _signing_stats(self) -> dict[str, object]:
        # named like every other refusal counter ("dropped_..."): scripts sum them
        counts = self.codec.signing_counts or {}
        out: dict[str, object] = {"enabled": self.codec.signing, "ok": counts.get("ok", 0)}
        for verdict in ("unsigned", "bad_signature", "replayed"):
            out[f"dropped_{verdict}"] = counts.get(verdict, 0)
        return out

    async def close(self) -> None:
        if self._hb_timer is not None:
            self._hb_timer.cancel()
            self._hb_timer = None
        if self._link is not None:
            self._link.close()
            self._link = None

    # ---- internals ----------------------------------------------------------------------

    def _write(self, data: bytes) -> None:
        if self._link is not None:
            self._link.send(data)

    def _encode(self, msg: Heartbeat | VehicleCommand) -> bytes:
        # the signing clock follows the wall clock (spec "Timestamp handling"); the codec
        # is pure, so the time is read here
        self.codec.advance_clock(timestamp_from_unix(time.time()))
        return self.codec.encode(msg)

    def _sync_remote(self) -> None:
        if isinstance(self._link, UdpLink) and self.pin is not None:
            self._link.set_remote(self.pin.address)

    def _heartbeat(self) -> None:
        if self._loop is None:
            return
        hb = Heartbeat(
            autopilot=MAV_AUTOPILOT_INVALID,
            vehicle_type=MAV_TYPE_ONBOARD_CONTROLLER,
            base_mode=0,
            custom_mode=0,
            system_status=MavState.ACTIVE,
        )
        self._write(self._encode(hb))
        self.heartbeats_sent += 1
        self._hb_count += 1
        want_home = self.intake.seen_autopilot and not self.intake.have_home
        if want_home and self._hb_count % HOME_REQUEST_EVERY == 1:
            self.send(VehicleCommand.make(MavCmd.REQUEST_MESSAGE, p1=MSG_ID_HOME_POSITION))
        # fixed grid: a slow callback does not drift the 1 Hz schedule
        when = (self._hb_timer.when() if self._hb_timer is not None else self._loop.time()) + (
            self.heartbeat_interval_s
        )
        self._hb_timer = self._loop.call_at(max(when, self._loop.time()), self._heartbeat)

    def _on_bytes(self, data: bytes, source: str | None) -> None:
        if self._loop is None or self._sink is None:
            return  # not started
        now = self._loop.time()
        if self.codec.signing:
            self.codec.advance_clock(timestamp_from_unix(time.time()))
        was = None if self.pin is None else self.pin.address
        observations = self.intake.receive(data, source, now)
        if self.pin is not None and self.pin.address != was:
            self._sync_remote()  # replies go to the new pin, and only there, before any
        for obs in observations:
            self._sink(obs, now)
