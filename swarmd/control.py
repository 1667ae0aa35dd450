"""The control socket: newline-delimited JSON between ``swarmctl`` and the daemon.

One request per line, one reply per line, any number of requests per connection (``swarmctl
watch`` keeps one open), each line complete within ``REQUEST_DEADLINE_S`` of connecting or of
the last reply, and each reply taken by the client within the same deadline::

    -> {"cmd": "status"}
    <- {"ok": true, "result": {...}}
    <- {"ok": false, "error": "unknown command 'x'; known: peers, ping, status"}
    <- {"ok": false, "error": "swarmd is stopping: ...", "code": "stopping"}

A refusal may carry a ``code`` (only ``STOPPING`` so far): what a client decides on, where
the ``error`` line is only for the operator, so no client matches its words.

The socket is a Unix stream socket (default ``/run/swarmd/swarmd.sock``, mode 0660), so
access is file permissions: root and the ``swarmd`` group. It works over ``ssh drone
swarmctl status`` because swarmctl runs on the drone. The server side is asyncio (it lives
in the daemon's loop); the client side is plain blocking sockets, so swarmctl needs no loop.

Who sent it: at accept the server reads the client's credentials from the kernel
(``SO_PEERCRED``, unix(7): the pid, uid and gid of the process that connected, as they were
at ``connect``; a client cannot choose them) and hands them to the *sender handlers*, the
state-changing requests (``takeoff``, ``command``), which log them and keep them with the
command (``sent_by``). It is a record, not a gate: who may connect at all stays the socket
file's mode and group (docs/security.md, "Control socket").
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import pwd
import select
import socket
import stat
import struct
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final

from swarmd.bundle.keys import others_can_write

MAX_LINE_BYTES: Final = 64 * 1024  # a request is tiny; this bounds a hostile client's buffer
MAX_CLIENTS: Final = 16  # stops a local user from exhausting the daemon's file descriptors
CLIENT_TIMEOUT_S: Final = 2.0  # swarmctl's wait for one reply
# How long a connection may take to complete its next request line: after it connects, and
# after each reply. swarmctl writes its line right after connecting and `swarmctl watch`
# asks again every --interval (1 s by default; above half of this it reconnects per
# refresh), so 10 s (5x swarmctl's own wait for a reply) is never reached by a working
# client on a busy drone, while a stuck or idle one (a hung script, a forgotten socat, a
# client that sends half a line) frees its slot: without it MAX_CLIENTS of them locked
# swarmctl out for good (docs/security.md, "Control socket").
REQUEST_DEADLINE_S: Final = 10.0

# A refusal's ``code``: the daemon is stopping (its swarm core no longer runs) and carried
# out nothing of the request, so a command was not sent: swarmctl's "not reachable, nothing
# sent" (exit 2), not a usage error (docs/operations.md, "Exit codes"; session 16)
STOPPING: Final = "stopping"

Handler = Callable[[Mapping[str, Any]], Any]


@dataclass(frozen=True, slots=True)
class PeerCredentials:
    """The connecting process as the kernel saw it at ``connect`` (``SO_PEERCRED``)."""

    pid: int
    uid: int
    gid: int

    @property
    def user(self) -> str | None:
        """The uid's login name; None when the password database has no entry for it."""
        try:
            return pwd.getpwuid(self.uid).pw_name
        except KeyError:
            return None

    def log_fields(self) -> dict[str, Any]:
        """The fields every state-changing request's log line carries (docs/operations.md)."""
        return {
            "peer_uid": self.uid,
            "peer_user": self.user,
            "peer_pid": self.pid,
            "peer_gid": self.gid,
        }


# A state-changing request's handler: the request and who sent it (None: the kernel did not
# say, e.g. a socketpair in a test or a platform without SO_PEERCRED)
SenderHandler = Callable[[Mapping[str, Any], PeerCredentials | None], Any]
_UCRED: Final = struct.Struct("3i")  # struct ucred {pid_t pid; uid_t uid; gid_t gid;}


def peer_credentials(sock: Any) -> PeerCredentials | None:
    """``SO_PEERCRED`` of a connected Unix socket; None where the kernel does not give it."""
    option = getattr(socket, "SO_PEERCRED", None)
    if sock is None or option is None:
        return None
    try:
        raw = sock.getsockopt(socket.SOL_SOCKET, option, _UCRED.size)
        pid, uid, gid = _UCRED.unpack(raw)
    except (OSError, struct.error):
        return None
    return PeerCredentials(pid, uid, gid)


