"""Byte links to a flight controller for asyncio: ``udpin:``, ``udpout:`` and ``serial:``.

Connection strings follow pymavlink/MAVSDK usage (reference section 1.7):

- ``udpin:HOST:PORT``  bind and listen (PX4 SITL sends to 14540+i; mavlink-router's
  ``[UdpEndpoint] Mode=Normal`` sends to us). Replies go only to the address the backend
  pinned (``linkguard.py``), never to whoever sent last: that was issue 10's attack 6.
  The socket is never ``SO_REUSEADDR``: with it, any local user could bind the same address
  with ``SO_REUSEADDR`` and Linux would hand them the autopilot's datagrams (issue 18). It is
  bound here, or adopted from systemd (``swarmd-px4.socket``, ``adopt_udpin``) with the flag
  cleared; a port someone else holds stops start-up with one line naming them
  (``portowner.py``). The XRCE agent's ``udp:`` port goes the same way, with its own unit
  (``swarmd-xrce.socket``, ``XRCE_SOCKET``).
- ``udpout:HOST:PORT`` send to a listener (PX4 SITL listens on 14580+i). The socket is
  *connected* to it, so the kernel drops datagrams from any other source, and bound to an
  ephemeral port, so the peer learns us from our first heartbeat.

Every datagram reaches ``on_bytes(data, "host:port")`` with its source; a serial link passes
``None`` (one wire, no addresses).

``is_network_endpoint`` says whether a UDP endpoint reaches beyond this host (the config
refuses those unless the operator opts in: issue 10, "never 0.0.0.0").
- ``serial:DEVICE:BAUD`` e.g. ``serial:/dev/ttyTHS1:921600`` (Jetson J41 UART to TELEM2).
  Opened non-blocking, raw 8N1 without flow control through ``termios`` and read with
  ``loop.add_reader``: no pyserial needed for one UART on Linux.

A link never raises on I/O once open: errors are counted and the last one kept, so the
heartbeat going stale (readiness) is what reports a dead link.
"""

from __future__ import annotations

import array
import asyncio
import errno
import fcntl
import ipaddress
import os
import socket
import struct
import termios
import tty
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Final, Literal, Protocol, cast

from swarmd.px4.portowner import describe, holders

UNPRIVILEGED_PORT_START_FILE: Final = Path("/proc/sys/net/ipv4/ip_unprivileged_port_start")
MAX_TX_BACKLOG: Final = 64 * 1024  # serial bytes queued while the UART drains; more is dropped
SERIAL_REOPEN_S: Final = 1.0  # retry a vanished serial device (USB adapter re-plugged)

Kind = Literal["udpin", "udpout", "serial"]
OnBytes = Callable[[bytes, str | None], None]  # data, source "host:port" (None: serial)


@dataclass(frozen=True, slots=True)
class SocketUnit:
    """The systemd socket unit that holds a link's port from boot (issue 18), for the one
    line that names a squatter and its fix."""

    unit: str  # the unit file, e.g. "swarmd-px4.socket"
    fd_name: str  # its FileDescriptorName=, as LISTEN_FDNAMES names the descriptor
    carries: str  # what a socket bound beside ours would receive instead of swarmd

    def port_fix(self) -> str:
        return (
            f"let systemd hold the port from boot ({self.unit}, docs/px4.md), on a port below "
            "1024 so no other user can bind it"
        )


# MAVLink from the autopilot or mavlink-router (px4.backend: mavlink, udpin:)
PX4_SOCKET: Final = SocketUnit("swarmd-px4.socket", "px4", "the autopilot's datagrams")
# PX4's uxrce_dds_client reaching swarmd as its agent (px4.backend: xrce-agent, udp:): a
# squatter would receive PX4's uORB samples and could answer them as the agent
XRCE_SOCKET: Final = SocketUnit("swarmd-xrce.socket", "xrce", "PX4's uXRCE-DDS traffic")
PORT_FIX: Final = PX4_SOCKET.port_fix()


class BadConnectionString(ValueError):
    """A connection string swarmd cannot use; ``str()`` is one line with the fix."""


@dataclass(frozen=True, slots=True)
class Endpoint:
    kind: Kind
    host: str = ""
    port: int = 0
    device: str = ""
    baud: int = 0

    def __str__(self) -> str:
        if self.kind == "serial":
            return f"serial:{self.device}:{self.baud}"
        return f"{self.kind}:{self.host}:{self.port}"


