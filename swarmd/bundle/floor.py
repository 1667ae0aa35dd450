"""The anti-rollback floor: the highest bundle serial this node has accepted.

Why (docs/security.md, "Bundle rollback"): after a member is revoked (a lost or captured
drone), the swarm re-signs a bundle without it. The older bundle is still validly signed
by the swarm key, so whoever can put it back where the daemon reads it (a flasher, a backup
restore, a mis-deploy) would silently re-admit the revoked member. Every bundle carries a
``serial`` in its signed body (docs/bundle-format.md, "Serial"); the daemon keeps the
highest one it accepted, with that bundle's content hash, in one small file per node::

    bundle-floor-<node>        {"serial": 7, "sha256": "<64 hex>"}

in the folder of node.key (``bundle.node_key``; ``/var/lib/swarmd`` on a drone, the state
directory), beside the boot epoch (``swarmd.auth.epoch``), under the state file's rules:
the folder must be writable by this daemon's user alone, judged on the descriptor the file
is then read and written through (``swarmd.bundle.safeopen``: no check-then-open race); the
file is read ``O_NOFOLLOW | O_NONBLOCK``, only as a regular file of a trusted owner, at most
``MAX_FLOOR_BYTES``; writes are atomic with a random ``O_EXCL | O_NOFOLLOW`` temp name.

At start-up, before anything is sent (``check``):

- a serial below the floor is refused (the rollback);
- the floor's serial with another content hash is refused: two bundles must not share a
  serial, or a stale build could pass as the current one;
- a higher serial is accepted and the floor raised (``raise_floor``) before the first send;
- a bundle without a serial (built before serials) counts as serial 0: with no floor it is
  accepted, so a drone upgraded to this swarmd keeps flying on the bundle it has; once a
  floor exists it passes only as the very bundle recorded at 0 (a restart), fail closed.

A floor file that does not parse is refused (``FloorError``), not taken as "no floor": it
is a security record, and the fix (delete it once the bundle is known to be the newest) is
the operator's decision. A *missing* file cannot be told from a first start: whoever can
delete it (root: the folder is swarmd's alone) resets the floor; the daemon logs that case
(docs/security.md lists it among the residual risks).

The serial is compared whatever key signed the bundle or swarm it names: a drone never
goes back, across key rotations too. A drone moved to another swarm needs its floor file
deleted by the operator (docs/operations.md).
"""

from __future__ import annotations

import errno
import json
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Final

from swarmd.bundle.errors import BundleError, FileProblem
from swarmd.bundle.keys import node_state_path, open_state_dir, refuse_shared_dir
from swarmd.bundle.model import SERIAL_MAX, Bundle
from swarmd.bundle.safeopen import (
    Folder,
    held,
    open_folder,
    read_file,
    unreadable_why,
    write_atomic,
)

FILE_PREFIX: Final = "bundle-floor-"
FILE_PATTERN: Final = FILE_PREFIX + "{node}"
FLOOR_FILE_MODE: Final = 0o640  # like the state file: the group reads it
_SHA256_HEX: Final = re.compile(r"[0-9a-f]{64}")
LEGACY_SERIAL: Final = 0  # what a bundle built before serials counts as
MAX_FLOOR_BYTES: Final = 4096  # the file is ~90 bytes; a bigger one is not ours


@dataclass(frozen=True, slots=True)
class Floor:
    """The highest serial accepted and the content hash of the bundle that carried it."""

    serial: int
    sha256: bytes


class FloorError(FileProblem):
    """The floor file exists but cannot be trusted (corrupt, unreadable); one line."""


class FloorWriteError(OSError):
    """The floor's folder is unsafe or cannot be written; ``str()`` is one line."""


def floor_path(state_dir: str | Path, node: str) -> Path:
    return node_state_path(state_dir, FILE_PATTERN, node)


def serial_of(bundle: Bundle) -> int:
    return LEGACY_SERIAL if bundle.serial is None else bundle.serial


def read_floor(
    path: Path,
    bundle_source: str,
    folder: Folder | None = None,
    also: frozenset[int] = frozenset(),
) -> Floor | None:
    """The floor at ``path``; None when there is none. ``FloorError`` when it does not parse
    (``bundle_source`` names the bundle in the fix). ``folder``: ``path``'s folder as judged
    (``safeopen``: read through it, never by path; None: opened here); ``also``: the file's
    owners trusted beside root and swarmd (the daemon's user, as check-config judges it)."""
    opened = folder if folder is not None else open_folder(path.parent)
    if opened is None:
        return None
    try:
        # never through a symlink (a link to a lower floor elsewhere would lower it), never
        # blocking (a FIFO would hang start-up with no line saying why): safeopen.read_file
        raw = read_file(opened, path.name, MAX_FLOOR_BYTES, also=also)
    except FileNotFoundError:
        return None
    except OSError as exc:
        raise _corrupt(path, bundle_source, f"unreadable ({unreadable_why(exc)})") from None
    finally:
        if folder is None:
            opened.close()
    return parse_floor(raw, path, bundle_source)


