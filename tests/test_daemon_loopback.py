"""The asyncio adapter, in-process: two daemons on the host loopback, real UDP sockets.

A per-process domain id keeps parallel runs apart. Waiting for a condition (with a
generous cap) is not a timing assertion: the tests assert states and counters only.
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import socket
from collections.abc import AsyncIterator, Callable, MutableMapping
from pathlib import Path
from typing import Any

import pytest
import structlog
from structlog.testing import capture_logs

from swarmd.auth import windows as windows_mod
from swarmd.auth.freshness import Freshness
from swarmd.bundle.model import EndpointKind
from swarmd.config import ConfigError, load_config
from swarmd.control import request
from swarmd.daemon import Daemon
from swarmd.dataplane.types import Readiness
from swarmd.discovery import engine as engine_module
from swarmd.rawclock import run_on_raw_clock
from tests.attacker import forge
from tests.daemon_support import (
    BundleFiles,
    in_process_daemon,
    loopback_daemon,
    run_domain,
    swarm_sections,
    write_bundle,
    write_config,
)

WAIT_S = 20.0


@pytest.fixture
def files(workdir: Path) -> BundleFiles:
    return write_bundle(workdir, 2, domain_id=run_domain(), lease_s=20.0)


def _daemon(workdir: Path, files: BundleFiles, node: str, *, dataplane: bool = False) -> Daemon:
    # the swarm's data plane on the user port, no vehicle (its readiness says so)
    extra = swarm_sections(workdir / f"state-{node}", None, period_s=0.5) if dataplane else ""
    return loopback_daemon(workdir, files, node, extra=extra)


def _start_error(daemon: Daemon) -> str:
    """The ConfigError a daemon's start-up stops with (stopped either way)."""

    async def main() -> None:
        try:
            await daemon.start()
        finally:
            await daemon.stop("test")

    with pytest.raises(ConfigError) as info:
        run_on_raw_clock(main())
    return str(info.value)


async def _until(cond: Callable[[], bool], what: str | Callable[[], str]) -> None:
    loop = asyncio.get_running_loop()
    deadline = loop.time() + WAIT_S
    while not cond():
        if loop.time() > deadline:
            raise AssertionError(f"gave up waiting for {what if isinstance(what, str) else what()}")
        await asyncio.sleep(0.05)


def _peer(status: dict[str, Any], name: str) -> dict[str, Any]:
    return next(p for p in status["peers"] if p["name"] == name)


@contextlib.asynccontextmanager
async def _discovered_pair(
    workdir: Path, files: BundleFiles
) -> AsyncIterator[tuple[Daemon, Daemon]]:
    """uav1 and uav2 started and discovered by each other; both stopped on the way out."""
    a, b = _daemon(workdir, files, "uav1"), _daemon(workdir, files, "uav2")
    await a.start()
    await b.start()
    try:
        await _until(
            lambda: (
                _peer(a.status(), "uav2")["state"] == "discovered"
                and _peer(b.status(), "uav1")["state"] == "discovered"
            ),
            "mutual discovery",
        )
        yield a, b
    finally:
        await a.stop("test")
        await b.stop("test")