def parse_connection(text: str, field: str = "px4.connection") -> Endpoint:
    """``udpin:127.0.0.1:14540`` | ``udpout:127.0.0.1:14580`` | ``serial:/dev/ttyTHS1:921600``."""
    example = "udpin:127.0.0.1:14540, udpout:127.0.0.1:14580 or serial:/dev/ttyTHS1:921600"
    kind, sep, rest = text.partition(":")
    if kind.endswith("//"):  # tolerate MAVSDK's udpin:// spelling
        kind = kind[:-2]
    rest = rest.removeprefix("//")
    if not sep or kind not in ("udpin", "udpout", "serial"):
        raise BadConnectionString(
            f"{field}: {text!r} has no known scheme (udpin, udpout, serial); fix: e.g. {example}"
        )
    head, sep, tail = rest.rpartition(":")
    if not sep or not head or not tail.isdigit():
        what = "DEVICE:BAUD" if kind == "serial" else "HOST:PORT"
        raise BadConnectionString(f"{field}: {text!r} is not {kind}:{what}; fix: e.g. {example}")
    number = int(tail)
    if kind == "serial":
        if not hasattr(termios, f"B{number}"):
            raise BadConnectionString(
                f"{field}: baud {number} is not a termios speed; fix: use 57600, 115200 or "
                "921600 (PX4 SER_TEL2_BAUD)"
            )
        return Endpoint("serial", device=head, baud=number)
    lowest = 0 if kind == "udpin" else 1  # udpin port 0: any free port (tests)
    if not lowest <= number < 65536:
        raise BadConnectionString(f"{field}: port {number} is out of range; fix: 1..65535")
    host = head.strip("[]")
    if host == "localhost":
        host = "127.0.0.1"  # addresses are compared as the kernel reports them
    return Endpoint(kind, host=host, port=number)  # type: ignore[arg-type]


def is_network_endpoint(endpoint: Endpoint) -> bool:
    """True when a UDP endpoint listens on or talks to more than this host's loopback.

    A wildcard (``0.0.0.0``, ``::``), a host name or any non-loopback address counts: a
    datagram from the swarm's Wi-Fi could then reach the link.
    """
    if endpoint.kind == "serial":
        return False
    try:
        return not ipaddress.ip_address(endpoint.host).is_loopback
    except ValueError:
        return True  # a name: it may resolve anywhere


def parse_address(text: str, field: str) -> str:
    """``HOST:PORT`` with an IP literal (the form datagram sources are compared in)."""
    head, sep, tail = text.rpartition(":")
    host = head.strip("[]")
    try:
        ipaddress.ip_address(host)
        ok = bool(sep) and tail.isdigit() and 1 <= int(tail) < 65536
    except ValueError:
        ok = False
    if not ok:
        raise BadConnectionString(
            f"{field}: {text!r} is not IP:PORT; fix: e.g. 127.0.0.1:14580 (PX4 SITL's source port)"
        )
    return f"{host}:{int(tail)}"


class ByteLink(Protocol):
    """An open link: send bytes, learn who the peer is, close."""

    def send(self, data: bytes) -> None: ...

    @property
    def peer(self) -> str | None: ...

    def stats(self) -> dict[str, object]: ...

    def close(self) -> None: ...


def unprivileged_port_start(path: Path = UNPRIVILEGED_PORT_START_FILE) -> int:
    """The lowest port any user may bind (``net.ipv4.ip_unprivileged_port_start``, 1024)."""
    try:
        return int(path.read_text())
    except (OSError, ValueError):
        return 1024


def bind_udpin(
    endpoint: Endpoint, inherited: socket.socket | None = None, unit: SocketUnit = PX4_SOCKET
) -> socket.socket:
    """The ``udpin:`` socket: ``inherited`` (from systemd's ``unit``) checked and adopted, or
    bound here.

    Raises ``OSError`` whose ``strerror`` is one line with the cause and the fix: the port is
    held (naming who holds it), or is privileged and we may not bind it. ``inherited`` is ours
    from the call on: closed when it is refused (systemd keeps its own copy).
    """
    if inherited is not None:
        try:
            return adopt_udpin(endpoint, inherited, unit)
        except OSError:
            inherited.close()
            raise
    family = socket.AF_INET6 if ":" in endpoint.host else socket.AF_INET
    sock = socket.socket(family, socket.SOCK_DGRAM)
    try:
        sock.bind((endpoint.host, endpoint.port))  # no SO_REUSEADDR: nobody binds beside us
    except OSError as exc:
        sock.close()
        port = endpoint.port
        if exc.errno == errno.EADDRINUSE:
            who = describe(holders(endpoint.host, port))
            raise OSError(
                errno.EADDRINUSE,
                f"port {port} is held by {who}; fix: stop it, and {unit.port_fix()}",
            ) from None
        if exc.errno == errno.EACCES:
            raise OSError(
                errno.EACCES,
                f"port {port} is below {unprivileged_port_start()}: only root (or "
                f"CAP_NET_BIND_SERVICE) may bind it; fix: start swarmd with {unit.unit}, "
                f"which binds it for us (systemctl start {unit.unit} swarmd, docs/px4.md)",
            ) from None
        raise
    sock.setblocking(False)
    return sock


