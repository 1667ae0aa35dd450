"""The PX4 stand-in over uXRCE-DDS (sans-IO): PX4's client session + the shared vehicle model.

Not PX4. ``Px4UxrceClient`` opens the session as PX4's ``uxrce_dds_client`` does; the vehicle
is ``SimVehicle``, the same model the MAVLink vehicle simulator flies (arming, COM_SPOOLUP_TIME,
the MPC_TKO_RAMP_T ramp to MPC_TKO_SPEED, the land detector's stages), so both backends take
off in the same time. Its state goes out as PX4's topics at the golden session's rates
(vehicle_gps_position 10 Hz, vehicle_status and failsafe_flags 2 Hz, battery_status,
vehicle_land_detected and timesync_status 1 Hz; vehicle_status and vehicle_land_detected also
at once on a change, as commander and the land detector publish); commands come in on
``vehicle_command`` (topic) or its service (1.15+), and their ack goes back on
``vehicle_command_ack`` and, for a request, as the service's reply.

Driving sources: ``receive_datagram(data, source, now)``, ``handle_timer(now)``. Outputs:
``datagrams_to_send()``, ``get_timer()``, ``next_log()`` (JSON-ready records).
"""

from __future__ import annotations

import random
from collections import deque
from dataclasses import dataclass
from typing import Any, Final

from swarmd.px4.constants import GpsFixType
from swarmd.px4.messages import MODE_LAND, MODE_LOITER, MODE_TAKEOFF, CommandAck, VehicleCommand
from swarmd.xrce.events import Address, SampleReceived, SessionCreated, SessionEnded
from swarmd.xrce.px4 import decode_fields, encode_fields
from swarmd.xrce.px4_layouts import LAYOUTS
from swarmd_lab.px4.sim_model import SimConfig, SimVehicle
from swarmd_lab.px4.uxrce_client import Px4UxrceClient

SAMPLE_IDENTITY_SIZE: Final = 24  # a service sample's SampleIdentity (GUID + sequence number)
PERIODS_S: Final = {  # golden session's rates
    "vehicle_gps_position": 0.1,
    "vehicle_status": 0.5,
    "failsafe_flags": 0.5,
    "battery_status": 1.0,
    "vehicle_land_detected": 1.0,
    "timesync_status": 1.0,
}
NAV_STATE: Final = {MODE_LOITER: 4, MODE_TAKEOFF: 17, MODE_LAND: 18}  # vehicle_status.nav_state
ARMING_STATE_DISARMED: Final = 1
ARMING_STATE_ARMED: Final = 2
VEHICLE_TYPE_ROTARY_WING: Final = 1
# commander's mode requirement masks (bit = nav_state): global position for Hold, Takeoff,
# Land, Mission, RTL...; home for RTL (bit 5); as PX4 1.16 fills them on a multicopter
MODE_REQ_GLOBAL_POSITION: Final = 0x0038003C
MODE_REQ_HOME_POSITION: Final = 0x20
MAX_LOG: Final = 1024


@dataclass(frozen=True, slots=True)
class StandinConfig:
    release: str = "1.16"
    key: int = 1  # UXRCE_DDS_KEY
    namespace: str | None = None  # UXRCE_DDS_NS
    localhost_only: bool = True  # UXRCE_DDS_PTCFG=1
    domain_id: int = 0  # UXRCE_DDS_DOM_ID
    vehicle: SimConfig = SimConfig()