def _ignoring_sender(handler: Handler) -> SenderHandler:
    return lambda request, _peer: handler(request)


class ControlSocketBusy(RuntimeError):
    """Another live process already answers on the control socket path."""


class ControlSocketUnsafe(RuntimeError):
    """The socket's folder lets another local user replace the socket; ``str()`` is one line."""


class DaemonUnreachable(RuntimeError):
    """swarmctl cannot talk to the daemon; ``str()`` is one line saying why and what to do."""


class ReplyLost(DaemonUnreachable):
    """The request reached the daemon whole but its answer never came back (the connection
    closed, the wait ran out, or the answer did not parse): the daemon may have carried it
    out. A command request it carried out has gone to the drones (session 16 command
    review, ``tests/test_cmd_reply_lost.py``)."""


class DaemonStopping(DaemonUnreachable):
    """The daemon answered ``code: stopping``: it is shutting down and carried out nothing of
    the request (a command was not sent); ``str()`` is one line."""


class RequestError(RuntimeError):
    """The daemon answered ``ok: false``."""


class RequestInvalid(ValueError):
    """A handler refuses a request (bad argument, wrong node); ``str()`` goes to the client,
    and ``code`` (``STOPPING``, or None) with it as the reply's ``code``."""

    def __init__(self, message: str, *, code: str | None = None) -> None:
        super().__init__(message)
        self.code = code


def encode_line(obj: Any) -> bytes:
    return json.dumps(obj, separators=(",", ":"), allow_nan=False).encode() + b"\n"