# SIOCGIFCONF (linux/sockios.h): the IPv4 address of every interface, as struct ifreq
# (name[16], then a struct sockaddr_in in a 24-byte union: 40 bytes on 64-bit Linux)
SIOCGIFCONF: Final = 0x8912
_IFREQ_SIZE: Final = 40
_MAX_INTERFACES: Final = 256
IF_INET6_FILE: Final = Path("/proc/net/if_inet6")


def interface_of(
    sock: socket.socket, address: ipaddress.IPv4Address | ipaddress.IPv6Address
) -> str | None:
    """The interface that holds ``address``, or None (no interface has it as its primary or
    a labelled address). IPv4 is asked through ``sock`` (its network namespace, which may
    not be the calling thread's); IPv6 from ``/proc/net/if_inet6`` (the caller's)."""
    if isinstance(address, ipaddress.IPv6Address):
        try:
            lines = IF_INET6_FILE.read_text().splitlines()
        except OSError:
            return None
        for line in lines:  # hex address, index, prefix length, scope, flags, name
            fields = line.split()
            if len(fields) == 6 and fields[0] == address.exploded.replace(":", ""):
                return fields[5]
        return None
    buf = array.array("B", bytes(_IFREQ_SIZE * _MAX_INTERFACES))
    pointer, size = buf.buffer_info()
    try:
        answer = fcntl.ioctl(sock.fileno(), SIOCGIFCONF, struct.pack("iP", size, pointer))
    except OSError:
        return None
    length = struct.unpack("iP", answer)[0]
    raw = buf.tobytes()[:length]
    for at in range(0, length - _IFREQ_SIZE + 1, _IFREQ_SIZE):
        if raw[at + 20 : at + 24] == address.packed:  # sin_addr, after family and port
            return raw[at : at + 16].split(b"\0", 1)[0].decode("ascii", "replace")
    return None


def bind_to_its_interface(sock: socket.socket) -> str | None:
    """Bind ``sock`` (UDP, bound to one address) to the interface that holds that address
    (``SO_BINDTODEVICE``), so it hears only datagrams that arrive there; the interface's
    name, or None when it stays as it was (loopback or wildcard address, an address no
    interface holds as its own, a kernel that refuses: before Linux 5.7 this takes
    ``CAP_NET_RAW``, which systemd's ``BindToDevice=`` has).

    Why (docs/security-history.md, "This morning's defences reviewed"): Linux accepts a datagram
    for any of its addresses on any interface, and nothing checks the source address of
    one from the Wi-Fi. An agent on the Ethernet address, bound to no interface, hears an
    outsider on the Wi-Fi who writes the FMU's address as the source, and the XRCE key-check
    budget, kept per source address, then spends the FMU's share on the outsider's tries."""
    host = str(sock.getsockname()[0]).removeprefix("::ffff:").partition("%")[0]
    try:
        address = ipaddress.ip_address(host)
    except ValueError:
        return None
    if address.is_loopback or address.is_unspecified:
        return None  # nothing arrives for 127/8 from outside; a wildcard has no one interface
    bound = sock.getsockopt(socket.SOL_SOCKET, socket.SO_BINDTODEVICE, 16).split(b"\0", 1)[0]
    if bound:  # systemd's BindToDevice= (a second bind would take CAP_NET_RAW)
        return bound.decode("ascii", "replace")
    name = interface_of(sock, address)
    if name is None:
        return None
    try:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_BINDTODEVICE, name.encode())
    except OSError:
        return None
    return name


