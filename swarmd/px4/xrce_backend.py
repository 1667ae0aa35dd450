"""The uXRCE-DDS backends: swarmd as PX4's agent (``xrce-agent``) or as a second client of an
existing MicroXRCEAgent (``xrce-client``).

Both translate topics into the same observations as MAVLink (``xrce_translate``) and
``VehicleCommand`` into ``/fmu/in/vehicle_command``; readiness and take-off do not know which
wire they run on. The sans-IO session engine (``swarmd.xrce``: ``XrceAgent`` or
``XrceClient``) runs under the shared ``swarmd.driver.Driver``; this module only opens the
socket or UART and turns the engine's events into observations.

As the agent with a key (the daemon always has one, docs/px4.md "One agent, one vehicle"),
the engine is bound to one vehicle: a second client is refused (``refused`` in ``stats()``,
logged at the 1st, 10th, 100th ... refusal; ``over_budget``: dropped unchecked by the
key-check budget, ``key_checks``: keys compared), and the translator drops samples whose
``vehicle_status.system_id`` is not ``sysid``.

Connections: ``udp:HOST:PORT`` -- the agent listens on it, the client sends to it;
``serial:/dev/ttyTHS1:921600`` -- the agent on a UART, with Micro XRCE-DDS's framing (PX4
``UXRCE_DDS_CFG`` = TELEM2). The default, ``udp:127.0.0.1:888``, is PX4 SITL's 8888 moved
below 1024 so that no local user can bind it (issue 18, docs/px4.md "The XRCE agent's
port"): as the agent, the socket is the one ``swarmd-xrce.socket`` bound from boot
(``inherited``, ``SO_REUSEADDR`` cleared) or one bound here without ``SO_REUSEADDR``; a
squatter stops start-up with one line naming it (``transport.bind_udpin``).
"""

from __future__ import annotations

import asyncio
import socket
import time
from collections import Counter
from typing import Any, Final, Literal

from swarmd.driver import Driver
from swarmd.px4.backend import ObservationSink
from swarmd.px4.command_sender import SenderConfig
from swarmd.px4.constants import MavCmd
from swarmd.px4.messages import Observation, VehicleCommand
from swarmd.px4.transport import (
    XRCE_SOCKET,
    ByteLink,
    Endpoint,
    bind_to_its_interface,
    bind_udpin,
    is_network_endpoint,
    open_link,
)
from swarmd.px4.xrce_translate import Px4Translator
from swarmd.senderuid import SenderUids, log_firewall_expected
from swarmd.xrce.agent import XrceAgent
from swarmd.xrce.client import XrceClient
from swarmd.xrce.events import (
    Address,
    ClientRefused,
    PacketDropped,
    SampleReceived,
    SessionCreated,
    SessionEnded,
    XrceEvent,
)
from swarmd.xrce.framing import Deframer, frame
from swarmd.xrce.px4 import dds_topic

Mode = Literal["xrce-agent", "xrce-client"]
# PX4's UXRCE_DDS_PRT default is 8888; 888 is below net.ipv4.ip_unprivileged_port_start
DEFAULT_XRCE_CONNECTION: Final = "udp:127.0.0.1:888"
SERIAL_PEER: Final = "serial"
SERVICE: Final = "vehicle_command"  # PX4's replier (>= 1.15), rq/rr/fmu/vehicle_command...
# How long one command frame may be repaired by the XRCE reliable stream (DDS-XRCE 1.0
# §8.4.2): the command sender's ack timeout. By then the sender has sent its own next copy
# (a new frame, ``confirmation`` + 1) or given the command up and its outcome is on its
# way to the operator, so a repair later would only deliver the command late: a take-off's
# ARMs written into a link outage reached PX4 after the take-off failed ``arm_no_ack``
# (docs/security.md, "A command frame delivered late"). Later repairs send a stand-in.
# Not a DISARM (``_life``): it starts no motion, and a failed take-off sends it once.
COMMAND_LIFE_S: Final = SenderConfig().ack_timeout_s


