"""Judge a folder and read or write its files through one descriptor (no check-then-open race).

Why (docs/security.md, "A state or key folder whose parent another user writes", review
15): swarmd judged each state folder (node.key's, ``dataplane.state_dir``) by its path,
then opened its files by path. A local user who may rename entries in the folder's parent
(a folder under their home, ``/tmp`` without the sticky bit) could swap the judged folder
for their own between the two: a planted epoch, state file or node.key, or a FIFO that
held the start. Now the folder is opened once (``open_folder``), judged by ``fstat`` on
that descriptor (``writers_problem``: the owner and mode rules of ``keys.others_can_write``),
and every file in it is opened relative to the descriptor (``openat``), so whatever was
judged is what is read and written, whatever happens to the path afterwards.

What is opened how:

- the folder: its last component with ``O_NOFOLLOW`` (a symlink planted at the folder's
  name is not followed). The components above it are followed, as before: the folder is
  judged by what the descriptor is, not by the way there. One exception keeps
  ``DynamicUser=`` working (systemd makes ``/var/lib/swarmd`` a symlink to
  ``/var/lib/private/swarmd``): a symlink at the last component is followed when the
  folder that holds it is itself not writable by others (only root, swarmd or this
  daemon's user could have put it there); the folder reached is judged all the same.
- a file: ``O_RDONLY | O_NOFOLLOW | O_NONBLOCK | O_CLOEXEC`` relative to the folder, so
  a symlink is refused (``ELOOP``) and a FIFO neither blocks the open nor is read
  (``fstat`` must say a regular file); a file owned by another user than root, swarmd or
  the daemon's user is refused; at most ``cap + 1`` bytes are read, and more is refused
  (``TooLarge``): each kind of file has its cap, far above its real size (``*_CAP``).
- a write (``write_atomic``): a random temp name created ``O_EXCL | O_NOFOLLOW`` in the
  folder, written, fsynced, renamed over the file (``renameat``, both names relative to
  the folder), then the folder itself fsynced, all through the same descriptor.
"""

from __future__ import annotations

import contextlib
import errno
import os
import pwd
import secrets
import stat
from collections.abc import Callable
from contextlib import AbstractContextManager
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import Final

SERVICE_USER: Final = "swarmd"  # systemd/swarmd.service's User=
# write_atomic's temporary name: ".<name>.tmp-" and this many random octets in hex
TEMP_TOKEN_BYTES: Final = 8

# The read caps, per kind of file: each far above what swarmd writes (the figures: the
# test named beside each), so only a file that is not swarmd's is refused by them, and a
# wrong file (a disk image, a sparse file of terabytes) never fills the memory.
NODE_KEY_CAP: Final = 64 * 1024  # two PKCS#8 PEM blocks: 238 bytes (test_safeopen_attacks)
EPOCH_CAP: Final = 4096  # one decimal u32 and a newline: at most 11 bytes
SIGNING_KEY_CAP: Final = 64 * 1024  # PX4's key file: 40 bytes; 64 hex digits + newline: 65
# executed ids, outcomes and decisions at their caps with the longest strings: under 2 MiB
# (test_safeopen_attacks.py::test_the_largest_state_file_is_far_under_its_cap)
STATE_FILE_CAP: Final = 16 * 1024 * 1024

DIR_FLAGS: Final = os.O_PATH | os.O_DIRECTORY | os.O_NOFOLLOW | os.O_CLOEXEC
READ_FLAGS: Final = os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC
TEMP_FLAGS: Final = os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW | os.O_CLOEXEC


class NotRegular(OSError):
    """A name in a judged folder that is not a regular file (a FIFO, a device, a folder)."""


class ForeignOwner(OSError):
    """A file owned by another user than root, swarmd or the daemon's user."""


class TooLarge(OSError):
    """A file over its kind's read cap (``*_CAP``)."""


def trusted_owners() -> frozenset[int]:
    """Root, this process's user, and the service's user (``User=swarmd`` in
    systemd/swarmd.service): root running the daemon by hand reads swarmd's flashed files."""
    owners = {0, os.geteuid()}
    with contextlib.suppress(KeyError):
        owners.add(pwd.getpwnam(SERVICE_USER).pw_uid)
    return frozenset(owners)


