"""swarmd_lab.netns: isolated LANs of namespaces, built and torn down on every exit path."""

from __future__ import annotations

import socket
import subprocess
import sys
from contextlib import closing

import pytest
from swarmd_lab import netns
from swarmd_lab.netns import Lan, NamespaceRecord, cleanup_stale, list_namespaces, run_prefix

from tests.peers.udp import group_listener, receive_until, unicast_socket

pytestmark = pytest.mark.netns


def host_links() -> set[str]:
    out = subprocess.run(["ip", "-o", "link"], capture_output=True, text=True, check=True).stdout
    return {line.split(":")[1].strip() for line in out.splitlines()}


def ours(prefix: str) -> list[str]:
    return [n for n in list_namespaces() if n.startswith(prefix + "-")]


def test_lan_hosts_reach_each_other_by_multicast_and_unicast() -> None:
    links_before = host_links()
    with Lan(3) as lan:
        assert ours(lan.prefix) == sorted([f"{lan.prefix}-{i}" for i in range(3)] + [lan.hub])
        assert [h.address for h in lan] == [str(lan.network[i]) for i in (1, 2, 3)]
        # nothing of the LAN lives in the host's own namespace
        assert host_links() == links_before
        with (
            closing(group_listener(lan[1])) as rx1,
            closing(group_listener(lan[2])) as rx2,
            closing(unicast_socket(lan[0], 7410)) as tx,
        ):
            tx.sendto(b"hello", ("239.255.0.1", 7400))
            for rx in (rx1, rx2):
                got = receive_until(rx, lambda data, src: (data, src), 5.0)
                assert got == (b"hello", (lan[0].address, 7410))
            tx.sendto(b"direct", (lan[2].address, 7400))
            assert receive_until(rx2, lambda data, src: data, 5.0) == b"direct"
    assert ours(lan.prefix) == []


def test_sockets_are_isolated_per_namespace() -> None:
    with Lan(1) as lan1, Lan(1) as lan2:
        # the same address and port in two LANs: no clash, they are different stacks
        with (
            closing(unicast_socket(lan1[0], 7410)) as a,
            closing(lan2[0].socket()) as b,
        ):
            b.bind(("0.0.0.0", 7410))
            assert a.getsockname()[1] == b.getsockname()[1] == 7410
            # one LAN cannot reach another (no route, or no such neighbour on its bridge)
            with closing(lan1[0].socket(socket.AF_INET, socket.SOCK_STREAM)) as s:
                s.settimeout(1.0)
                assert s.connect_ex((lan2[0].address, 7410)) != 0


@pytest.mark.parametrize("exc", [RuntimeError("boom"), KeyboardInterrupt()])
def test_teardown_on_exception_and_keyboard_interrupt(exc: BaseException) -> None:
    made: list[tuple[Lan, subprocess.Popen[bytes]]] = []

    def work() -> None:
        with Lan(2) as lan:
            made.append((lan, lan[0].popen([sys.executable, "-c", "import time; time.sleep(60)"])))
            raise exc

    with pytest.raises(type(exc)):
        work()
    ((lan, proc),) = made
    assert ours(lan.prefix) == []
    assert proc.poll() is not None  # the child was stopped, not leaked


def test_failed_build_removes_what_it_made() -> None:
    prefix = run_prefix()
    clash = Lan(1, prefix=prefix).__enter__()
    try:
        # building a second LAN with the same names fails half-way and must clean up itself
        with pytest.raises(Exception, match="already exists"), Lan(1, prefix=prefix):
            pass
        assert ours(prefix) == [f"{prefix}-0", f"{prefix}-hub"]
    finally:
        clash.close()
    assert ours(prefix) == []


def test_cleanup_stale_removes_leftovers_only_under_its_prefix() -> None:
    left = Lan(2).__enter__()  # a "crashed" run that never closed its LAN
    with Lan(1) as other:
        removed = cleanup_stale(left.prefix + "-")
        assert sorted(removed) == sorted([f"{left.prefix}-0", f"{left.prefix}-1", left.hub])
        assert ours(left.prefix) == []
        assert ours(other.prefix) != []
    with pytest.raises(ValueError, match="empty prefix"):
        cleanup_stale("")


def test_rejects_bad_sizes_and_subnets() -> None:
    with pytest.raises(ValueError, match="hosts"):
        Lan(0)
    with pytest.raises(ValueError, match="private"):
        Lan(2, subnet="8.8.8.0/24")


def _interrupt_after_netns_add(monkeypatch: pytest.MonkeyPatch, nth: int) -> None:
    """Make the ``nth`` ``ip netns add`` succeed and then raise, as a signal arriving while
    it runs would: the namespace exists, the builder never returned from the call."""
    real = netns._ip
    seen = [0]

    def ip(*args: str, check: bool = True) -> subprocess.CompletedProcess[str]:
        proc = real(*args, check=check)
        if args[:2] == ("netns", "add"):
            seen[0] += 1
            if seen[0] == nth:
                raise KeyboardInterrupt
        return proc

    monkeypatch.setattr(netns, "_ip", ip)


@pytest.mark.parametrize("nth", [1, 2])
def test_a_signal_during_ip_netns_add_leaks_nothing(
    monkeypatch: pytest.MonkeyPatch, nth: int
) -> None:
    prefix = run_prefix()
    _interrupt_after_netns_add(monkeypatch, nth)
    with pytest.raises(KeyboardInterrupt), Lan(2, prefix=prefix):
        pass
    assert ours(prefix) == []


def test_the_wifi_testbed_shares_the_leak_fix(monkeypatch: pytest.MonkeyPatch) -> None:
    # bench/wifi builds per-drone bridges and taps, but its namespaces come from the same
    # NamespaceRecord: interrupted on its second namespace (the first drone), nothing stays
    from bench.wifi.topology import Testbed

    prefix = run_prefix("swf")
    _interrupt_after_netns_add(monkeypatch, 2)
    with pytest.raises(KeyboardInterrupt), Testbed(prefix, 2):
        pass
    assert [n for n in list_namespaces() if n.startswith(prefix + "-")] == []


def test_a_record_deletes_what_it_recorded_newest_first() -> None:
    record = NamespaceRecord()
    prefix = run_prefix()
    try:
        record.add(f"{prefix}-a")
        record.add(f"{prefix}-b")
        assert ours(prefix) == [f"{prefix}-a", f"{prefix}-b"]
        with pytest.raises(netns.NetnsError, match="already exists"):
            record.add(f"{prefix}-a")
    finally:
        record.close()
    assert ours(prefix) == []
    record.close()  # idempotent
