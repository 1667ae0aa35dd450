"""``swarmd-vehicle-sim``: the MAVLink vehicle **simulator** on a UDP socket.

It is a simulator, not PX4 (``sim_model.py`` says what it copies and docs/px4.md where it
departs). The adapter is the thin asyncio shell style.md asks for: datagrams in ->
``SimVehicle.receive``; one ``TimerHandle`` at ``SimVehicle.get_timer()``; everything the
model queues goes out as MAVLink 2 frames from (sysid, component 1).

Like PX4 SITL it sends to a companion listening on 14540 by default
(``--connect udpout:127.0.0.1:14540``, swarmd's ``udpin:127.0.0.1:14540``); with
``--listen udpin:127.0.0.1:14580`` it waits for the companion to speak first and answers
whoever spoke last (swarmd ``udpout:127.0.0.1:14580``).

``--signing-key FILE`` (the file ``swarmctl px4 key`` writes for PX4's SD card) turns on
MAVLink 2 signing as PX4 >= v1.17 does once a key is provisioned: every frame sent is
signed, and a received frame without a good signature is dropped, except PX4's unsigned
allowlist (HEARTBEAT, RADIO_STATUS, ADSB_VEHICLE, COLLISION: PX4
``mavlink_sign_control.cpp``). So a command from a host without the key never reaches the
model, as with PX4. ``SETUP_SIGNING`` is obeyed as current PX4 main does: taken unsigned
while no key is set, only signed with the current key once one is (the codec drops the rest),
refused while armed; an all-zero key and timestamp turns signing off.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import random
import signal
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, cast

from swarmd.exitcodes import EX_OSERR
from swarmd.px4.constants import COMP_ID_AUTOPILOT1
from swarmd.px4.mavlink_codec import Frame, MavlinkCodec, SetupSigning
from swarmd.px4.signing import parse_key_file, timestamp_from_unix
from swarmd.px4.transport import BadConnectionString, Endpoint, parse_connection
from swarmd_lab.px4.sim_model import REBOOT_S, SimConfig, SimVehicle

LogSink = Callable[[str, dict[str, Any]], None]

# PX4's unsigned allowlist once signing is on (mavlink_sign_control.cpp, docs "Unsigned
# Message Allowlist"): HEARTBEAT, RADIO_STATUS, ADSB_VEHICLE, COLLISION
PX4_UNSIGNED_ALLOWLIST = frozenset({0, 109, 246, 247})


class SimProtocol(asyncio.DatagramProtocol):
    """Joins one ``SimVehicle`` to one UDP socket."""

    def __init__(
        self,
        config: SimConfig,
        rng: random.Random,
        remote: tuple[str, int] | None,
        log: LogSink | None = None,
        signing_key: bytes | None = None,
    ) -> None:
        self._config = config
        self._rng = rng
        self._remote = remote
        self._learn = remote is None
        self._log = log
        self._loop = asyncio.get_running_loop()
        self.codec = MavlinkCodec(
            config.sysid,
            COMP_ID_AUTOPILOT1,
            signing_key=signing_key,
            accept_unsigned=PX4_UNSIGNED_ALLOWLIST,
        )
        self.model = SimVehicle(config, rng, self._loop.time())
        self._transport: asyncio.DatagramTransport | None = None
        self._timer: asyncio.TimerHandle | None = None
        self.sent = 0

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        # cast, not isinstance: CPython 3.11's selector UDP transport does not subclass
        # DatagramTransport
        self._transport = cast(asyncio.DatagramTransport, transport)
        self._pump()

    def datagram_received(self, data: bytes, addr: tuple[str | int, ...]) -> None:
        now = self._loop.time()
        self.codec.advance_clock(timestamp_from_unix(time.time()))
        frames = self.codec.feed(data, datagram=True)
        if self._learn and frames:  # with signing: only a sender whose frames checked
            self._remote = (str(addr[0]), int(addr[1]))
        for frame in frames:
            if isinstance(frame.msg, SetupSigning):
                self._setup_signing(frame, now)
                continue
            self.model.receive(frame.msg, (frame.src_system, frame.src_component), now)
        self._pump()

    def _setup_signing(self, frame: Frame, now: float) -> None:
        msg = frame.msg
        if not isinstance(msg, SetupSigning):
            return
        if msg.target_system not in (0, self._config.sysid) or msg.target_component not in (
            0,
            COMP_ID_AUTOPILOT1,
        ):
            return
        if self.model.armed:  # PX4: "Signing key changes ... are rejected while armed"
            self._note("signing_key_refused", now, why="armed")
            return
        if msg.secret_key == bytes(32) and msg.initial_timestamp == 0:
            self.codec.set_signing_key(None)
            self._note("signing_key_cleared", now)
            return
        self.codec.set_signing_key(msg.secret_key)
        self.codec.advance_clock(msg.initial_timestamp)
        self._note("signing_key_set", now, signed=frame.signed)

    def _note(self, event: str, now: float, **fields: Any) -> None:
        if self._log is not None:
            self._log(event, {"t": round(now, 3), **fields})

    def error_received(self, exc: Exception) -> None:
        pass  # ICMP unreachable while nobody listens yet, as PX4 SITL shrugs it off

    def _on_timer(self) -> None:
        self._timer = None
        self.model.handle_timer(self._loop.time())
        self._pump()

    def _pump(self) -> None:
        self.codec.advance_clock(timestamp_from_unix(time.time()))
        for msg in self.model.messages_to_send():
            if self._transport is not None and self._remote is not None:
                self._transport.sendto(self.codec.encode(msg), self._remote)
                self.sent += 1
        while (record := self.model.next_log()) is not None:
            if self._log is not None:
                self._log(*record)
        if self._timer is not None:
            self._timer.cancel()
        if self._transport is not None and not self._transport.is_closing():
            self._timer = self._loop.call_at(self.model.get_timer(), self._on_timer)

    def reboot(self, boot_s: float = REBOOT_S) -> None:
        """Power-cycle the simulated PX4 now (``SimVehicle.reboot``: silent for ``boot_s``)."""
        self.model.reboot(self._loop.time(), boot_s)
        self._pump()

    @property
    def local_port(self) -> int:
        if self._transport is None:
            return 0
        port: int = self._transport.get_extra_info("sockname")[1]
        return port

    def close(self) -> None:
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        if self._transport is not None:
            self._transport.close()


async def start_sim(
    config: SimConfig,
    endpoint: Endpoint,
    *,
    seed: int = 0,
    log: LogSink | None = None,
    signing_key: bytes | None = None,
) -> SimProtocol:
    """Start a simulator on ``endpoint`` (``udpout:`` sends to it, ``udpin:`` binds it)."""
    loop = asyncio.get_running_loop()
    rng = random.Random(seed)  # noqa: S311 - simulation noise, reproducible by design
    if endpoint.kind == "udpout":
        remote: tuple[str, int] | None = (endpoint.host, endpoint.port)
        local = ("127.0.0.1" if endpoint.host.startswith("127.") else "0.0.0.0", 0)  # noqa: S104
    elif endpoint.kind == "udpin":
        remote, local = None, (endpoint.host, endpoint.port)
    else:
        raise BadConnectionString(
            f"--connect/--listen: {endpoint} is not UDP; fix: the simulator speaks UDP only"
        )
    _, protocol = await loop.create_datagram_endpoint(
        lambda: SimProtocol(config, rng, remote, log, signing_key), local_addr=local
    )
    return protocol


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="swarmd-vehicle-sim",
        description="A PX4-like MAVLink vehicle SIMULATOR for swarmd tests and demos (not PX4).",
    )
    where = p.add_mutually_exclusive_group()
    where.add_argument(
        "--connect",
        metavar="udpout:HOST:PORT",
        help="send to a companion listening there (default udpout:127.0.0.1:14540, as SITL)",
    )
    where.add_argument(
        "--listen",
        metavar="udpin:HOST:PORT",
        help="bind here and answer whoever speaks (like SITL's 14580 port)",
    )
    p.add_argument("--sysid", type=int, default=1, help="MAV_SYS_ID (1..255)")
    p.add_argument("--gps-fix-after", type=float, default=2.0, metavar="S",
                   help="seconds until the simulated 3D GPS fix (and home) arrive")  # fmt: skip
    p.add_argument("--battery", type=float, default=90.0, metavar="PCT",
                   help="battery remaining in percent")  # fmt: skip
    p.add_argument("--fail-prearm", action="store_true",
                   help="a sensor never passes its pre-flight check (no PREARM bit)")  # fmt: skip
    p.add_argument("--no-home", action="store_true", help="never publish HOME_POSITION")
    p.add_argument("--reject-arms", type=int, default=0, metavar="N",
                   help="answer the first N arm commands TEMPORARILY_REJECTED")  # fmt: skip
    p.add_argument("--seed", type=int, default=0, help="seed for stream phases and GPS noise")
    p.add_argument("--duration", type=float, default=None, metavar="S",
                   help="exit after S seconds (default: run until SIGINT/SIGTERM)")  # fmt: skip
    p.add_argument("--reboot-after", type=float, default=None, metavar="S",
                   help="power-cycle the simulated PX4 once after S seconds (silent "
                   f"{REBOOT_S:g} s, then a new life: disarmed, no fix, no home)")  # fmt: skip
    p.add_argument("--json-log", action="store_true", help="JSON lines on stderr")
    p.add_argument("--signing-key", metavar="FILE", default=None,
                   help="MAVLink 2 signing on with this key (PX4's 40-byte key file, 32 raw "
                   "bytes or 64 hex digits): sign all, drop unsigned as PX4 does")  # fmt: skip
    return p


def config_from_args(args: argparse.Namespace) -> tuple[SimConfig, Endpoint]:
    """Checked options; raises BadConnectionString/ValueError with one line."""
    if not 1 <= args.sysid <= 255:
        raise ValueError(f"--sysid {args.sysid}: out of range; fix: 1..255")
    if not 0.0 <= args.battery <= 100.0:
        raise ValueError(f"--battery {args.battery}: out of range; fix: 0..100")
    if args.gps_fix_after < 0 or args.reject_arms < 0:
        raise ValueError("--gps-fix-after and --reject-arms must be >= 0")
    if args.reboot_after is not None and args.reboot_after < 0:
        raise ValueError(f"--reboot-after {args.reboot_after}: fix: >= 0 seconds")
    if args.listen is not None:
        text = args.listen if args.listen.startswith("udp") else f"udpin:{args.listen}"
        endpoint = parse_connection(text, "--listen")
        if endpoint.kind != "udpin":
            raise BadConnectionString(f"--listen {args.listen}: fix: udpin:HOST:PORT")
    else:
        endpoint = parse_connection(args.connect or "udpout:127.0.0.1:14540", "--connect")
        if endpoint.kind != "udpout":
            raise BadConnectionString(f"--connect {args.connect}: fix: udpout:HOST:PORT")
    config = SimConfig(
        sysid=args.sysid,
        gps_fix_after_s=args.gps_fix_after,
        battery_pct=args.battery,
        fail_prearm=args.fail_prearm,
        no_home=args.no_home,
        reject_arms=args.reject_arms,
    )
    return config, endpoint


async def _run(config: SimConfig, endpoint: Endpoint, args: argparse.Namespace) -> int:
    from swarmd.logs import configure, get_logger

    configure("info", "json" if args.json_log else "auto")
    log = get_logger(component="vehicle-sim", simulator=True, sysid=config.sysid)

    def sink(event: str, fields: dict[str, Any]) -> None:
        log.info(event, **fields)

    key: bytes | None = args.key
    sim = await start_sim(config, endpoint, seed=args.seed, log=sink, signing_key=key)
    log.info(
        "vehicle_sim_started",
        note="MAVLink vehicle SIMULATOR, not PX4",
        endpoint=str(endpoint),
        local_port=sim.local_port,
        signing=key is not None,
        config=repr(config),
    )
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    if args.reboot_after is not None:
        loop.call_later(args.reboot_after, sim.reboot)
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, stop.set)
    try:
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(stop.wait(), timeout=args.duration)
    finally:
        log.info(
            "vehicle_sim_stopped",
            sent=sim.sent,
            signing=sim.codec.signing_counts,
            **sim.model.snapshot(),
        )
        sim.close()
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        config, endpoint = config_from_args(args)
        args.key = None
        if args.signing_key is not None:
            args.key = parse_key_file(Path(args.signing_key).read_bytes(), args.signing_key)
    except ValueError as exc:
        print(f"swarmd-vehicle-sim: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        print(f"swarmd-vehicle-sim: --signing-key {args.signing_key}: {exc.strerror}",
              file=sys.stderr)  # fmt: skip
        return 66  # EX_NOINPUT
    try:
        return asyncio.run(_run(config, endpoint, args))
    except OSError as exc:
        print(f"swarmd-vehicle-sim: cannot open {endpoint}: {exc.strerror}", file=sys.stderr)
        return EX_OSERR


if __name__ == "__main__":
    sys.exit(main())