def _life(command: VehicleCommand, until: float) -> float | None:
    """Until when ``command``'s frame may be repaired as itself (``COMMAND_LIFE_S``); None:
    as long as the session lives. A DISARM (param1 0) stops motion, and a failed take-off's
    is sent once and left to the link (takeoff.py): with a life, an outage a little longer
    than it left PX4 armed on the ground after the ARM that reached it (review 17). Late,
    it still lands behind the frames before it, and PX4 refuses a non-forced one in the
    air."""
    if command.command == MavCmd.COMPONENT_ARM_DISARM and command.params[0] == 0.0:
        return None
    return until


def parse_xrce_connection(text: str, field: str = "px4.connection") -> Endpoint:
    """``udp:HOST:PORT`` or ``serial:DEVICE:BAUD``; ValueError with one line otherwise."""
    kind, _, rest = text.partition(":")
    example = "udp:127.0.0.1:888 or serial:/dev/ttyTHS1:921600"
    if kind == "udp":
        host, _, port = rest.rpartition(":")
        if host and port.isdigit() and 0 < int(port) < 65536:
            return Endpoint("udpin", host=host, port=int(port))
    elif kind == "serial":
        device, _, baud = rest.rpartition(":")
        if device.startswith("/") and baud.isdigit():
            return Endpoint("serial", device=device, baud=int(baud))
    raise ValueError(f"{field}: {text!r} is not an XRCE connection; fix: {example}")


class _Datagrams(asyncio.DatagramProtocol):
    def __init__(self, backend: XrceBackend) -> None:
        self.backend = backend

    def datagram_received(self, data: bytes, addr: tuple[str, int]) -> None:
        self.backend._receive(data, (addr[0], addr[1]))

    def error_received(self, exc: Exception) -> None:
        self.backend.counters["socket_errors"] += 1