def writers_problem(info: os.stat_result, also: frozenset[int] = frozenset()) -> str | None:
    """Why another local user could write what ``info`` describes (a folder: plant or swap
    files in it; a file: rewrite it), or None: owned by a trusted owner (``also``: the
    daemon's uid as ``check-config`` judges it for a unit) and not group/other-writable."""
    if info.st_uid not in trusted_owners() | also:
        return f"owned by uid {info.st_uid}, not by root, swarmd or this daemon's user"
    if info.st_mode & 0o022:
        who = "others" if info.st_mode & 0o002 else "its group"
        return f"writable by {who} (mode {info.st_mode & 0o7777:04o})"
    return None


@dataclass(slots=True)
class Folder:
    """An open folder: ``path`` as the config named it, ``fd`` (``O_PATH``) and ``info``,
    its ``fstat`` at open (what every judgement reads). Close it (``with``)."""

    path: Path
    fd: int
    info: os.stat_result

    def close(self) -> None:
        if self.fd >= 0:
            os.close(self.fd)
            self.fd = -1

    def __enter__(self) -> Folder:
        return self

    def __exit__(
        self,
        kind: type[BaseException] | None,
        value: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        self.close()

    def __del__(self) -> None:  # a folder a caller kept (NodeState's) closes with it
        self.close()

    def handle(self) -> int:
        """A readable descriptor of this very folder (``openat(fd, ".")``: the same inode,
        whatever its path is now), for ``fsync`` and listing; the caller closes it."""
        return os.open(".", os.O_RDONLY | os.O_DIRECTORY | os.O_CLOEXEC, dir_fd=self.fd)


def open_folder(path: str | Path, *, follow: bool = False) -> Folder | None:
    """The folder at ``path``, opened (module docstring); None when there is no folder
    there (missing, or a file: the caller's own check of the path says which, in its line).

    ``follow``: follow a symlink at the last component too (writers that do not judge the
    folder, ``write_file_atomic``'s callers). Raises ``NotADirectoryError`` for a symlink
    there in a folder others may write, another ``OSError`` when it cannot be opened."""
    where = Path(path)
    flags = DIR_FLAGS & ~os.O_NOFOLLOW if follow else DIR_FLAGS
    try:
        fd = os.open(where, flags)
    except FileNotFoundError:
        return None
    except NotADirectoryError:
        if not os.path.islink(where):
            return None
        if not _symlink_in_trusted_folder(where):
            raise NotADirectoryError(
                errno.ENOTDIR, "a symlink, in a folder others may write", str(where)
            ) from None
        try:
            fd = os.open(where, DIR_FLAGS & ~os.O_NOFOLLOW)
        except (FileNotFoundError, NotADirectoryError):
            return None
    return Folder(where, fd, os.fstat(fd))


def _symlink_in_trusted_folder(path: Path) -> bool:
    """Whether the symlink ``path``'s own folder is written by trusted users alone (module
    docstring: ``DynamicUser=``'s ``/var/lib/swarmd``)."""
    try:
        return writers_problem(os.stat(path.parent)) is None
    except OSError:
        return False


def read_file(
    folder: Folder,
    name: str,
    cap: int,
    *,
    also: frozenset[int] = frozenset(),
    judge: Callable[[os.stat_result], None] | None = None,
) -> bytes:
    """At most ``cap`` bytes of the regular file ``name`` in ``folder`` (module docstring).
    ``also``: owners trusted beside root, swarmd and this process's user; ``judge``: called
    with the file's ``fstat`` before it is read (a mode check; it raises to refuse).

    Raises ``FileNotFoundError`` when there is none, ``NotRegular``, ``ForeignOwner``,
    ``TooLarge``, or the ``OSError`` of the open (``ELOOP``: a symlink)."""
    fd = os.open(name, READ_FLAGS, dir_fd=folder.fd)
    try:
        info = os.fstat(fd)
        if not stat.S_ISREG(info.st_mode):
            raise NotRegular(errno.EINVAL, "not a regular file", name)
        if info.st_uid not in trusted_owners() | also:
            raise ForeignOwner(errno.EPERM, f"owned by uid {info.st_uid}", name)
        if judge is not None:
            judge(info)
        if info.st_size > cap:  # refused at its size: a sparse terabyte is never read
            raise TooLarge(errno.EFBIG, f"over its {cap}-byte cap", name)
        chunks: list[bytes] = []
        size = 0
        while size <= cap:  # bounded: a file growing while read stops at cap + 1
            chunk = os.read(fd, min(cap + 1 - size, 1 << 20))
            if not chunk:
                break
            chunks.append(chunk)
            size += len(chunk)
        if size > cap:
            raise TooLarge(errno.EFBIG, f"over its {cap}-byte cap", name)
        return b"".join(chunks)
    finally:
        os.close(fd)


class SharedFolder(OSError):
    """A trusted file's folder another user may write (``read_trusted``); ``strerror``:
    which folder and why, ``TRUSTED_FIX`` the fix."""


TRUSTED_FIX: Final = (
    "make it and its folder writable by root or swarmd alone (chmod go-w; /etc/swarmd/keys, "
    "/var/lib/swarmd)"
)


def read_trusted(
    path: Path,
    cap: int,
    *,
    also: frozenset[int] = frozenset(),
    judge: Callable[[os.stat_result], None] | None = None,
) -> bytes:
    """A key file's bytes (node.key, the PX4 signing key) through its folder's descriptor:
    the folder judged on it (``config.check_trusted_files``' rule, so a folder swapped
    in since that check is refused: ``SharedFolder``), then ``read_file``. Raises
    ``FileNotFoundError`` (no file, or no folder), ``SharedFolder`` or ``read_file``'s."""
    with judged_folder(path, also) as folder:
        return read_file(folder, path.name, cap, also=also, judge=judge)


def judged_folder(path: Path, also: frozenset[int] = frozenset()) -> Folder:
    """The folder of the file ``path``, opened and judged on that descriptor
    (``writers_problem``), for the file to be read or written through it. Raises
    ``FileNotFoundError`` (no folder), ``SharedFolder`` or ``open_folder``'s ``OSError``."""
    folder = open_folder(path.parent)
    if folder is None:
        raise FileNotFoundError(errno.ENOENT, "No such file or directory", str(path))
    why = writers_problem(folder.info, also)
    if why is not None:
        folder.close()
        problem = f"folder {path.parent} is {why}, so another user could swap it"
        raise SharedFolder(errno.EPERM, problem, str(path))
    return folder


def unreadable_why(exc: OSError) -> str:
    """A short reason for ``read_file``'s ``OSError`` (a symlink, a FIFO, an owner, a cap)."""
    if exc.errno == errno.ELOOP:
        return "a symlink, not a file"
    return exc.strerror or str(exc)


def temp_name(name: str) -> str:
    """A fresh temporary name beside ``name``: random, so never one planted in advance."""
    return f".{name}.tmp-{secrets.token_hex(TEMP_TOKEN_BYTES)}"


def write_atomic(folder: Folder, name: str, data: bytes, mode: int) -> None:
    """Write ``data`` to ``name`` in ``folder`` via a random temp file, fsync, rename and a
    folder fsync, every step relative to the folder's descriptor (module docstring).

    The temp file is created with ``mode`` already set, so a private key is never readable
    by others, not even for the instant between create and chmod; a name collision is a
    planted file, and another name is drawn (2^64 names)."""
    for _attempt in range(16):
        tmp = temp_name(name)
        try:
            fd = os.open(tmp, TEMP_FLAGS, mode, dir_fd=folder.fd)
            break
        except FileExistsError:
            continue
    else:
        raise FileExistsError(errno.EEXIST, "no free temporary name", str(folder.path))
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fchmod(f.fileno(), mode)  # O_CREAT's mode is masked by the umask
            os.fsync(f.fileno())
        os.rename(tmp, name, src_dir_fd=folder.fd, dst_dir_fd=folder.fd)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp, dir_fd=folder.fd)
        raise
    sync_folder(folder)


def sync_folder(folder: Folder) -> None:
    """Make a rename in ``folder`` durable (POSIX: the folder's entry needs its own fsync)."""
    handle = folder.handle()
    try:
        os.fsync(handle)
    finally:
        os.close(handle)


def held(folder: Folder | None) -> AbstractContextManager[Folder | None]:
    """``with held(open_folder(...)) as folder``: closed on exit, None passed through."""
    return folder if folder is not None else contextlib.nullcontext()
