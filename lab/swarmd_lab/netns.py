"""Throw-away network namespaces joined by one Linux bridge, for tests and the demo.

``Lan(n)`` builds, as a context manager::

    <prefix>-hub      bridge br0 + host ends v0..v{n-1} of the veth pairs (no addresses)
    <prefix>-0 .. -{n-1}   eth0 = 10.77.X.(i+1)/24, lo up, route 224.0.0.0/4 dev eth0

Everything, the bridge included, lives in namespaces the ``Lan`` creates, so nothing is
added to the host's own network stack: host firewalls, ``br_netfilter`` and the host's
multicast settings cannot touch the traffic, and deleting the namespaces deletes every
interface with them (a veth dies with either end's namespace). Multicast snooping is off
on the bridge, so a group is flooded to every port whether or not an IGMP querier exists
(there is none on a lab bridge; with snooping on, forwarding would depend on timing).

Names carry a per-run prefix (``swn-<pid>-<counter>`` by default) so parallel runs never
collide, and ``cleanup_stale`` removes what a killed run left behind.

Needs root (CAP_SYS_ADMIN + CAP_NET_ADMIN) and iproute2's ``ip``; ``unavailable_reason()``
says why not, for a clean test skip. This module does I/O on purpose: it is test and demo
tooling, never imported by the sans-IO core.
"""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import ipaddress
import itertools
import os
import shutil
import signal
import socket
import subprocess
import threading
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from typing import IO, Final

from swarmd_lab.closing import Closing

NETNS_DIR: Final = "/run/netns"
DEFAULT_BASE: Final = "swn"  # swarmd netns; distinct from hand-made "swt-*" names
HUB_SUFFIX: Final = "hub"
BRIDGE: Final = "br0"
IFNAME: Final = "eth0"
MULTICAST_NET: Final = "224.0.0.0/4"
MAX_HOSTS: Final = 253  # .1 .. .253 of a /24; .254/.255 stay free
_CLONE_NEWNET: Final = 0x40000000
_IP_TIMEOUT_S: Final = 10.0
_STOP_TIMEOUT_S: Final = 3.0

_counter = itertools.count(1)
# Every namespace a ``NamespaceRecord`` of this process holds (insertion order), so a second
# Ctrl-C can delete them all at once without the records' owners (``delete_recorded``).
_recorded: dict[str, None] = {}


class NetnsError(RuntimeError):
    """An ``ip`` command failed while building or using a namespace."""


def unavailable_reason() -> str | None:
    """Why namespaces cannot be made here (for ``pytest.skip``), or None when they can."""
    if os.geteuid() != 0:
        return "network namespaces need root (run the tests as root, e.g. in the CI container)"
    if shutil.which("ip") is None:
        return "iproute2 'ip' is not installed (apt-get install iproute2; scripts/setup.sh does)"
    return None


def run_prefix(base: str = DEFAULT_BASE) -> str:
    """A prefix unique to this process and call: ``<base>-<pid>-<n>``."""
    return f"{base}-{os.getpid()}-{next(_counter)}"


def _ip(*args: str, check: bool = True) -> subprocess.CompletedProcess[str]:
    proc = subprocess.run(  # noqa: S603 - fixed argv, no shell
        ["ip", *args],  # noqa: S607 - iproute2 is looked up on PATH on purpose
        capture_output=True,
        text=True,
        timeout=_IP_TIMEOUT_S,
        check=False,
    )
    if check and proc.returncode != 0:
        raise NetnsError(f"ip {' '.join(args)}: {proc.stderr.strip() or proc.returncode}")
    return proc


def list_namespaces() -> list[str]:
    """Names of the named network namespaces (``ip netns list``)."""
    try:
        return sorted(os.listdir(NETNS_DIR))
    except FileNotFoundError:
        return []


def _namespace_pids(name: str) -> list[int]:
    proc = _ip("netns", "pids", name, check=False)
    return [int(tok) for tok in proc.stdout.split() if tok.isdigit()]


def _kill_namespace_processes(name: str) -> None:
    # Only processes inside a namespace this module created, so they are ours by construction.
    for pid in _namespace_pids(name):
        with contextlib.suppress(ProcessLookupError, PermissionError):
            os.kill(pid, signal.SIGKILL)


def delete_namespace(name: str) -> None:
    """Kill what still runs in ``name`` and delete it; absent namespaces are fine."""
    if name not in list_namespaces():
        return
    _kill_namespace_processes(name)
    _ip("netns", "delete", name, check=False)


def cleanup_stale(prefix: str) -> list[str]:
    """Delete every namespace whose name starts with ``prefix``; return the names removed.

    Pass a full run prefix (``swn-1234-1``) or ``swn-1234-`` for one dead process; to sweep
    up after any dead run without touching live parallel runs use ``cleanup_dead_runs``.
    """
    if not prefix:
        raise ValueError("refusing to clean up with an empty prefix")
    removed = []
    for name in list_namespaces():
        if name.startswith(prefix):
            delete_namespace(name)
            removed.append(name)
    return removed


