"""The daemon: wiring. Sockets, the link poller, the control socket and sd_notify around
the sans-IO cores, each run by the one asyncio ``Driver`` (``swarmd/driver.py``).

The discovery engine's driver (aioquic's shape, style.md rule 11): every input goes to the
engine with ``loop.time()`` as ``now`` and is followed by the same steps: send what the
engine queued, drain its events, re-arm its one ``TimerHandle`` at ``engine.get_timer()``
(with the early-wake guard). The inputs are

- datagrams on the SPDP multicast socket (239.255.0.1:7400+250*domain, joined on the
  configured interface) and on the unicast metatraffic socket (port from the bundle index;
  every send leaves from this socket, so peers see one source port per participant);
- the engine timer;
- link-quality samples from the link monitor, polled every ``link.poll_interval_s``.

On top of discovery, ``SwarmApp`` (``swarmd/swarmapp.py``) runs the swarm itself when
configured: the sans-IO ``SwarmCore`` (readiness reports, commands, outcomes; the data plane
inside it) on the user unicast port, through the one asyncio ``Driver`` (``swarmd/driver.py``),
fed with discovery's ``PeerDiscovered``/``PeerLost``; and the PX4 bridge.

Around it: the control socket (``swarmctl``), sd_notify (``READY=1`` once the bundle is
verified and the sockets are bound, ``STATUS=`` on phase/peer changes, ``WATCHDOG=1`` at half
``WATCHDOG_USEC`` only while the loop is healthy) and SIGTERM/SIGINT for a clean shutdown
that tells every peer we leave (DATA(p[UD])).

This module keeps the life cycle (start, stop, the sockets, link polling, the replay
windows' saves). Split out by concern at 757 lines (style.md rule 19): ``Daemon``'s base
classes hold its state and status (``daemon_status.py``: ``status``, ``healthy``, the
watchdog, ``STATUS=``) and its routing of discovery's events (``daemon_events.py``); what it
works out before it starts, the bundle floor and the PX4 listen socket included, is in
``daemon_setup.py``.

Start-up order: the discovery engine is built as soon as its keys, epoch and link sample
are in hand, and its passive clock runs from then (paper section 4.1); the swarm layer
(``SwarmApp``: the PX4 bridge, pymavlink, the data plane), the ROS 2 relay and the control
socket are imported only after it, inside that window (issue 20, the reboot: a restarted
drone's first announcement is its start-up plus the window; docs/benchmarks.md, "Daemon
start-up"). Their refusals still come before ``READY=1``, and the engine's timer is armed
where it was: at the end of ``start``, or earlier by a datagram heard during its awaits.
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import random
import secrets
import signal
import socket
import time
from collections.abc import Mapping
from functools import partial
from typing import TYPE_CHECKING, Any

from swarmd import __version__
from swarmd.auth.epoch import EpochError, EpochResult, epoch_path, next_epoch, plan_epoch
from swarmd.auth.keys import KeyRing, NodeKeyMismatch, NodeSecrets
from swarmd.auth.spdp import SpdpAuth
from swarmd.auth.windows import (
    SAVE_PERIOD_S,
    encode_windows,
    load_windows,
    windows_path,
    write_windows,
)
from swarmd.bundle.floor import floor_path
from swarmd.bundle.keys import remove_left_temps
from swarmd.bundle.model import Bundle
from swarmd.bundle.statedir import DaemonUser
from swarmd.config import ConfigError, DaemonConfig, config_mode_problem
from swarmd.daemon_events import DaemonEvents, peer_change_reports
from swarmd.daemon_setup import (
    NodeSecretsError,
    engine_config,
    link_sources,
    load_node_secrets,
    open_spdp_socket,
    open_unicast_socket,
    px4_listen_socket,
    raise_bundle_floor,
    resolve_ipv4,
)
from swarmd.discovery.engine import DiscoveryEngine
from swarmd.discovery.events import Event
from swarmd.driver import Driver
from swarmd.exitcodes import EX_CANTCREAT, EX_OSERR, EX_UNAVAILABLE, StartupError
from swarmd.filewriter import FileWriter
from swarmd.link.monitor import LinkMonitor
from swarmd.link.source import LinkSource
from swarmd.peerlog import PeerHistory
from swarmd.rawclock import RawClockEventLoop
from swarmd.sdnotify import Notifier, watchdog_interval_s
from swarmd.udp import RECV_BUFFER_BYTES, BatchedSocket, Datagram, rcvbuf_capped

if TYPE_CHECKING:  # imported in start(), once the engine is built ("Start-up order" above)
    from swarmd.control import ControlServer
    from swarmd.ros2app import Ros2App
    from swarmd.swarmapp import SwarmApp


class Daemon(DaemonEvents):
    """One swarmd process: the engine, its sockets, link polling, control and sd_notify."""

    def __init__(
        self,
        config: DaemonConfig,
        bundle: Bundle,
        *,
        log: Any,
        notifier: Notifier | None = None,
        sources: list[LinkSource] | None = None,
        rng: random.Random | None = None,
        env: Mapping[str, str] | None = None,
        node_secrets: NodeSecrets | None = None,
    ) -> None:
        self.config = config
        self.bundle = bundle
        try:
            # every datagram is signed with these (docs/security.md): no keys, no daemon
            self._secrets = node_secrets or load_node_secrets(config, bundle)
        except NodeSecretsError as exc:
            raise config.error("bundle.node_key", str(exc), "see docs/security.md") from None
        # made in start(), once the node is known to be in the bundle
        self.keyring: KeyRing | None = None
        # raised and made durable in start(), before the first send (swarmd.auth.epoch),
        # in the folder of node.key (/var/lib/swarmd on a drone: the state directory)
        self.epoch: EpochResult | None = None
        self._state_dir = config.bundle.node_state_dir  # epoch, windows, bundle floor
        # SPDP replay windows persisted beside the epoch (swarmd.auth.windows): a restart
        # does not make a dead member's captured DATA(p) fresh again
        self._spdp_auth: SpdpAuth | None = None
        self._windows_path = windows_path(self._state_dir, config.node)
        self._windows_timer: asyncio.TimerHandle | None = None
        # every save while running (replay windows, the swarm's state file) is written on
        # this writer's thread, never on the loop: a slow SD card's fsync stalled it
        # (swarmd.filewriter); stop() flushes it
        self.writer = FileWriter()
        self.log = log
        self.notifier = notifier if notifier is not None else Notifier(env)
        # sd_listen_fds(3): read (and unset) once; a copy when the caller passed its own
        self._listen_env: dict[str, str] | None = None if env is None else dict(env)
        self.monitor = LinkMonitor(sources if sources is not None else link_sources(config), log)
        # seeded from the OS: two drones booting together must not draw the same timers
        self.rng = rng if rng is not None else random.Random(secrets.randbits(64))  # noqa: S311 - timer jitter, not cryptography
        self.engine_config = engine_config(config)
        self.local_ipv4 = resolve_ipv4(config)
        self.watchdog_s = watchdog_interval_s(env)
        self.counters: dict[str, int] = {}
        self.engine: DiscoveryEngine | None = None
        self.stopped = asyncio.Event()
        # lost/regained/restarted peers for the operator in flight (swarmctl watch)
        self.peer_history = PeerHistory()
        # which of a peer's moves and ROS 2 liveness changes are logged (daemon_events.py)
        self._peer_changes = peer_change_reports()
        self._loop: asyncio.AbstractEventLoop | None = None
        self._transports: dict[str, BatchedSocket] = {}
        self.driver: Driver[bytes, Datagram, Event] | None = None
        self._watchdog: asyncio.TimerHandle | None = None
        self._link_task: asyncio.Task[None] | None = None
        self._control: ControlServer | None = None
        self.app: SwarmApp | None = None  # made in start(), after the engine checked the node
        # the SPDP relay of this drone's stock ROS 2 nodes (config ros2.relay, docs/ros2.md)
        self.ros2: Ros2App | None = None
        self._status_line = ""
        self._ready = False  # STATUS= updates start with READY=1, which carries the first
        self._started_wall = time.time()
        self._started = 0.0

    # -- life cycle ----------------------------------------------------------------------

    async def start(self) -> None:
        """Bind everything, then ``READY=1``. Raises ``StartupError`` with a one-line reason."""
        loop = asyncio.get_running_loop()
        self._loop = loop
        self._started = loop.time()
        if not isinstance(loop, RawClockEventLoop):
            # a command's validity is proved for clocks NTP cannot slew (docs/dataplane.md,
            # "Validity"): an embedder that drives the daemon on asyncio's default loop
            # (CLOCK_MONOTONIC) is told, once, what it gives up
            self.log.warning(
                "loop_clock_slewable",
                clock="CLOCK_MONOTONIC",
                fix="drive the daemon with swarmd.rawclock.run_on_raw_clock, as `swarmd run` does",
            )
        self.keyring = self.check_start()
        # node.key's folder judged before the floor's write into it, as check-config judges it
        self._plan_epoch(DaemonUser.this_process())
        raise_bundle_floor(self.config, self.bundle, self.log)
        try:
            self.epoch = next_epoch(self._state_dir, self.config.node, time.time())
        except EpochError as exc:
            raise StartupError(str(exc), EX_CANTCREAT) from None
        # a crash inside an atomic write leaves its temporary file: remove this node's
        # (keys.remove_left_temps; the folder was checked as ours by next_epoch)
        left = sum(
            remove_left_temps(path(self._state_dir, self.config.node))
            for path in (epoch_path, windows_path, floor_path)
        )
        if left:
            self.log.warning("state_temp_files_removed", path=self._state_dir, count=left)
        if self.epoch.recovered_from is not None:
            self.log.warning(
                "auth_epoch_recovered",
                path=str(self.epoch.path),
                problem=self.epoch.recovered_from,
                epoch=self.epoch.epoch,
            )
        # paper section 4.1: the passive timer is drawn from the link quality at start
        first = await self.monitor.poll()
        now = loop.time()
        spdp_auth = self._spdp_auth = SpdpAuth(self.keyring, self.epoch.epoch, now)
        loaded = load_windows(self._windows_path)
        restored = spdp_auth.verifier.restore(loaded.highs)
        if loaded.problem is not None:
            self.log.warning(
                "auth_windows_recovered", path=str(self._windows_path), problem=loaded.problem
            )
        if restored:
            self.log.info("auth_windows_restored", senders=restored)
        try:
            self.engine = DiscoveryEngine(
                self.bundle,
                self.config.node,
                config=self.engine_config,
                rng=self.rng,
                now=now,
                local_ipv4=self.local_ipv4,
                wallclock=time.time,  # INFO_TS only; every deadline uses loop.time()
                link=first,
                # every SPDP datagram signed and verified (docs/security.md)
                auth=spdp_auth,
            )
        except ValueError as exc:
            problem, _, fix = str(exc).partition("; fix: ")
            raise self.config.error("node", problem, fix or "check node and the bundle") from None
        self.driver = Driver(
            self.engine,
            transmit=self._send,
            on_event=self._on_event,
            name="discovery",
            log=self.log,
            on_core_error=lambda: self.count("engine_exceptions"),
        )
        # the engine's passive clock runs from here (paper section 4.1): what only the
        # swarm layer, the relay and the control socket need (PX4 link, pymavlink, the data
        # plane) is imported now, inside that window, not before it (docs/benchmarks.md,
        # "Daemon start-up"); their refusals below still come before READY=1
        from swarmd.swarmapp import SwarmApp

        # before the first datagram can arrive: peers discovered while it starts are kept
        # and replayed to the data plane once it is up
        app = SwarmApp(
            self.config,
            self.bundle,
            log=self.log,
            link_q=self._link_q,
            keys=self.keyring,  # user data is MAC'd per pair and bound to epochs
            epoch=self.epoch.epoch,
            node_secrets=self._secrets,
            writer=self.writer,
            px4_socket=px4_listen_socket(
                self.config.px4,
                os.environ if self._listen_env is None else self._listen_env,
                self.log,
            ),
            # the epoch file held one: a missing state file was deleted (state_file_missing)
            booted_before=self.epoch.stored is not None,
        )
        self.app = app
        app.on_peer_traffic = self._peer_traffic
        group, mport = self.engine.spdp_multicast
        uport = self.engine.metatraffic_port
        try:
            spdp = open_spdp_socket(group, mport, self.local_ipv4)
        except OSError as exc:
            raise StartupError(
                f"cannot join {group}:{mport} on {self.config.interface} "
                f"({self.local_ipv4}): {exc.strerror}",
                EX_OSERR,
            ) from None
        try:
            unicast = open_unicast_socket(uport, self.local_ipv4)
        except OSError as exc:
            spdp.close()
            raise StartupError(
                f"cannot bind metatraffic port {uport}: {exc.strerror} "
                "(is another participant with the same bundle index running?)",
                EX_OSERR,
            ) from None
        for name, sock in (("multicast", spdp), ("unicast", unicast)):
            self._transports[name] = BatchedSocket(
                sock, name, self.datagrams_received, self.count, loop
            )
        granted = spdp.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF)
        if rcvbuf_capped(granted):
            # a smaller buffer overflows sooner under a flood, and the kernel then drops
            # real renewals with the forgeries (docs/security.md, "Flood")
            self.log.warning(
                "spdp_receive_buffer_capped",
                granted=granted,
                wanted=RECV_BUFFER_BYTES,
                fix="sysctl net.core.rmem_max=4194304 (docs/deploy.md)",
            )
        if self.config.ros2.relay:
            from swarmd.ros2app import Ros2App  # relay configs only

            try:
                self.ros2 = Ros2App(
                    self.config,
                    self.bundle,
                    epoch=self.epoch.epoch,
                    log=self.log,
                    count=self.count,
                    on_liveness=self._ros2_liveness,
                )
                self.ros2.start(loop)
                # every DATA(p) carries our nodes' liveness from the first (PID 0x8A06)
                self._ros2_liveness(self.ros2.relay.liveness())
            except (StartupError, ConfigError):
                await self._close_transports()
                raise
        try:
            await app.start()
        except StartupError:
            self.app = None
            await self._close_transports()
            raise
        from swarmd.control import ControlServer

        self._control = ControlServer(
            self.config.control_socket,
            {
                "status": lambda _r: self.status(),
                "peers": lambda _r: self.status()["peers"],
                "ping": lambda _r: "pong",
                "readiness": lambda _r: app.table.rows(loop.time()),
                "outcomes": app.request_outcomes,
            },
            # the state-changing requests: logged with who sent them (SO_PEERCRED)
            sender_handlers={
                "takeoff": app.request_takeoff,
                "command": app.request_command,
            },
            mode=self.config.control_socket_mode,
        )
        try:
            await self._control.start()
        except (OSError, RuntimeError) as exc:
            self._control = None
            await app.stop()
            await self._close_transports()
            raise StartupError(
                f"control socket {self.config.control_socket}: {exc}", EX_UNAVAILABLE
            ) from None
        self._link_task = loop.create_task(self._poll_link(), name="swarmd-link")
        self._drive().drain()
        self._status_line = self._status_text()
        self._ready = True
        self.notifier.ready(self._status_line)
        if self.watchdog_s is not None:
            self._watchdog = loop.call_later(self.watchdog_s, self._watchdog_tick)
        self._windows_timer = loop.call_later(SAVE_PERIOD_S, self._windows_tick)
        self.log.info(
            "started",
            version=__version__,
            node=self.config.node,
            swarm=self.bundle.swarm,
            interface=self.config.interface,
            ipv4=self.local_ipv4,
            spdp=f"{group}:{mport}",
            metatraffic_port=uport,
            link=first.source if first else None,
            q=first.q if first else None,
            watchdog_s=self.watchdog_s,
            role="commander" if app.is_commander else "member",
            dataplane=self.config.dataplane.enabled,
            px4=self.config.px4.connection if self.config.px4.enabled else None,
        )
        # after start-up, so a failed start stays one line: a warning, not a refusal
        mode_problem = config_mode_problem(self.config.file)
        if mode_problem is not None:  # docs/deploy.md: 0640 root:swarmd
            self.log.warning("config_mode", path=self.config.file, problem=mode_problem)

    def check_start(self) -> KeyRing:
        """The start-up checks that neither bind, send nor write: the node is a member, its
        address is the bundle's pin, its key is the bundle's, and a relay has a ROS 2 graph
        to serve. ``start`` runs them first; ``swarmd check-config`` runs them alone
        (docs/operations.md, "Exit codes"), so it refuses what ``run`` refuses, with
        the same one line. Raises ``ConfigError``; returns this node's key ring."""
        me = self.config.member_of(self.bundle)  # ConfigError at `node` if it is not
        if me.ipv4 is not None and me.ipv4 != self.local_ipv4:
            # every peer refuses a DATA(p) whose locators name another address than the
            # bundle's pin (docs/security.md, "Pinned addresses"): we would never be found
            field = "network.ipv4" if self.config.ipv4 is not None else "network.interface"
            raise self.config.error(
                field,
                f"this node announces {self.local_ipv4}, but the bundle "
                f"{self.config.bundle.path} pins {me.name} at ipv4 {me.ipv4}",
                f"give {self.config.interface} the address {me.ipv4} (network.ipv4), or "
                f"rebuild the bundle with ipv4: {self.local_ipv4} for {me.name}",
            )
        if self.config.ros2.relay:
            from swarmd.ros2app import require_ros2_graph  # relay configs only

            require_ros2_graph(self.config, self.bundle)
        try:
            return KeyRing.from_bundle(self.bundle, self.config.node, self._secrets)
        except NodeKeyMismatch as exc:
            raise self.config.error("bundle.node_key", str(exc), "re-flash this node") from None

    def _plan_epoch(self, user: DaemonUser) -> EpochResult:
        """``plan_epoch`` (read only) with ``start``'s one line and exit code (73)."""
        try:
            return plan_epoch(self._state_dir, self.config.node, time.time(), user)
        except EpochError as exc:
            raise StartupError(str(exc), EX_CANTCREAT) from None

    def check_state(self, keyring: KeyRing, user: DaemonUser) -> list[str]:
        """What ``start`` writes and builds after ``check_start``, judged by reading only
        (``swarmd check-config``, docs/operations.md): the boot epoch's folder (node.key's)
        safe and writable by ``user`` and its epoch not exhausted (``plan_epoch``, which
        ``next_epoch`` runs first); the swarm layer's PX4 link and data plane
        (``SwarmApp.check``). Each refusal is ``start``'s own one-line ``StartupError``, from
        the same function. Sockets stay out: binding one is its only test. Returns what
        ``start`` would warn about and go on."""
        from swarmd.swarmapp import SwarmApp

        planned = self._plan_epoch(user)
        app = SwarmApp(
            self.config,
            self.bundle,
            log=self.log,
            link_q=self._link_q,
            keys=keyring,
            epoch=planned.epoch,
            node_secrets=self._secrets,
        )
        return app.check(user)

    async def stop(self, reason: str = "stop") -> None:
        """Tell every peer we leave (DATA(p[UD])), then release everything."""
        if self.stopped.is_set():
            return
        self.stopped.set()
        self.notifier.stopping("stopping: " + reason)
        if self._watchdog is not None:
            self._watchdog.cancel()
        if self._windows_timer is not None:
            self._windows_timer.cancel()
        self._save_windows()
        if self._link_task is not None:
            self._link_task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._link_task
        if self.engine is not None and self.driver is not None:
            self.driver.call(self.engine.shutdown)  # DATA(p[UD]) leaves now
            self.driver.close()
        if self.app is not None:
            await self.app.stop()
        # the last windows and state written before we exit (systemd's stop waits for us)
        await self.writer.flush()
        if self._control is not None:
            await self._control.close()
        await self._close_transports()
        self.monitor.close()
        self.notifier.close()
        self.log.info("stopped", reason=reason)

    async def _close_transports(self) -> None:
        if self.ros2 is not None:
            self.ros2.close()  # no dispose: the nodes keep their peers (docs/ros2.md)
        if self.driver is not None:
            self.driver.close()  # no timer may fire into a daemon that failed or stopped
        for transport in self._transports.values():
            transport.close()
        self._transports.clear()
        await asyncio.sleep(0)  # let anything the sockets' last batch queued run

    # -- the adapter (rule 11) -----------------------------------------------------------

    def datagrams_received(self, batch: list[Datagram], via: str) -> None:
        if self.driver is None or self.stopped.is_set():
            return
        name = f"rx_{via}"
        self.counters[name] = self.counters.get(name, 0) + len(batch)
        self.driver.datagrams_received(batch)

    async def _poll_link(self) -> None:
        engine, driver = self._core(), self._drive()
        while True:
            await asyncio.sleep(self.config.link.poll_interval_s)
            sample = await self.monitor.poll()
            if sample is not None and not self.stopped.is_set():
                driver.call(partial(engine.update_link_quality, sample))

    def _send(self, datagram: Datagram) -> None:
        out = self._transports.get("unicast")
        if out is None:
            self.count("tx_dropped_closed")
            return
        out.sendto(*datagram)

    def _save_windows(self) -> None:
        """Persist the SPDP replay windows if one moved (swarmd.auth.windows): encoded now,
        written on the writer's thread (swarmd.filewriter); a newer save replaces one not
        started yet, and a failed one is tried again next period."""
        auth = self._spdp_auth
        if auth is None or not auth.verifier.windows_changed:
            return
        auth.verifier.windows_changed = False  # a window moving during the write: next time
        path, data = self._windows_path, encode_windows(auth.verifier.snapshot())
        self.writer.submit("auth_windows", partial(write_windows, path, data), self._windows_saved)

    def _windows_saved(self, error: Exception | None) -> None:
        """On the loop: the writer ended a save of the windows."""
        auth = self._spdp_auth
        if error is None or auth is None:
            return
        auth.verifier.windows_changed = True  # try again next period
        self.count("auth_windows_save_errors")
        self.log.warning("auth_windows_save_failed", path=str(self._windows_path), error=str(error))

    def _windows_tick(self) -> None:
        self._save_windows()
        if self._loop is not None and not self.stopped.is_set():
            self._windows_timer = self._loop.call_later(SAVE_PERIOD_S, self._windows_tick)


async def run(
    config: DaemonConfig,
    bundle: Bundle,
    *,
    log: Any,
    env: Mapping[str, str] | None = None,
    sources: list[LinkSource] | None = None,
    node_secrets: NodeSecrets | None = None,
) -> int:
    """Run until SIGTERM/SIGINT; the exit code. Config/start-up errors propagate."""
    daemon = Daemon(config, bundle, log=log, env=env, sources=sources, node_secrets=node_secrets)
    loop = asyncio.get_running_loop()
    stop = asyncio.Event()
    reasons: list[str] = []

    def on_signal(name: str) -> None:
        reasons.append(name)
        stop.set()

    for sig in (signal.SIGTERM, signal.SIGINT):
        loop.add_signal_handler(sig, on_signal, sig.name)
    try:
        try:
            await daemon.start()
        except BaseException:
            await daemon.stop("start-up failed")
            raise
        await stop.wait()
        await daemon.stop(reasons[0] if reasons else "stop")
    finally:
        for sig in (signal.SIGTERM, signal.SIGINT):
            loop.remove_signal_handler(sig)
    return 0