class XrceBackend:
    """``VehicleBackend`` over DDS-XRCE for vehicle ``sysid`` (see the module docstring)."""

    def __init__(
        self,
        mode: Mode,
        connection: str = DEFAULT_XRCE_CONNECTION,
        *,
        sysid: int = 1,
        client_key: int = 0x5357_4D44,  # "SWMD": swarmd's own key as a second client
        expected_key: int | None = None,
        namespace: str | None = None,
        domain_id: int = 0,
        loopback_user: int | None = None,
        log: Any = None,
        inherited: socket.socket | None = None,
        sender_uids: SenderUids | None = None,
        command_life_s: float = COMMAND_LIFE_S,
    ) -> None:
        """``loopback_user`` (xrce-agent): the uid PX4 SITL runs as; the agent then drops
        every other local user's loopback datagram, told by the kernel's socket table
        (``sender_uids``, swarmd.senderuid; injected by tests). ``command_life_s``: how long
        a command's frame may be repaired on a reliable stream (``COMMAND_LIFE_S``)."""
        if not 1 <= sysid <= 255:
            raise ValueError("px4.sysid must be 1..255")
        self.mode: Mode = mode
        self.name: str = mode
        self.endpoint = parse_xrce_connection(connection)
        if mode == "xrce-client" and self.endpoint.kind == "serial":
            raise ValueError("px4.connection: xrce-client reaches its agent over udp:HOST:PORT")
        self.sysid = sysid
        self.namespace = namespace
        self.translator = Px4Translator(sysid)
        # agent time = Unix time, as with eProsima's agent (PX4 stamps samples with it)
        self._clock_offset = time.time() - time.monotonic()
        self.engine: XrceAgent | XrceClient
        if mode == "xrce-agent":
            self.engine = XrceAgent(
                clock_offset_s=0.0,
                expected_key=None if expected_key is None else expected_key.to_bytes(4, "big"),
                vehicle_uid=loopback_user,
            )
        else:
            self.engine = XrceClient(
                client_key.to_bytes(4, "big"),
                subscriptions=_subscriptions(namespace),
                publications={dds_topic("vehicle_command", "in", 0, namespace): _cmd_type()},
                domain_id=domain_id,
            )
        self.command_life_s = command_life_s
        self.counters: Counter[str] = Counter()
        self.loopback_user = loopback_user if mode == "xrce-agent" else None
        # who sent a loopback datagram: looked up only when the agent tells users apart
        # (PX4's sources are kept: another user's sockets cannot push them out of the
        # table read: swarmd.senderuid, MAX_KEPT_SOURCES)
        self._sender_uids = (
            (sender_uids or SenderUids(keep_uids={self.loopback_user}, log=log))
            if self.loopback_user is not None
            else None
        )
        self.session: str = "none"
        self.client: str | None = None
        self.last_refused: str | None = None  # "ADDR key KEY (reason)" of the last refusal
        self._log = log
        # the interface the agent's socket hears on alone (``bind_to_its_interface``)
        self.interface: str | None = None
        self._sink: ObservationSink | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._transport: asyncio.DatagramTransport | None = None
        self._link: ByteLink | None = None
        self._deframer = Deframer()
        self._driver: Driver[bytes, tuple[bytes, Address], XrceEvent] | None = None
        self._agent_addr: tuple[str, int] | None = None
        # xrce-agent on udp: the socket swarmd-xrce.socket bound (sd_listen_fds "xrce")
        self._inherited = (
            inherited if mode == "xrce-agent" and self.endpoint.kind == "udpin" else None
        )

    async def start(self, sink: ObservationSink) -> None:
        loop = asyncio.get_running_loop()
        self._loop, self._sink = loop, sink
        self._driver = Driver(
            self.engine, transmit=self._transmit, on_event=self._event, name=self.mode, loop=loop
        )
        self._clock_offset = time.time() - loop.time()
        if isinstance(self.engine, XrceAgent):
            self.engine.clock_offset_s = self._clock_offset
            if (
                self.loopback_user is None
                and self._log is not None
                and self.endpoint.kind != "serial"
            ):
                # docs/security.md, "XRCE's key, guessed": a many-port loopback flood delays a
                # loopback PX4 while it lasts; px4.loopback_user closes it for SITL
                self._log.info(
                    "xrce_local_users_not_told_apart",
                    fix="set px4.loopback_user to PX4 SITL's user (docs/px4.md)",
                )
            elif self._log is not None and self.endpoint.kind != "serial":
                log_firewall_expected(self._log, "px4.connection")
        ep = self.endpoint
        if ep.kind == "serial":
            self._link = await open_link(ep, self._on_serial)
        elif self.mode == "xrce-agent":
            # never SO_REUSEADDR, a squatter named: issue 18's defence for the agent's port
            sock = bind_udpin(ep, self._inherited, XRCE_SOCKET)
            self._inherited = None  # adopted (or refused): ours to close from now on
            # the Ethernet address heard from the Ethernet only: a Wi-Fi host writing the
            # FMU's address would spend the FMU's key-check budget (transport.py)
            self.interface = bind_to_its_interface(sock)
            if self.interface is None and is_network_endpoint(ep) and self._log is not None:
                self._log.warning(
                    "xrce_agent_any_interface",
                    connection=_show(ep),
                    why="datagrams for this address are heard from every interface: a host "
                    "on another one (the Wi-Fi) can write the vehicle's address as its source "
                    "and spend its key-check budget",
                    fix="connection: a single address (not a wildcard), or BindToDevice= in "
                    "swarmd-xrce.socket (docs/px4.md)",
                )
            try:
                self._transport, _ = await loop.create_datagram_endpoint(
                    lambda: _Datagrams(self), sock=sock
                )
            except BaseException:
                sock.close()
                raise
        else:
            self._agent_addr = (ep.host, ep.port)
            self._transport, _ = await loop.create_datagram_endpoint(
                lambda: _Datagrams(self), remote_addr=self._agent_addr
            )
            # the address datagrams arrive from ("localhost" resolves to 127.0.0.1)
            peer = self._transport.get_extra_info("peername")
            self._agent_addr = (peer[0], peer[1])
            if isinstance(self.engine, XrceClient):
                client, agent = self.engine, self._agent_addr
                self._driver.call(lambda now: client.connect(agent, now))

    def send(self, command: VehicleCommand) -> None:
        if self._driver is None:
            return
        topic = dds_topic("vehicle_command", "in", 0, self.namespace)

        engine = self.engine
        # PX4 >= 1.15 serves vehicle_command as a service too; use it when PX4 offers it (its
        # reply is the ack), never both ways at once or PX4 would run the command twice
        service = isinstance(engine, XrceAgent) and engine.has_replier(SERVICE)

        def publish(now: float) -> int:
            sample = self.translator.command(command, round((now + self._clock_offset) * 1e6))
            life = now + self.command_life_s
            if command.not_after is not None:
                # never repaired past the operator's validity: a take-off's ARM or
                # NAV_TAKEOFF delivered after it would start the flight late (takeoff.py,
                # "Validity")
                life = min(life, command.not_after)
            until = _life(command, life)
            if service and isinstance(engine, XrceAgent):
                return engine.request(SERVICE, sample, now, until=until)
            return engine.publish(topic, sample, now, until=until)

        sent = self._driver.call(publish)
        self.counters["commands_unrouted"] += 0 if sent else 1
        if sent:
            self.counters["commands_via_service" if service else "commands_sent"] += 1

    def stats(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "backend": self.mode,
            "connection": _show(self.endpoint),
            "sysid": self.sysid,
            "session": self.session,
            "client": self.client,
            "px4_version": self.translator.px4_version,
            "layout_problem": self.translator.problem,
            "failsafe_blockers": (
                None if self.translator.blockers is None else list(self.translator.blockers)
            ),
            "foreign_acks": self.translator.foreign_acks,
            # one vehicle (docs/px4.md "One agent, one vehicle")
            "bound": isinstance(self.engine, XrceAgent) and self.engine.bound,
            "refused": dict(self.engine.refused) if isinstance(self.engine, XrceAgent) else {},
            # client keys compared; CREATE_CLIENTs over the budget are refused.over_budget
            "key_checks": (
                self.engine.key_checks.checks if isinstance(self.engine, XrceAgent) else 0
            ),
            "interface": self.interface,
            "last_refused": self.last_refused,
            "foreign_samples": self.translator.foreign_samples,
            "foreign_system_id": self.translator.foreign_system_id,
            "unidentified_samples": self.translator.unidentified_samples,
            "dropped": dict(self.engine.dropped),
            # command frames whose repair came too late: a stand-in went instead (a link
            # outage or a stalled PX4; docs/security.md, "A command frame delivered late")
            "commands_expired": self.engine.stand_ins,
            "bad_frames": self._deframer.dropped,
        }
        # the counters a status reader polls are there from the start, at 0 (a JSON reader
        # must not meet a missing key in the window between the session and its first sample)
        out.update({"datagrams_in": 0, "samples": 0})
        out.update(self.counters)
        if self._sender_uids is not None:
            # PX4's port another user holds too: its datagrams dropped (swarmd.senderuid)
            out["sender_port_shared"] = self._sender_uids.counters["port_shared"]
        return out

    async def close(self) -> None:
        if self._driver is not None:
            if isinstance(self.engine, XrceClient):
                self._driver.call(self.engine.disconnect)  # DELETE the session, sent now
            self._driver.close()
            self._driver = None
        if self._transport is not None:
            self._transport.close()
            self._transport = None
            await asyncio.sleep(0)  # the socket closes on the next loop turn: free the port now
        if self._link is not None:
            self._link.close()
            self._link = None

    # ---- driving ----------------------------------------------------------------------------

    def _on_serial(self, data: bytes, _peer: str | None = None) -> None:
        for _src, _dst, payload in self._deframer.feed(data):
            self._receive(payload, SERIAL_PEER)

    def _receive(self, data: bytes, source: Address) -> None:
        if self._driver is None:
            return
        self.counters["datagrams_in"] += 1
        uids, engine = self._sender_uids, self.engine
        if uids is None or not isinstance(engine, XrceAgent):
            self._driver.datagram_received(data, source)
            return
        # the kernel's word; the agent decides (XrceAgent). The agent's own address: PX4's
        # XRCE-DDS client connects its UDP socket to it (swarmd.senderuid, "First contact")
        ep = self.endpoint
        to = (ep.host, ep.port) if ep.kind == "udpin" and ep.host and ep.port else None
        uid = uids.uid_of(source, to)
        self._driver.datagram_received(
            data, source, lambda d, s, now: engine.receive_datagram(d, s, now, uid)
        )

    def _transmit(self, out: tuple[bytes, Address]) -> None:
        data, dest = out
        self.counters["datagrams_out"] += 1
        if self._link is not None:
            self._link.send(frame(data, src=0, dst=1))
        elif self._transport is not None:
            if self.mode == "xrce-client":
                self._transport.sendto(data)
            elif isinstance(dest, tuple):
                self._transport.sendto(data, dest)

    def _deliver(self, observations: list[Observation]) -> None:
        if self._sink is not None and self._loop is not None:
            now = self._loop.time()
            for obs in observations:
                self._sink(obs, now)

    def _event(self, event: XrceEvent) -> None:
        match event:
            case SampleReceived():
                self.counters["samples"] += 1
                self._deliver(self.translator.sample(event.topic_name, event.data))
            case SessionCreated():
                # whose samples, and every vehicle fact: the new session's samples say
                self._deliver(self.translator.new_session())
                self.session = "established"
                self.client = f"{_peer(event.source)} key {event.client_key.hex()}"
                self.counters["sessions"] += 1
            case SessionEnded():
                self.session = f"ended ({event.reason})"
            case ClientRefused():
                self.counters["clients_refused"] += 1
                self.last_refused = (
                    f"{_peer(event.source)} key {event.client_key.hex()} ({event.reason})"
                )
                n = self.counters["clients_refused"]
                if self._log is not None and _is_power_of_ten(n):  # a flood logs log10(n) lines
                    self._log.warning(
                        "xrce_client_refused",
                        client=_peer(event.source),
                        key=event.client_key.hex(),
                        reason=event.reason,
                        refused_total=n,
                    )
            case PacketDropped():
                self.counters["drop_events"] += 1
            case _:
                pass


def _is_power_of_ten(n: int) -> bool:
    while n >= 10 and n % 10 == 0:
        n //= 10
    return n == 1


def _cmd_type() -> str:
    return "px4_msgs::msg::dds_::VehicleCommand_"


def _subscriptions(namespace: str | None) -> dict[str, str]:
    """Every out-topic name v1.14..v1.17 uses (vehicle_status and vehicle_status_v1, ...)."""
    from swarmd.xrce.px4 import OUT_TOPICS, TOPIC_MESSAGES, dds_type, topic_names

    out: dict[str, str] = {}
    for t in OUT_TOPICS:
        for name in topic_names(t, "out", namespace):
            out[name] = dds_type(TOPIC_MESSAGES[t])
    return out


def _peer(source: Address) -> str:
    if isinstance(source, tuple) and len(source) == 2:
        return f"{source[0]}:{source[1]}"
    return str(source)


def _show(ep: Endpoint) -> str:
    return f"serial:{ep.device}:{ep.baud}" if ep.kind == "serial" else f"udp:{ep.host}:{ep.port}"