def cleanup_dead_runs(base: str = DEFAULT_BASE) -> list[str]:
    """Delete ``<base>-<pid>-*`` namespaces whose creating process no longer exists."""
    removed = []
    for name in list_namespaces():
        parts = name.split("-")
        if len(parts) < 3 or parts[0] != base or not parts[1].isdigit():
            continue
        if not os.path.exists(f"/proc/{parts[1]}"):
            delete_namespace(name)
            removed.append(name)
    return removed


class NamespaceRecord:
    """The namespaces one run creates, for every builder (``Lan``, bench/wifi's ``Testbed``).

    Each name is recorded *before* ``ip netns add`` runs, so a signal arriving while it runs
    cannot leak the namespace; ``close()`` deletes every recorded name, absent ones harmlessly,
    newest first. This is the one place that fix lives.
    """

    def __init__(self) -> None:
        self.names: list[str] = []

    def add(self, name: str) -> None:
        """Create namespace ``name`` with ``lo`` up; ``NetnsError`` if it exists already."""
        if name in list_namespaces():
            raise NetnsError(f"namespace {name} already exists; remove it with cleanup_stale")
        self.names.append(name)
        _recorded[name] = None
        _ip("netns", "add", name)
        _ip("-n", name, "link", "set", "lo", "up")

    def close(self) -> None:
        """Kill what runs in them and delete every recorded namespace (idempotent)."""
        for name in reversed(self.names):
            delete_namespace(name)
            _recorded.pop(name, None)
        self.names.clear()


def delete_recorded() -> list[str]:
    """Kill what runs in, and delete, every namespace this process's records still hold,
    newest first; return the names of those that still existed. For a run that must stop at
    once, or whose records' owners were cut short (Ctrl-C in the test suite,
    tests/interrupt.py)."""
    existing = set(list_namespaces())
    names = list(reversed(_recorded))
    for name in names:
        delete_namespace(name)
        _recorded.pop(name, None)
    return [name for name in names if name in existing]


def add_veth(hub: str, port: str, host: str, ifname: str = IFNAME) -> None:
    """A veth pair: ``port`` in namespace ``hub``, its peer ``ifname`` in namespace ``host``
    (it dies with either namespace, so nothing outlives the run)."""
    _ip("-n", hub, "link", "add", port, "type", "veth", "peer", "name", ifname, "netns", host)


def configure_host(name: str, cidr: str, ifname: str = IFNAME) -> None:
    """``ifname`` of namespace ``name``: address ``cidr``, multicast on, up, and a
    224.0.0.0/4 route on it."""
    _ip("-n", name, "addr", "add", cidr, "dev", ifname)
    _ip("-n", name, "link", "set", ifname, "multicast", "on", "up")
    # Without a default route a multicast send fails with ENETUNREACH unless the socket
    # names an interface; the route makes plain sendto(239.255.0.1) work.
    _ip("-n", name, "route", "add", MULTICAST_NET, "dev", ifname)


def stop_processes(procs: Sequence[subprocess.Popen[bytes]], timeout_s: float) -> None:
    """SIGTERM every process of ``procs`` that still runs (all at once, so daemons leave
    cleanly and tell their peers in parallel), then wait up to ``timeout_s`` for each and
    SIGKILL a straggler (waiting for it again, at most ``timeout_s``)."""
    for proc in procs:
        if proc.poll() is None:
            proc.terminate()
    for proc in procs:
        try:
            proc.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(timeout=timeout_s)


def _setns(fd: int, nstype: int) -> None:
    """setns(2) for the calling thread (``os.setns`` only exists from Python 3.12)."""
    libc = ctypes.CDLL(ctypes.util.find_library("c"), use_errno=True)
    if libc.setns(ctypes.c_int(fd), ctypes.c_int(nstype)) != 0:
        err = ctypes.get_errno()
        raise OSError(err, f"setns: {os.strerror(err)}")