def parse_floor(raw: bytes, path: Path, bundle_source: str) -> Floor:
    """A floor file's bytes (read here, or over ssh by ``swarmctl bundle``); ``FloorError``
    when they do not parse."""
    try:
        if len(raw) > MAX_FLOOR_BYTES:
            raise ValueError(f"over {MAX_FLOOR_BYTES} bytes")
        value = json.loads(raw)
        serial, sha = value["serial"], value["sha256"]
        if isinstance(serial, bool) or not isinstance(serial, int):
            raise ValueError(f"serial {serial!r} is not a number")
        if not LEGACY_SERIAL <= serial <= SERIAL_MAX:
            raise ValueError(f"serial {serial} out of range")
        if not isinstance(sha, str) or not _SHA256_HEX.fullmatch(sha):
            raise ValueError("sha256 is not 64 lower-case hex digits")
    except (ValueError, KeyError, TypeError) as exc:  # json's errors are ValueErrors
        raise _corrupt(path, bundle_source, f"corrupt ({type(exc).__name__}: {exc})") from None
    return Floor(serial, bytes.fromhex(sha))


def _corrupt(path: Path, bundle_source: str, why: str) -> FloorError:
    return FloorError(
        str(path),
        f"bundle floor {why}",
        f"check that {bundle_source} is this swarm's newest bundle ('swarmctl bundle check "
        f"BUNDLE --node NAME'), then delete {path}: the next start records its serial",
    )


def check(bundle: Bundle, floor: Floor | None, *, source: str, path: Path) -> bool:
    """Raise ``BundleError`` (one line: the bundle file, field ``serial``, the floor, the
    fix) when ``bundle`` must not start over ``floor``; True when the floor must be raised
    to it (a first start, or a higher serial)."""
    serial = serial_of(bundle)
    if floor is None or serial > floor.serial:
        return True
    shown = "missing (built before bundle serials)" if bundle.serial is None else str(serial)
    nxt = floor.serial + 1
    if serial < floor.serial:
        raise BundleError(
            source,
            f"field serial: {shown} is below this node's floor {floor.serial} ({path}: the "
            f"highest serial it accepted, sha256 {floor.sha256.hex()}): an older bundle "
            "(rollback)",
            f"flash this swarm's newest bundle (serial {floor.serial} or above); to go back "
            f"on purpose, rebuild the older mission with 'swarmctl bundle build --serial "
            f"{nxt}' and flash that",
        )
    if bundle.content_sha256 != floor.sha256:
        raise BundleError(
            source,
            f"field serial: {shown} is this node's floor ({path}), held by another bundle "
            f"(sha256 {floor.sha256.hex()}, this one {bundle.content_sha256.hex()}): two "
            "bundles must not share a serial",
            f"rebuild with 'swarmctl bundle build --serial {nxt}' and flash it",
        )
    return False  # the very bundle of the floor: a restart


def raise_floor(path: Path, bundle: Bundle, folder: Folder | None = None) -> None:
    """Record ``bundle`` as the floor, atomically; ``FloorWriteError`` on failure.
    ``folder``: ``path``'s folder as judged (written through it); None: created when
    missing, opened and judged here."""
    body = {"serial": serial_of(bundle), "sha256": bundle.content_sha256.hex()}
    data = json.dumps(body, separators=(",", ":")).encode("ascii") + b"\n"
    try:
        if folder is not None:
            write_atomic(folder, path.name, data, FLOOR_FILE_MODE)
            return
        path.parent.mkdir(parents=True, exist_ok=True, mode=0o750)
        with held(open_state_dir(path.parent, "bundle.node_key", FloorWriteError)) as made:
            refuse_shared_dir(made, "bundle.node_key", FloorWriteError)
            if made is None:
                raise FileNotFoundError(errno.ENOENT, "No such file or directory")
            write_atomic(made, path.name, data, FLOOR_FILE_MODE)
    except FloorWriteError:
        raise
    except OSError as exc:
        raise FloorWriteError(
            f"cannot persist the bundle floor in {path}: {exc.strerror}"
        ) from None


@dataclass(frozen=True, slots=True)
class FloorResult:
    path: Path
    previous: Floor | None  # what the file held; None: no file (a first start, or deleted)
    raised: bool  # the floor moved to this bundle (or would, when not committed)


def enforce(
    bundle: Bundle,
    *,
    source: str,
    state_dir: str | Path,
    node: str,
    commit: bool,
    also: frozenset[int] = frozenset(),
) -> FloorResult:
    """Check ``bundle`` (read from ``source``) against the node's floor and, when
    ``commit``, raise the floor to it. ``check-config`` passes ``commit=False``: a bundle
    checked but never run must not lock out the one the drone runs now; and ``also``, the
    owners the daemon's user trusts beside root and swarmd (``DaemonUser.trusted_owners``,
    as the epoch's check): its folder and floor are judged as ``run`` will judge them.

    Raises ``BundleError`` (refused: exit 78), ``FloorError`` (corrupt floor: exit 78),
    ``FloorWriteError`` (unsafe or unwritable folder: exit 73)."""
    directory = Path(state_dir)
    path = floor_path(directory, node)
    # judged, read and written through one descriptor (safeopen: no check-then-open race)
    with held(open_state_dir(directory, "bundle.node_key", FloorWriteError)) as folder:
        # a folder others can write could hold a planted floor (or a planted low one)
        refuse_shared_dir(folder, "bundle.node_key", FloorWriteError, also)
        previous = read_floor(path, source, folder, also) if folder is not None else None
        raised = check(bundle, previous, source=source, path=path)
        if raised and commit:
            raise_floor(path, bundle, folder)
    return FloorResult(path, previous, raised)