def adopt_udpin(
    endpoint: Endpoint, sock: socket.socket, unit: SocketUnit = PX4_SOCKET
) -> socket.socket:
    """A socket systemd bound for ``endpoint``: check it, clear ``SO_REUSEADDR``, and make
    sure no other socket shares its address (a user who bound beside it before we cleared
    the flag would receive what the port carries: the autopilot's or PX4's datagrams)."""
    where = f"the socket passed as '{unit.fd_name}' ({unit.unit} ListenDatagram=)"
    if sock.type != socket.SOCK_DGRAM or sock.family not in (socket.AF_INET, socket.AF_INET6):
        raise OSError(
            errno.EINVAL,
            f"{where} is not a UDP socket; fix: ListenDatagram={endpoint.host}:{endpoint.port}",
        )
    bound = sock.getsockname()
    host = str(bound[0]).removeprefix("::ffff:")
    if host != endpoint.host or (endpoint.port != 0 and bound[1] != endpoint.port):
        raise OSError(
            errno.EINVAL,
            f"{where} is bound to {host}:{bound[1]}, not {endpoint.host}:{endpoint.port}; fix: "
            "make ListenDatagram= and px4.connection name the same address",
        )
    # systemd sets SO_REUSEADDR on every socket it binds; cleared, nobody can bind beside us
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 0)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEPORT, 0)
    others = holders(endpoint.host, int(bound[1]), exclude_inode=os.fstat(sock.fileno()).st_ino)
    if others:
        raise OSError(
            errno.EADDRINUSE,
            f"port {bound[1]} is also bound by {describe(others)}, which receives "
            f"{unit.carries}; fix: stop it, and {unit.port_fix()}",
        )
    sock.setblocking(False)
    return sock


async def open_link(
    endpoint: Endpoint, on_bytes: OnBytes, *, inherited: socket.socket | None = None
) -> ByteLink:
    """Open ``endpoint``; received bytes go to ``on_bytes`` on the event loop.

    ``inherited``: for ``udpin:``, the socket systemd bound (``bind_udpin``)."""
    if endpoint.kind == "serial":
        link = SerialLink(endpoint, on_bytes)
        link.open()
        return link
    loop = asyncio.get_running_loop()
    if endpoint.kind == "udpin":
        sock = bind_udpin(endpoint, inherited)
        try:
            _, protocol = await loop.create_datagram_endpoint(
                lambda: UdpLink(on_bytes, None), sock=sock
            )
        except BaseException:
            sock.close()
            raise
    else:  # connected: the kernel delivers only the target's datagrams
        remote = (endpoint.host, endpoint.port)
        _, protocol = await loop.create_datagram_endpoint(
            lambda: UdpLink(on_bytes, remote), remote_addr=remote
        )
    return protocol


class UdpLink(asyncio.DatagramProtocol):
    """One UDP socket; ``remote`` fixed (udpout) or set by the backend's pin (udpin)."""

    def __init__(self, on_bytes: OnBytes, remote: tuple[str, int] | None) -> None:
        self._on_bytes = on_bytes
        self._connected = remote is not None
        self._remote = remote
        self._transport: asyncio.DatagramTransport | None = None
        self.rx_datagrams = 0
        self.tx_datagrams = 0
        self.tx_unroutable = 0  # udpin before the autopilot is pinned
        self.errors = 0
        self.last_error: str | None = None

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        # cast, not isinstance: CPython 3.11's selector UDP transport does not subclass
        # DatagramTransport
        self._transport = cast(asyncio.DatagramTransport, transport)

    def datagram_received(self, data: bytes, addr: tuple[str | int, ...] | None) -> None:
        self.rx_datagrams += 1
        if addr is None:  # a connected socket may not say; it can only be the target
            addr = self._remote or ("", 0)
        self._on_bytes(data, f"{addr[0]}:{addr[1]}")

    def set_remote(self, address: str | None) -> None:
        """Where replies go (udpin): the pinned autopilot, or nowhere (None)."""
        if self._connected:
            return  # udpout: the target, for good
        if address is None:
            self._remote = None
            return
        host, _, port = address.rpartition(":")
        self._remote = (host, int(port))

    def error_received(self, exc: Exception) -> None:
        # ICMP port unreachable on loopback when the peer is not up yet: harmless
        self.errors += 1
        self.last_error = str(exc)

    def send(self, data: bytes) -> None:
        if self._transport is None or self._transport.is_closing() or self._remote is None:
            self.tx_unroutable += 1
            return
        if self._connected:
            self._transport.sendto(data)  # connected socket: no address allowed
        else:
            self._transport.sendto(data, self._remote)
        self.tx_datagrams += 1

    @property
    def peer(self) -> str | None:
        return None if self._remote is None else f"{self._remote[0]}:{self._remote[1]}"

    @property
    def local_port(self) -> int | None:
        if self._transport is None:
            return None
        port: int = self._transport.get_extra_info("sockname")[1]
        return port

    def stats(self) -> dict[str, object]:
        return {
            "peer": self.peer,
            "rx_datagrams": self.rx_datagrams,
            "tx_datagrams": self.tx_datagrams,
            "tx_unroutable": self.tx_unroutable,
            "errors": self.errors,
            "last_error": self.last_error,
        }

    def close(self) -> None:
        if self._transport is not None:
            self._transport.close()


