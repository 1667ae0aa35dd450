"""The XRCE client key swarmd's agent is bound to, kept with the node's secrets (file I/O).

``px4.backend: xrce-agent`` binds the agent to one vehicle by the key PX4 sends in
CREATE_CLIENT (``UXRCE_DDS_KEY``, docs/px4.md "One agent, one vehicle"). ``px4.xrce_key`` in
the config names it; without it the daemon generates one at its first start and keeps it in
``px4-xrce-key`` in the folder of ``node.key`` (``/var/lib/swarmd``, the state directory),
mode 0600, so restarts keep it and the operator sets it on PX4 once. The file holds the key in
decimal, as ``param set UXRCE_DDS_KEY`` takes it.

The key is a session identifier PX4 sends in the clear, not a credential: its file is
private so that a local user who can read the config (or the journal) cannot also read it,
which bounds what such a user can do (docs/px4.md).
"""

from __future__ import annotations

import errno
import os
import secrets
import stat
from dataclasses import dataclass
from pathlib import Path
from typing import Final

from swarmd.bundle.keys import PRIVATE_MODE
from swarmd.bundle.safeopen import (
    READ_FLAGS,
    Folder,
    held,
    judged_folder,
    unreadable_why,
    write_atomic,
)

XRCE_KEY_FILE: Final = "px4-xrce-key"
# PX4's UXRCE_DDS_KEY is an INT32 parameter: a generated key stays positive so the operator
# types it as it is; 0 would mean "no key" to a reader of either side
GENERATED_MAX: Final = 0x7FFF_FFFF
KEY_MAX: Final = 0xFFFF_FFFF  # what px4.xrce_key accepts (a negative INT32 seen as u32)
SWARMD_CLIENT_KEY: Final = 0x5357_4D44  # "SWMD", swarmd's own key as a client: never PX4's
MAX_FILE_BYTES: Final = 64


class XrceKeyError(ValueError):
    """The key file is unusable; ``str()`` is one line naming the file and the fix."""


@dataclass(frozen=True, slots=True)
class XrceKey:
    value: int
    path: Path
    created: bool  # generated now: the operator must set UXRCE_DDS_KEY on PX4
    mode_fixed: bool  # the file was readable by others and is 0600 now


def xrce_key_path(secrets_dir: str | Path) -> Path:
    return Path(secrets_dir) / XRCE_KEY_FILE


def generate_key(draw: int | None = None) -> int:
    """A key in 1..GENERATED_MAX, never swarmd's own client key (``draw``: tests' choice)."""
    while True:
        value = draw if draw is not None else 1 + secrets.randbelow(GENERATED_MAX)
        if value != SWARMD_CLIENT_KEY:
            return value
        draw = None


def load_or_create(secrets_dir: str | Path) -> XrceKey:
    """The key in ``secrets_dir/px4-xrce-key``, generated and written (0600) when absent.

    One descriptor of the folder, held from its judgement through the read and the first
    write (``safeopen.write_atomic``): the key is written into the very folder judged and
    found without a key, never into one swapped in at its path since (the key is private:
    in another user's folder they would read it). Held, not reopened: it is one step at
    start-up, and a reopen would judge a second folder, not the one found empty."""
    path = xrce_key_path(secrets_dir)
    try:
        path.parent.mkdir(parents=True, exist_ok=True, mode=0o750)
    except OSError as exc:
        raise _unwritable(path, exc) from None
    with held(_open_judged(path, frozenset())) as folder:
        if folder is None:  # removed since the mkdir: nothing judged, nothing written
            raise _unwritable(path, FileNotFoundError(errno.ENOENT, "No such file or directory"))
        existing = _read_key(path, folder, fix_mode=True)
        if existing is not None:
            return existing
        value = generate_key()
        try:
            write_atomic(folder, path.name, f"{value}\n".encode(), PRIVATE_MODE)
        except OSError as exc:
            raise _unwritable(path, exc) from None
    return XrceKey(value, path, created=True, mode_fixed=False)


def _unwritable(path: Path, exc: OSError) -> XrceKeyError:
    return XrceKeyError(
        f"{path}: cannot write the XRCE key: {exc.strerror}; fix: make "
        f"{path.parent} writable by swarmd, or set px4.xrce_key"
    )


def check(secrets_dir: str | Path, also: frozenset[int] = frozenset()) -> XrceKey | None:
    """``load_or_create`` by reading only (``swarmd check-config``): an existing file is read
    and refused as the daemon would refuse it, its mode reported (``mode_fixed``) and never
    changed; a missing one gives None (its folder is the boot epoch's, which
    ``swarmd.auth.epoch.plan_epoch`` judges). ``also``: the folder's owners trusted beside
    root and swarmd (the daemon's user, as check-config judges it). Raises ``XrceKeyError``."""
    path = xrce_key_path(secrets_dir)
    with held(_open_judged(path, also)) as folder:
        return None if folder is None else _read_key(path, folder, fix_mode=False)


def _fix(path: Path) -> str:
    return f"delete {path} to generate a new key, then set UXRCE_DDS_KEY on PX4 to it"


def _open_judged(path: Path, also: frozenset[int]) -> Folder | None:
    """The key's folder opened once and judged on that descriptor (``safeopen``: a folder
    swapped in since the epoch's check of it is refused); None when there is none.
    ``also``: the folder's owners trusted beside root and swarmd. Raises ``XrceKeyError``."""
    unreadable = f"{path}: cannot read the XRCE key"
    try:
        return judged_folder(path, also)
    except FileNotFoundError:
        return None
    except OSError as exc:  # SharedFolder's strerror names the folder and why
        raise XrceKeyError(f"{unreadable}: {unreadable_why(exc)}; fix: {_fix(path)}") from None


def _read_key(path: Path, folder: Folder, *, fix_mode: bool) -> XrceKey | None:
    """The key file ``path`` in its judged ``folder``, None when there is none;
    ``fix_mode``: make a file others may read 0600 (the daemon does; a check does not)."""
    fix = _fix(path)
    unreadable = f"{path}: cannot read the XRCE key"
    try:
        # O_NONBLOCK: a FIFO planted here must be refused at fstat, not hang the open
        fd = os.open(path.name, READ_FLAGS, dir_fd=folder.fd)
    except FileNotFoundError:
        return None
    except OSError as exc:
        raise XrceKeyError(f"{unreadable}: {exc.strerror}; fix: {fix}") from None
    try:
        info = os.fstat(fd)
        if not stat.S_ISREG(info.st_mode):
            raise XrceKeyError(f"{path}: not a regular file; fix: {fix}")
        mode_fixed = bool(info.st_mode & 0o077)
        if mode_fixed and fix_mode:  # readable by others: its privacy bounds a local user
            os.fchmod(fd, PRIVATE_MODE)
        raw = os.read(fd, MAX_FILE_BYTES + 1)
    except OSError as exc:
        raise XrceKeyError(f"{unreadable}: {exc.strerror}; fix: {fix}") from None
    finally:
        os.close(fd)
    text = raw.decode("ascii", "replace").strip()
    if len(raw) > MAX_FILE_BYTES or not text.isdigit() or not 1 <= int(text) <= KEY_MAX:
        raise XrceKeyError(f"{path}: not a key (a whole number 1..{KEY_MAX}); fix: {fix}")
    return XrceKey(int(text), path, created=False, mode_fixed=mode_fixed)