def test_two_daemons_discover_each_other_survive_garbage_and_see_a_clean_leave(
    workdir: Path, files: BundleFiles
) -> None:
    async def main() -> None:
        with capture_logs() as logs:
            async with _discovered_pair(workdir, files) as (a, b):
                st = a.status()
                assert st["node"] == "uav1"
                assert st["peers_discovered"] == 1
                peer = _peer(st, "uav2")
                # ready and outcome (uav2 -> uav1), command (uav1 -> uav2)
                assert peer["matched_endpoints"] == 3
                assert peer["locator"] == f"udp/127.0.0.1:{b.engine.metatraffic_port}"  # type: ignore[union-attr]
                assert st["link"]["source"] == "static"
                assert st["daemon"]["healthy"]
                control = {k: v for k, v in st["counters"]["daemon"].items() if "control" in k}
                assert control == {
                    "control_clients_refused": 0,
                    "control_clients_idle_closed": 0,
                    "control_clients_slow_closed": 0,
                }

                # garbage on both of a's ports: counted, dropped, a keeps running. The SPDP
                # port is shared (SO_REUSEPORT), so the kernel may hand those to b instead.
                def garbage_drops() -> int:
                    return sum(
                        v
                        for d in (a, b)
                        for k, v in d.status()["counters"]["dropped"].items()
                        if k != "own"
                    )

                before, rx_before = garbage_drops(), a.counters.get("rx_unicast", 0)
                junk = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
                _, mport = a.engine.spdp_multicast  # type: ignore[union-attr]
                payloads = (b"", b"RTPS", b"\xff" * 300, b"RTPS\x02\x03" + b"\x00" * 40)
                for payload in payloads:
                    junk.sendto(payload, ("127.0.0.1", a.engine.metatraffic_port))  # type: ignore[union-attr]
                    junk.sendto(payload, ("127.0.0.1", mport))
                junk.close()
                await _until(
                    lambda: (
                        a.counters.get("rx_unicast", 0) >= rx_before + len(payloads)
                        # >=: a legitimate frame may also be dropped meanwhile (e.g. a
                        # renewal racing the stop); the garbage itself must all be counted
                        and garbage_drops() >= before + 2 * len(payloads)
                    ),
                    lambda: f"garbage counted: {a.status()['counters']}",
                )
                assert a.counters.get("engine_exceptions", 0) == 0
                assert a.status()["daemon"]["healthy"]

                # the control socket answers the same status
                reply = await asyncio.to_thread(request, str(workdir / "uav1.sock"), "status")
                assert reply["node"] == "uav1"
                assert _peer(reply, "uav2")["state"] == "discovered"

                # a clean stop sends DATA(p[UD]): the peer drops it at once, not after the lease
                await b.stop("test")
                await _until(lambda: _peer(a.status(), "uav2")["state"] == "lost", "uav2 lost")
        events = [e["event"] for e in logs]
        assert "started" in events
        assert "peer_discovered" in events
        lost = [e for e in logs if e["event"] == "peer_lost"]
        assert lost[0]["peer"] == "uav2"
        assert lost[0]["reason"] == "disposed"

    run_on_raw_clock(main())
    assert not os.path.exists(workdir / "uav1.sock")