class SerialLink:
    """A raw UART through ``termios`` and ``add_reader``/``add_writer`` (no threads)."""

    def __init__(self, endpoint: Endpoint, on_bytes: OnBytes) -> None:
        self.endpoint = endpoint
        self._on_bytes = on_bytes
        self._loop = asyncio.get_running_loop()
        self._fd: int | None = None
        self._backlog = bytearray()
        self._reopen: asyncio.TimerHandle | None = None
        self._closed = False
        self.rx_bytes = 0
        self.tx_bytes = 0
        self.tx_dropped = 0
        self.errors = 0
        self.last_error: str | None = None

    def open(self) -> None:
        """Open and configure the device; raises OSError on the first attempt only."""
        fd = os.open(self.endpoint.device, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
        try:
            configure_raw(fd, self.endpoint.baud)
        except (OSError, termios.error):
            os.close(fd)
            raise
        self._fd = fd
        self._loop.add_reader(fd, self._readable)

    def _readable(self) -> None:
        fd = self._fd
        if fd is None:
            return
        try:
            data = os.read(fd, 4096)
        except BlockingIOError:
            return
        except OSError as exc:  # EIO: the device went away (or a pty's other end closed)
            self._lost(exc)
            return
        if not data:
            return
        self.rx_bytes += len(data)
        self._on_bytes(data, None)

    def send(self, data: bytes) -> None:
        if self._fd is None:
            self.tx_dropped += len(data)
            return
        if self._backlog:
            self._queue(data)
            return
        try:
            n = os.write(self._fd, data)
        except BlockingIOError:
            n = 0
        except OSError as exc:
            self._lost(exc)
            return
        self.tx_bytes += n
        if n < len(data):
            self._queue(data[n:])
            self._loop.add_writer(self._fd, self._writable)

    def _queue(self, data: bytes) -> None:
        if len(self._backlog) + len(data) > MAX_TX_BACKLOG:
            self.tx_dropped += len(data)  # a stuck UART must not grow memory without bound
            return
        self._backlog += data

    def _writable(self) -> None:
        if self._fd is None:
            return
        try:
            n = os.write(self._fd, self._backlog)
        except BlockingIOError:
            return
        except OSError as exc:
            self._lost(exc)
            return
        self.tx_bytes += n
        del self._backlog[:n]
        if not self._backlog:
            self._loop.remove_writer(self._fd)

    def _lost(self, exc: OSError) -> None:
        self.errors += 1
        self.last_error = f"{self.endpoint.device}: {os.strerror(exc.errno or errno.EIO)}"
        self._release()
        if not self._closed:
            self._reopen = self._loop.call_later(SERIAL_REOPEN_S, self._try_reopen)

    def _try_reopen(self) -> None:
        self._reopen = None
        if self._closed:
            return
        try:
            self.open()
        except (OSError, termios.error) as exc:
            self.errors += 1
            self.last_error = f"{self.endpoint.device}: {exc}"
            self._reopen = self._loop.call_later(SERIAL_REOPEN_S, self._try_reopen)

    def _release(self) -> None:
        fd, self._fd = self._fd, None
        self._backlog.clear()
        if fd is not None:
            self._loop.remove_reader(fd)
            self._loop.remove_writer(fd)
            os.close(fd)

    @property
    def peer(self) -> str | None:
        return self.endpoint.device if self._fd is not None else None

    def stats(self) -> dict[str, object]:
        return {
            "peer": self.peer,
            "rx_bytes": self.rx_bytes,
            "tx_bytes": self.tx_bytes,
            "tx_dropped": self.tx_dropped,
            "errors": self.errors,
            "last_error": self.last_error,
        }

    def close(self) -> None:
        self._closed = True
        if self._reopen is not None:
            self._reopen.cancel()
        self._release()


def configure_raw(fd: int, baud: int) -> None:
    """Raw 8N1, no flow control, reads return what is there (VMIN=0, VTIME=0)."""
    tty.setraw(fd)
    attrs = termios.tcgetattr(fd)
    speed = getattr(termios, f"B{baud}")
    attrs[2] = (attrs[2] | termios.CLOCAL | termios.CREAD) & ~termios.CRTSCTS  # cflag
    attrs[4] = attrs[5] = speed  # ispeed, ospeed
    attrs[6][termios.VMIN] = 0
    attrs[6][termios.VTIME] = 0
    termios.tcsetattr(fd, termios.TCSANOW, attrs)