class ControlServer:
    """Serves ``handlers`` (command name -> function of the request) on a Unix socket."""

    def __init__(
        self,
        path: str,
        handlers: Mapping[str, Handler],
        *,
        sender_handlers: Mapping[str, SenderHandler] | None = None,
        mode: int = 0o660,
        request_deadline_s: float = REQUEST_DEADLINE_S,
    ) -> None:
        self.path = path
        self.mode = mode
        # one table: a read-only request's handler ignores who sent it; the state-changing
        # requests (``sender_handlers``) also get the sender's credentials
        self._handlers: dict[str, SenderHandler] = {
            name: _ignoring_sender(handler) for name, handler in handlers.items()
        }
        self._handlers.update(sender_handlers or {})
        self.request_deadline_s = request_deadline_s
        self.requests = 0
        self.rejected_clients = 0  # refused at the cap
        self.idle_clients_closed = 0  # no complete request line within the deadline
        self.slow_clients_closed = 0  # a reply not taken within the deadline
        self._server: asyncio.Server | None = None
        self._clients: set[asyncio.Task[None]] = set()

    async def start(self) -> None:
        """Bind, replacing a stale socket file; ``ControlSocketBusy`` when one is live."""
        folder = Path(self.path).parent
        shared = others_can_write(folder)
        if shared is not None:
            # another user could unlink our socket and bind theirs in its place (swarmctl
            # would talk to them), or squat the path before we start (session 10 review)
            raise ControlSocketUnsafe(
                f"its folder {folder} is {shared}; fix: use a folder only swarmd writes "
                "(/run/swarmd, systemd's RuntimeDirectory=swarmd), or chmod go-w it"
            )
        _remove_stale(self.path)
        folder.mkdir(parents=True, exist_ok=True)
        # bind(2) makes the file 0777 less the umask; under a umask of 0 anyone could connect
        # before the chmod and keep the connection (session 10 review). Bound under 0177 (the
        # file is ours alone), synchronously so no other task runs under that umask, then
        # opened to control.mode's group.
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        old_umask = os.umask(0o177)
        try:
            sock.bind(self.path)
        except OSError:
            sock.close()
            raise
        finally:
            os.umask(old_umask)
        try:
            os.chmod(self.path, self.mode)
            self._server = await asyncio.start_unix_server(
                self._serve, sock=sock, limit=MAX_LINE_BYTES
            )
        except BaseException:
            sock.close()
            with contextlib.suppress(FileNotFoundError):
                os.unlink(self.path)
            raise

    async def close(self) -> None:
        if self._server is not None:
            self._server.close()
            for task in list(self._clients):
                task.cancel()
            await asyncio.gather(*self._clients, return_exceptions=True)
            await self._server.wait_closed()
            self._server = None
            with contextlib.suppress(FileNotFoundError):
                os.unlink(self.path)

    async def _serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        task = asyncio.current_task()
        if len(self._clients) >= MAX_CLIENTS or task is None:
            self.rejected_clients += 1
            writer.write(encode_line({"ok": False, "error": "too many control clients"}))
            await _close_writer(writer)
            return
        self._clients.add(task)
        # read once, at accept: the kernel's record of who connected (unix(7))
        peer = peer_credentials(writer.get_extra_info("socket"))
        try:
            while True:
                try:
                    async with asyncio.timeout(self.request_deadline_s):
                        line = await reader.readline()
                except ValueError:  # longer than MAX_LINE_BYTES without a newline
                    writer.write(encode_line({"ok": False, "error": "request line too long"}))
                    break
                except TimeoutError:  # idle, or a line that never ends: free the slot
                    within = f"{self.request_deadline_s:g} s"
                    error = f"no complete request line within {within}"
                    writer.write(encode_line({"ok": False, "error": error}))
                    self.idle_clients_closed += 1
                    break
                if not line:
                    break
                writer.write(encode_line(self.dispatch(line, peer)))
                try:
                    # a client that sends requests and never reads the replies: without
                    # this bound drain() waited forever and the slot was never freed
                    async with asyncio.timeout(self.request_deadline_s):
                        await writer.drain()
                except TimeoutError:
                    self.slow_clients_closed += 1
                    writer.transport.abort()  # close() would wait for the unread replies
                    break
        except (ConnectionError, asyncio.CancelledError):
            pass
        finally:
            self._clients.discard(task)
            await _close_writer(writer)

    def dispatch(self, line: bytes, peer: PeerCredentials | None = None) -> dict[str, Any]:
        """One request line from ``peer`` -> the reply object. Never raises."""
        self.requests += 1
        try:
            request = json.loads(line)
        except (ValueError, RecursionError):
            # RecursionError: a line nested ~1,000 deep overflows the decoder (not a
            # ValueError); unhandled, it killed this client's handler without a reply
            return {"ok": False, "error": "request is not JSON"}
        if not isinstance(request, dict) or not isinstance(request.get("cmd"), str):
            return {"ok": False, "error": 'request must be an object like {"cmd": "status"}'}
        cmd = request["cmd"]
        handler = self._handlers.get(cmd)
        if handler is None:
            known = ", ".join(sorted(self._handlers))
            return {"ok": False, "error": f"unknown command {cmd!r}; known: {known}"}
        try:
            return {"ok": True, "result": handler(request, peer)}
        except RequestInvalid as exc:
            reply: dict[str, Any] = {"ok": False, "error": str(exc)}
            if exc.code is not None:
                reply["code"] = exc.code
            return reply
        except Exception as exc:  # a handler bug must not take the daemon down
            return {"ok": False, "error": f"internal error: {type(exc).__name__}: {exc}"}


async def _close_writer(writer: asyncio.StreamWriter) -> None:
    writer.close()
    try:
        # close() waits to flush what is buffered; a peer that never reads would hold the
        # handler here, so a close that does not finish within a second is an abort
        async with asyncio.timeout(1.0):
            await writer.wait_closed()
    except TimeoutError:
        writer.transport.abort()
    except (ConnectionError, asyncio.CancelledError):
        pass


def _remove_stale(path: str) -> None:
    try:
        st = os.lstat(path)
    except FileNotFoundError:
        return
    if not stat.S_ISSOCK(st.st_mode):
        raise ControlSocketBusy(f"{path} exists and is not a socket")
    probe = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    try:
        probe.settimeout(0.5)
        probe.connect(path)
    except (ConnectionRefusedError, FileNotFoundError):
        os.unlink(path)  # left behind by a daemon that died without cleaning up
        return
    except OSError:
        pass
    finally:
        probe.close()
    raise ControlSocketBusy(f"another swarmd answers on {path}")