@dataclass(frozen=True, slots=True)
class Namespace:
    """One host on the LAN: a named namespace with ``eth0`` on the bridge."""

    name: str
    address: str  # eth0's IPv4 address
    prefixlen: int
    ifname: str = IFNAME
    _children: list[subprocess.Popen[bytes]] = field(
        default_factory=list, repr=False, compare=False
    )

    def command(self, argv: Sequence[str]) -> list[str]:
        """``argv`` wrapped to run inside this namespace."""
        return ["ip", "netns", "exec", self.name, *argv]

    def run(
        self,
        argv: Sequence[str],
        *,
        timeout: float = 30.0,
        check: bool = True,
        env: Mapping[str, str] | None = None,
    ) -> subprocess.CompletedProcess[str]:
        """Run ``argv`` in this namespace to completion and capture its output as text."""
        return subprocess.run(  # noqa: S603 - argv list, no shell
            self.command(argv),
            capture_output=True,
            text=True,
            timeout=timeout,
            check=check,
            env=None if env is None else dict(env),
        )

    def popen(
        self,
        argv: Sequence[str],
        *,
        env: Mapping[str, str] | None = None,
        stdout: int | IO[bytes] | None = subprocess.DEVNULL,
        stderr: int | IO[bytes] | None = None,
        stdin: int | IO[bytes] | None = subprocess.DEVNULL,
    ) -> subprocess.Popen[bytes]:
        """Start ``argv`` in this namespace; the ``Lan`` stops it on exit if still running."""
        proc = subprocess.Popen(  # noqa: S603 - argv list, no shell
            self.command(argv),
            env=None if env is None else dict(env),
            stdout=stdout,
            stderr=stderr,
            stdin=stdin,
        )
        self._children.append(proc)
        return proc

    def socket(
        self,
        family: socket.AddressFamily = socket.AF_INET,
        type: socket.SocketKind = socket.SOCK_DGRAM,  # noqa: A002 - mirrors socket.socket
        proto: int = 0,
    ) -> socket.socket:
        """A socket of this namespace, usable from the calling (host) thread.

        A socket belongs to the namespace it was created in for life, so a short-lived
        thread enters the namespace (setns(2) acts on the calling thread only), creates the
        socket and ends; the caller's own thread never changes namespace.
        """
        result: list[socket.socket] = []
        errors: list[BaseException] = []

        def create() -> None:
            try:
                fd = os.open(os.path.join(NETNS_DIR, self.name), os.O_RDONLY | os.O_CLOEXEC)
                try:
                    _setns(fd, _CLONE_NEWNET)
                finally:
                    os.close(fd)
                result.append(socket.socket(family, type, proto))
            except BaseException as exc:  # handed to the caller's thread below
                errors.append(exc)

        worker = threading.Thread(target=create, name=f"setns-{self.name}")
        worker.start()
        worker.join()
        if errors:
            raise errors[0]
        return result[0]

    def stop_children(self) -> None:
        """Terminate (then kill) the processes ``popen`` started that still run."""
        stop_processes(self._children, _STOP_TIMEOUT_S)
        self._children.clear()


class Lan(Closing):
    """N namespaces on one bridge; build with ``with Lan(n) as lan:``, torn down on any exit.

    ``lan.hosts[i]`` is host i (address ``.i+1``). Teardown runs on normal exit, on
    exceptions and on KeyboardInterrupt, and also when ``__enter__`` fails half-way.
    """

    def __init__(
        self,
        size: int,
        *,
        prefix: str | None = None,
        subnet: str | None = None,
    ) -> None:
        if not 1 <= size <= MAX_HOSTS:
            raise ValueError(f"a LAN holds 1..{MAX_HOSTS} hosts, not {size}")
        self.prefix = prefix if prefix is not None else run_prefix()
        net = ipaddress.IPv4Network(subnet if subnet is not None else self._default_subnet())
        if net.prefixlen > 24 or not net.is_private:
            raise ValueError(f"LAN subnet {net} must be a private /24 or larger")
        self.network = net
        self.size = size
        self.hub = f"{self.prefix}-{HUB_SUFFIX}"
        self.hosts: list[Namespace] = []
        self._namespaces = NamespaceRecord()

    def _default_subnet(self) -> str:
        # 10.77.X.0/24 with X from the run prefix; the namespaces are isolated from the
        # host and from each other's bridges, so X only has to be readable, not unique.
        return f"10.77.{sum(self.prefix.encode()) % 256}.0/24"

    def _open(self) -> None:
        self._namespaces.add(self.hub)
        _ip("-n", self.hub, "link", "add", BRIDGE, "type", "bridge", "mcast_snooping", "0")
        _ip("-n", self.hub, "link", "set", BRIDGE, "up")
        hosts = list(itertools.islice(self.network.hosts(), self.size))
        for i, address in enumerate(hosts):
            name = f"{self.prefix}-{i}"
            self._namespaces.add(name)
            port = f"v{i}"
            add_veth(self.hub, port, name)
            _ip("-n", self.hub, "link", "set", port, "master", BRIDGE)
            _ip("-n", self.hub, "link", "set", port, "up")
            configure_host(name, f"{address}/{self.network.prefixlen}")
            self.hosts.append(Namespace(name, str(address), self.network.prefixlen))

    def close(self) -> None:
        """Stop child processes and delete every namespace this LAN created (idempotent)."""
        for host in self.hosts:
            host.stop_children()
        self._namespaces.close()

    def __iter__(self) -> Iterator[Namespace]:
        return iter(self.hosts)

    def __getitem__(self, index: int) -> Namespace:
        return self.hosts[index]

    def __len__(self) -> int:
        return len(self.hosts)