class Px4XrceStandin:
    """PX4 over uXRCE-DDS, simulated (see the module docstring)."""

    def __init__(self, config: StandinConfig, rng: random.Random, now: float) -> None:
        self.config = config
        self.release = config.release
        self.vehicle = SimVehicle(config.vehicle, rng, now)
        self.client = Px4UxrceClient(
            config.release, config.key, boot=now - 1.0, namespace=config.namespace,
            localhost_only=config.localhost_only, domain_id=config.domain_id,
        )  # fmt: skip
        self._due = {topic: now for topic in PERIODS_S}
        self._last_status: tuple[int, int, bool] | None = None
        self._last_land: tuple[bool, bool, bool] | None = None
        self._log: deque[dict[str, Any]] = deque(maxlen=MAX_LOG)
        self.commands = 0
        self.samples_out = 0

    @property
    def sysid(self) -> int:
        return self.config.vehicle.sysid

    # ---- driving -------------------------------------------------------------------------

    def connect(self, agent: Address, now: float) -> None:
        self.client.connect(agent, now)

    def receive_datagram(self, data: bytes, source: Address, now: float) -> None:
        self.client.receive_datagram(data, source, now)
        self._drain(now)

    def handle_timer(self, now: float) -> None:
        self.vehicle.handle_timer(now)
        self.vehicle.messages_to_send()  # MAVLink-side streams: not on this bridge
        self.client.handle_timer(now)
        self._drain(now)
        if self.client.running:
            self._publish_due(now)

    def get_timer(self) -> float | None:
        times = [self.vehicle.get_timer()]
        if (t := self.client.get_timer()) is not None:
            times.append(t)
        if self.client.running:
            times.append(min(self._due.values()))
        return min(times)

    def datagrams_to_send(self) -> list[tuple[bytes, Address]]:
        return self.client.datagrams_to_send()

    def next_log(self) -> dict[str, Any] | None:
        return self._log.popleft() if self._log else None

    # ---- topics out ----------------------------------------------------------------------

    def _publish_due(self, now: float) -> None:
        status, land = self._status_key(), self._land_key()
        if status != self._last_status:
            self._due["vehicle_status"] = now  # commander publishes on a change
        if land != self._last_land:
            self._due["vehicle_land_detected"] = now  # so does the land detector
        for topic, period in PERIODS_S.items():
            if now >= self._due[topic]:
                self._publish(topic, now)
                self._due[topic] = max(self._due[topic] + period, now)
        self._last_status, self._last_land = status, land

    def _status_key(self) -> tuple[int, int, bool]:
        v = self.vehicle
        return (int(v.armed), NAV_STATE.get(v.mode, 4), v.prearm_failure() is None)

    def _land_key(self) -> tuple[bool, bool, bool]:
        v = self.vehicle
        return (v.ground_contact, v.maybe_landed, v.landed_detected)

    def _publish(self, topic: str, now: float) -> None:
        data = self.sample(topic, now)
        if self.client.publish_sample(topic, data, now):
            self.samples_out += 1

    def sample(self, topic: str, now: float) -> bytes:
        """The sample PX4 ``release`` would publish on ``topic`` for the vehicle's state."""
        if topic == "timesync_status":
            return self.client.timesync_status(now)
        v, c = self.vehicle, self.config.vehicle
        layouts = LAYOUTS[self.release]
        ts = self.client.timestamp_us(now)
        fixed = v.fix >= GpsFixType.FIX_3D
        values: dict[str, float | int | bool]
        match topic:
            case "vehicle_status":
                message = "VehicleStatus"
                values = {
                    "arming_state": ARMING_STATE_ARMED if v.armed else ARMING_STATE_DISARMED,
                    "nav_state": NAV_STATE.get(v.mode, 4),
                    "vehicle_type": VEHICLE_TYPE_ROTARY_WING,
                    "failsafe": False,
                    "system_id": self.sysid,
                    "component_id": 1,
                    "pre_flight_checks_pass": v.prearm_failure() is None,
                }
            case "vehicle_land_detected":
                message = "VehicleLandDetected"
                values = {"ground_contact": v.ground_contact, "maybe_landed": v.maybe_landed,
                          "landed": v.landed_detected}  # fmt: skip
            case "battery_status":
                message = "BatteryStatus"
                values = {"connected": True, "voltage_v": 14.0 + v.battery * 0.028,
                          "remaining": v.battery / 100.0}  # fmt: skip
            case "failsafe_flags":
                message = "FailsafeFlags"
                values = {
                    "mode_req_global_position": MODE_REQ_GLOBAL_POSITION,
                    "mode_req_home_position": MODE_REQ_HOME_POSITION,
                    "global_position_invalid": not fixed,
                    "home_position_invalid": not v.home_set,
                }
            case "vehicle_gps_position":
                message = "SensorGps"
                alt = c.home_amsl_m + v.alt_m
                fields = layouts[message][2]
                values = {"fix_type": int(v.fix), "satellites_used": v.satellites,
                          "eph": 0.9 if fixed else 99.0}  # fmt: skip
                if "latitude_deg" in fields:  # 1.15+: float64 degrees and metres
                    values |= {"latitude_deg": c.home_lat_deg, "longitude_deg": c.home_lon_deg,
                               "altitude_msl_m": alt}  # fmt: skip
                else:  # 1.14: 1e-7 degrees and millimetres
                    lat, lon = round(c.home_lat_deg * 1e7), round(c.home_lon_deg * 1e7)
                    values |= {"lat": lat, "lon": lon, "alt": round(alt * 1000)}
            case _:
                raise ValueError(f"not a periodic topic: {topic}")
        return encode_fields(layouts[message], {"timestamp": ts, **values})

    # ---- commands in ---------------------------------------------------------------------

    def _drain(self, now: float) -> None:
        while (event := self.client.next_event()) is not None:
            match event:
                case SampleReceived():
                    self._sample_in(event, now)
                case SessionCreated():
                    self._note("session", now, state="created", key=event.client_key.hex())
                case SessionEnded():
                    self._note("session", now, state="ended", reason=event.reason)
                case _:
                    pass

    def _sample_in(self, event: SampleReceived, now: float) -> None:
        if event.topic_name == self.client.request_topic:
            if len(event.data) < SAMPLE_IDENTITY_SIZE:
                self._note("dropped", now, reason="short_request")
                return
            identity, data = event.data[:SAMPLE_IDENTITY_SIZE], event.data[SAMPLE_IDENTITY_SIZE:]
            self._command(data, now, identity)
        elif event.topic_name == self.client.names["vehicle_command"]:
            self._command(event.data, now, None)

    def _command(self, data: bytes, now: float, identity: bytes | None) -> None:
        layout = LAYOUTS[self.release]["VehicleCommand"]
        try:
            f = decode_fields(layout, data)
        except ValueError:
            self._note("dropped", now, reason="short_command")
            return
        self.commands += 1
        params = tuple(float(f[f"param{i}"]) for i in range(1, 8))
        cmd = VehicleCommand(int(f["command"]), params,  # type: ignore[arg-type]
                             int(f["confirmation"]), int(f["target_system"]),
                             int(f["target_component"]))  # fmt: skip
        src = (int(f["source_system"]), int(f["source_component"]))
        self.vehicle.receive(cmd, src, now)
        acks = [m for m in self.vehicle.messages_to_send() if isinstance(m, CommandAck)]
        result = acks[-1].result if acks else None
        self._note(
            "vehicle_command", now, via="topic" if identity is None else "service",
            fields={k: (v if v == v else None) for k, v in f.items()},  # NaN -> null
            ack_result=result,
        )  # fmt: skip
        if not acks:
            return  # PX4 ignores a command for another vehicle: no ack
        ack = acks[-1]
        sample = encode_fields(LAYOUTS[self.release]["VehicleCommandAck"], {
            "timestamp": self.client.timestamp_us(now), "command": ack.command,
            "result": ack.result, "target_system": ack.target_system,
            "target_component": ack.target_component, "from_external": False,
        })  # fmt: skip
        if identity is not None:
            self.client.reply(identity, sample, now)
        self.client.publish_sample("vehicle_command_ack", sample, now)
        self._due["vehicle_status"] = now  # commander publishes the new state at once

    def _note(self, event: str, now: float, **fields: Any) -> None:
        self._log.append({"event": event, "t": round(now - self.vehicle.boot, 3), **fields})