class ControlClient:
    """A blocking client for one connection; use as a context manager."""

    def __init__(self, path: str, *, timeout: float = CLIENT_TIMEOUT_S) -> None:
        self.path = path
        self.timeout = timeout
        self._sock: socket.socket | None = None
        self._buffer = b""

    def __enter__(self) -> ControlClient:
        self.connect()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def connect(self) -> None:
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        sock.settimeout(self.timeout)
        try:
            sock.connect(self.path)
        except FileNotFoundError:
            sock.close()
            raise DaemonUnreachable(
                f"swarmd is not running (no control socket at {self.path}); "
                "start it with 'systemctl start swarmd'"
            ) from None
        except ConnectionRefusedError:
            sock.close()
            raise DaemonUnreachable(
                f"swarmd is not running (stale control socket {self.path}); "
                "start it with 'systemctl start swarmd'"
            ) from None
        except PermissionError:
            sock.close()
            raise DaemonUnreachable(
                f"permission denied on {self.path}; run as root or join group swarmd "
                "('sudo usermod -aG swarmd $USER', then log in again)"
            ) from None
        except OSError as exc:
            sock.close()
            raise DaemonUnreachable(f"cannot connect to {self.path}: {exc.strerror}") from None
        self._sock = sock

    def request(self, cmd: str, **args: Any) -> Any:
        """Send one command and return its ``result``; raises on transport or daemon error."""
        if self._sock is not None and self._closed_by_daemon():
            self.close()  # idle past REQUEST_DEADLINE_S: the daemon freed the slot
        if self._sock is None:
            self.connect()
        assert self._sock is not None  # noqa: S101 - connect() sets it or raises
        with self._transport_errors(DaemonUnreachable, "take the request"):
            self._sock.sendall(encode_line({"cmd": cmd, **args}))
        # from here the daemon holds the whole line: it may carry the request out whatever
        # becomes of its answer (a daemon held up past our wait still reads it)
        with self._transport_errors(ReplyLost, "answer"):
            line = self._readline()
        try:
            reply = json.loads(line)
        except ValueError:
            raise ReplyLost(f"swarmd sent a malformed reply on {self.path}") from None
        if not isinstance(reply, dict) or "ok" not in reply:
            raise ReplyLost(f"swarmd sent a malformed reply on {self.path}")
        if not reply["ok"]:
            error = str(reply.get("error", "request failed"))
            if reply.get("code") == STOPPING:
                raise DaemonStopping(
                    f"swarmd on {self.path} answered: {error}; it carried out nothing of "
                    f"this {cmd!r} request"
                )
            raise RequestError(error)
        return reply.get("result")

    @contextlib.contextmanager
    def _transport_errors(self, error: type[DaemonUnreachable], step: str) -> Iterator[None]:
        """A timeout or a socket error in ``step`` as ``error``, one line for the operator."""
        try:
            yield
        except TimeoutError:
            raise error(f"swarmd did not {step} within {self.timeout:g} s on {self.path}") from None
        except OSError as exc:
            raise error(f"lost the connection to swarmd: {exc.strerror}") from None

    def _closed_by_daemon(self) -> bool:
        """Whether the daemon closed this connection while it sat idle: its deadline line,
        or the end of the stream, is waiting unasked (a reply only ever follows a request,
        and ``_readline`` took the last one whole)."""
        assert self._sock is not None  # noqa: S101 - only called with a connection
        # poll, not recv(MSG_DONTWAIT): a socket with a timeout would wait that long
        readable, _, _ = select.select([self._sock], [], [], 0)
        return bool(readable)

    def _readline(self) -> bytes:
        assert self._sock is not None  # noqa: S101 - only called after connect()
        while b"\n" not in self._buffer:
            chunk = self._sock.recv(65536)
            if not chunk:
                raise ConnectionResetError(0, "swarmd closed the connection")
            self._buffer += chunk
            if len(self._buffer) > 64 * MAX_LINE_BYTES:
                raise ConnectionResetError(0, "reply too long")
        line, _, self._buffer = self._buffer.partition(b"\n")
        return line

    def close(self) -> None:
        if self._sock is not None:
            self._sock.close()
            self._sock = None


def request(path: str, cmd: str, *, timeout: float = CLIENT_TIMEOUT_S, **args: Any) -> Any:
    """One-shot: connect, send ``cmd``, return the result, close."""
    with ControlClient(path, timeout=timeout) as client:
        return client.request(cmd, **args)