def test_a_large_swarms_leave_is_heard_from_the_group_copies_alone(
    workdir: Path, files: BundleFiles, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Above MAX_DISPOSE_UNICAST discovered peers a leave sends no directed dispose: the
    group copies, over real sockets, drop the leaver at once (docs/discovery.md, "Leaving").
    The cap is lowered to 0 so two daemons stand for a large swarm."""
    monkeypatch.setattr(engine_module, "MAX_DISPOSE_UNICAST", 0)

    async def main() -> None:
        with capture_logs() as logs:
            async with _discovered_pair(workdir, files) as (a, b):
                engine = b.engine
                assert engine is not None
                sent = engine.counters()
                await b.stop("test")
                after = engine.counters()
                copies = engine_module.DISPOSE_MULTICAST_COPIES
                assert after["tx_kind"]["dispose"] - sent["tx_kind"]["dispose"] == copies
                assert after["tx_unicast"] == sent["tx_unicast"]
                await _until(lambda: _peer(a.status(), "uav2")["state"] == "lost", "uav2 lost")
        lost = [e for e in logs if e["event"] == "peer_lost"]
        assert [(e["peer"], e["reason"]) for e in lost][:1] == [("uav2", "disposed")]

    run_on_raw_clock(main())


def test_unknown_node_is_a_config_error_naming_the_node_line(
    workdir: Path, files: BundleFiles
) -> None:
    daemon = _daemon(workdir, files, "uav9")

    async def main() -> None:
        try:
            await daemon.start()
        finally:
            await daemon.stop("test")

    with pytest.raises(ConfigError, match=r"uav9.yaml:1: field node: .*uav9"):
        run_on_raw_clock(main())


def test_an_address_other_than_the_bundles_pin_stops_start_up_naming_the_fix(
    workdir: Path,
) -> None:
    """Its peers would refuse every DATA(p) it sends (the pin binds its locators): one line
    naming the config file, the field, the bundle's pin and the fix, before any socket."""
    pinned = write_bundle(
        workdir, 2, domain_id=run_domain(), ipv4=["127.0.0.1", "127.0.0.2"], swarm="pinned"
    )
    daemon = _daemon(workdir, pinned, "uav2")  # announces 127.0.0.1, pinned at 127.0.0.2

    line = _start_error(daemon)
    assert "\n" not in line
    assert line.startswith(f"{workdir / 'uav2.yaml'}:") and "field network.ipv4:" in line
    assert "127.0.0.2" in line and str(pinned.path) in line
    # the control: uav1 is pinned at the 127.0.0.1 it announces, and starts
    uav1 = _daemon(workdir, pinned, "uav1")

    async def control() -> None:
        try:
            await uav1.start()
        finally:
            await uav1.stop("test")

    run_on_raw_clock(control())


def test_missing_interface_is_a_config_error(workdir: Path, files: BundleFiles) -> None:
    cfg = write_config(
        workdir / "c.yaml", files, node="uav1", interface="nosuchif0", socket_path="/x"
    )
    with pytest.raises(ConfigError, match=r"c.yaml:7: field network.interface: no interface"):
        Daemon(load_config(cfg), files.bundle, log=structlog.get_logger(), env={})


def test_a_datagram_flood_rebuilds_no_status(workdir: Path, files: BundleFiles) -> None:
    """The status snapshot is evaluated when swarmctl asks, never per datagram: a flood of
    garbage moves the drop counters and nothing else (it used to rebuild the whole status,
    O(N log N), for every datagram: the amplifier of a flood)."""

    async def main() -> None:
        a = _daemon(workdir, files, "uav1")
        await a.start()
        try:
            engine = a.engine
            assert engine is not None
            calls: list[str] = []
            for name in ("status", "peers", "peer_counts", "foreign"):
                real = getattr(engine, name)

                def spy(*args: Any, _real: Any = real, _name: str = name) -> Any:
                    calls.append(_name)
                    return _real(*args)

                setattr(engine, name, spy)  # a spy: counts the calls, changes nothing
            rx_before = a.counters.get("rx_unicast", 0)
            junk = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            for i in range(300):
                junk.sendto(
                    b"RTPS\x02\x03" + bytes([i % 256]) * 40, ("127.0.0.1", engine.metatraffic_port)
                )
            junk.close()
            await _until(
                lambda: a.counters.get("rx_unicast", 0) >= rx_before + 300,
                lambda: f"flood received: {a.counters}",
            )
            # no snapshot at all; the sd_notify line's peer count only on discovery's own
            # events (a phase change may fall in the window), never once per datagram
            assert [c for c in calls if c != "peer_counts"] == []
            assert calls.count("peer_counts") < 10
            a.status()  # asked: evaluated now
            assert "status" in calls
        finally:
            await a.stop("test")

    run_on_raw_clock(main())


def test_a_forged_user_data_flood_is_read_in_batches_and_moves_nothing(
    workdir: Path, files: BundleFiles
) -> None:
    """Attacker-style, in-process: 200 readiness datagrams claiming uav2 (discovered, its
    data plane up), with both real epochs and a fresh sequence but a MAC under the
    attacker's own key, queued on the commander's user port before its loop can read:
    every one counted ``auth_failed`` and nothing else, uav2's readiness row untouched, and
    read in far fewer wake-ups than datagrams (it was one loop turn per datagram)."""
    n = 200

    async def main() -> None:
        a = _daemon(workdir, files, "uav1", dataplane=True)
        b = _daemon(workdir, files, "uav2", dataplane=True)
        await a.start()
        await b.start()
        try:
            assert a.app is not None and a.epoch is not None and b.epoch is not None
            await _until(
                lambda: (
                    _peer(a.status(), "uav2")["state"] == "discovered"
                    and _peer(b.status(), "uav1")["state"] == "discovered"
                    and a.status()["readiness"]["uav2"]["peer_up"]
                ),
                lambda: f"uav2 up at uav1: {a.status()['readiness']}",
            )
            bundle = files.bundle
            commander, member = bundle.participant("uav1"), bundle.participant("uav2")
            ready = bundle.topic("swarm/ready").index
            forged = Readiness("uav2", 999_999, True, "", False, 1, 3, 12, 77, 800)
            datagrams = [
                forge.mac(
                    forge.forged_readiness(
                        member.guid_prefix,
                        commander.guid_prefix,
                        writer=forge.entity(ready, EndpointKind.WRITER),
                        reader=forge.entity(ready, EndpointKind.READER),
                        sn=forge.JUMP_SN + i,
                        sample=forged,
                    ),
                    pair_key=bytes(range(32)),  # the attacker's own, in no bundle
                    freshness=Freshness(b.epoch.epoch, 1_000_000 + i),
                    receiver=commander.guid_prefix,
                    receiver_epoch=a.epoch.epoch,
                )
                for i in range(n)
            ]
            user_socket = a.app.socket
            assert user_socket is not None
            wakeups: list[object] = []
            real_sink = user_socket.sink

            def counting_sink(*args: Any) -> None:  # a spy: counts, changes nothing
                wakeups.append(args)
                real_sink(*args)

            user_socket.sink = counting_sink
            counters = a.status()["dataplane"]["counters"]
            before = {k: v for k, v in counters.items() if k.startswith("dropped_")}
            target = ("127.0.0.1", bundle.user_port(commander))
            attacker = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            for datagram in datagrams:  # no await: all queued before the loop reads
                attacker.sendto(datagram, target)
            attacker.close()

            def dropped() -> dict[str, int]:
                now = a.status()["dataplane"]["counters"]
                return {
                    k: v - before.get(k, 0)
                    for k, v in now.items()
                    if k.startswith("dropped_") and v != before.get(k, 0)
                }

            await _until(
                lambda: dropped().get("dropped_auth_failed", 0) >= n,
                lambda: f"forgeries counted: {dropped()}",
            )
            assert dropped() == {"dropped_auth_failed": n}
            row = a.status()["readiness"]["uav2"]
            assert row["seq"] != forged.seq and row["battery_pct"] != 77, row
            # the flood plus uav2's own 2 Hz readiness meanwhile, a few batches each way
            assert len(wakeups) < n // 4, len(wakeups)
        finally:
            await a.stop("test")
            await b.stop("test")

    run_on_raw_clock(main())


def test_ros2_relay_without_a_ros2_graph_is_a_config_error(
    workdir: Path, files: BundleFiles
) -> None:
    cfg = write_config(
        workdir / "r.yaml",
        files,
        node="uav1",
        interface="lo",
        ipv4="127.0.0.1",
        socket_path=str(workdir / "r.sock"),
        extra="ros2:\n  relay: true\n",
    )
    # a bundle whose mission has no ros2: section
    daemon = in_process_daemon(load_config(cfg), files.bundle)

    text = _start_error(daemon)
    assert "\n" not in text and "field ros2.relay: " in text
    assert "no ROS 2 graph" in text and "; fix: " in text


def test_replay_windows_are_saved_at_stop_and_restored_at_start(
    workdir: Path, files: BundleFiles
) -> None:
    """Issue 18: the SPDP replay windows live in the state directory (beside the epoch): a
    restarted daemon refuses the datagrams it had passed before, as replays."""

    async def main() -> None:
        with capture_logs() as logs:
            async with _discovered_pair(workdir, files) as (a, _b):
                path = a._windows_path
                auth = a._spdp_auth
                assert auth is not None
                heard = auth.verifier.snapshot()
            # stopped: the file holds uav2's highest freshness, and only bundle senders
            saved = windows_mod.load_windows(path)
            assert saved.problem is None and saved.highs
            assert set(saved.highs) <= {p.guid_prefix.value for p in files.bundle.participants}
            assert all(saved.highs[p] >= f for p, f in heard.items())
            again = _daemon(workdir, files, "uav1")
            await again.start()
            try:
                restored = again._spdp_auth
                assert restored is not None
                assert restored.verifier.snapshot() == saved.highs
            finally:
                await again.stop("test")
        assert any(e["event"] == "auth_windows_restored" for e in logs)

    run_on_raw_clock(main())


@pytest.mark.parametrize("raw", [True, False])
def test_a_daemon_on_a_slewable_loop_clock_says_so(
    workdir: Path, files: BundleFiles, raw: bool
) -> None:
    """The validity proof rests on CLOCK_MONOTONIC_RAW (docs/dataplane.md, "Validity"):
    ``swarmd run`` drives the daemon on it; an embedder that drives it with
    ``asyncio.run`` (CLOCK_MONOTONIC, slewed by NTP) gets one ``loop_clock_slewable``
    warning, and the raw loop none."""
    daemon = _daemon(workdir, files, "uav1")

    async def main() -> list[MutableMapping[str, Any]]:
        with capture_logs() as logs:
            try:
                await daemon.start()
            finally:
                await daemon.stop("test")
        return logs

    logs = run_on_raw_clock(main()) if raw else asyncio.run(main())
    warned = [e for e in logs if e["event"] == "loop_clock_slewable"]
    assert len(warned) == (0 if raw else 1), warned
