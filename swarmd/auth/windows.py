"""Persisted SPDP replay windows: a receiver's restart does not make old captures fresh.

Replay windows live in memory (``swarmd.auth.freshness.ReplayWindow``). Before this, a
receiver that restarted had forgotten every sender's highest (epoch, seq): a DATA(p)
captured from a member that has since died was fresh again to it, and made the dead member
appear discovered for one full lease (issue 18; its readiness row stayed ``no_report``).
Now the daemon keeps each bundle sender's highest verified freshness in the state
directory, ``auth-windows-<node>`` next to ``auth-epoch-<node>``, and restores it at
start-up (``SpdpVerifier.restore``: that value and the 64 below it count as seen).

When: every ``SAVE_PERIOD_S`` while a window moved, and at a clean stop, written on the
daemon's writer thread (``swarmd.filewriter``: never on the loop; a save not started yet is
replaced by the newer one). A capture made in the last ``SAVE_PERIOD_S`` (plus the write's
own time) before a crash can still be replayed once after it (the same
bound as the sender's own risk: docs/security.md, "Residual risks"); a dead member's last
datagrams are long persisted by the time anyone could replay them.

Format: one line per sender, ``<prefix hex> <epoch> <seq>``, at most the bundle's size
(the caller only ever saves bundle prefixes; lines for prefixes outside the bundle are
ignored on load). A missing file is a first start; an unreadable or corrupt one is
reported and ignored (the receiver starts with empty windows, as before this file existed),
never a reason not to start. Written through the folder's descriptor, judged at each save
(``safeopen.write_atomic``: temp file, fsync, rename, folder fsync), so a crash mid-write
leaves the previous file and a folder swapped in at the path is never written into.

The one other module in ``swarmd.auth`` that touches a file (with ``epoch``); the daemon
calls it, the verifier itself stays sans-IO.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path
from typing import Final

from swarmd.auth.freshness import U32_MAX, Freshness
from swarmd.bundle.keys import node_state_path
from swarmd.bundle.safeopen import (
    TooLarge,
    judged_folder,
    open_folder,
    read_file,
    unreadable_why,
    write_atomic,
    writers_problem,
)

FILE_PATTERN: Final = "auth-windows-{node}"
# how often a moved window is written: an fsync every few seconds at most on an SD card
SAVE_PERIOD_S: Final = 2.0
# a file larger than this is not a window file (1000 senders x ~45 octets = 45 KB)
MAX_FILE_BYTES: Final = 1 << 20
_LINE: Final = re.compile(r"([0-9a-f]{24}) ([0-9]{1,10}) ([0-9]{1,10})")


@dataclass(frozen=True, slots=True)
class LoadedWindows:
    highs: dict[bytes, Freshness]
    problem: str | None  # why (part of) the file was not used, for the log


def windows_path(state_dir: str | Path, node: str) -> Path:
    return node_state_path(state_dir, FILE_PATTERN, node)


def encode_windows(highs: dict[bytes, Freshness]) -> bytes:
    lines = [f"{p.hex()} {f.epoch} {f.seq}\n" for p, f in sorted(highs.items())]
    return "".join(lines).encode("ascii")


def decode_windows(data: bytes) -> LoadedWindows:
    """Every well-formed line; the first malformed one is reported (and skipped)."""
    highs: dict[bytes, Freshness] = {}
    problem: str | None = None
    try:
        text = data.decode("ascii")
    except UnicodeDecodeError:
        return LoadedWindows({}, "corrupt (not ASCII)")
    for number, line in enumerate(text.splitlines(), 1):
        match = _LINE.fullmatch(line.strip())
        if match is None:
            problem = problem or f"corrupt line {number}"
            continue
        epoch, seq = int(match[2]), int(match[3])
        if epoch > U32_MAX or seq > U32_MAX:
            problem = problem or f"out of range at line {number}"
            continue
        highs[bytes.fromhex(match[1])] = Freshness(epoch, seq)
    return LoadedWindows(highs, problem)


def load_windows(path: Path) -> LoadedWindows:
    """The persisted highs; empty (problem None) for a missing file. Read through its
    folder's descriptor (``swarmd.bundle.safeopen``): the folder judged on it (one another
    user could write, or swapped in since the epoch's check, is not read), the file a
    regular one of a trusted owner (a FIFO never blocks the start), at most
    ``MAX_FILE_BYTES``."""
    try:
        folder = open_folder(path.parent)
    except OSError as exc:
        return LoadedWindows({}, f"unreadable ({unreadable_why(exc)})")
    if folder is None:
        return LoadedWindows({}, None)
    with folder:
        why = writers_problem(folder.info)
        if why is not None:
            return LoadedWindows({}, f"not read: folder {path.parent} is {why}")
        try:
            data = read_file(folder, path.name, MAX_FILE_BYTES)
        except FileNotFoundError:
            return LoadedWindows({}, None)
        except TooLarge:
            return LoadedWindows({}, f"larger than {MAX_FILE_BYTES} octets")
        except OSError as exc:
            return LoadedWindows({}, f"unreadable ({unreadable_why(exc)})")
    return decode_windows(data)


def save_windows(path: Path, highs: dict[bytes, Freshness]) -> None:
    """Durably replace the file. Raises ``OSError`` (the caller logs and carries on: the
    windows in memory still hold; only a restart would lose them). ``write_windows`` with
    ``encode_windows(highs)``: the daemon encodes on its loop and writes on its writer
    thread (``swarmd.filewriter``)."""
    write_windows(path, encode_windows(highs))


def write_windows(path: Path, data: bytes) -> None:
    """Replace the file with ``data`` (``encode_windows``'); blocking (two fsyncs), safe on
    another thread. Raises ``OSError``.

    Each save reopens the folder and judges it again on that descriptor, as ``load_windows``
    does, then writes through it (``safeopen.write_atomic``): a folder swapped in at the
    path since the start is refused (``SharedFolder``), never written into. Reopened, not
    held: the cost is one open and one ``fstat`` per save (at most one per
    ``SAVE_PERIOD_S``), and the daemon keeps no descriptor of its own for its whole life."""
    with judged_folder(path) as folder:
        write_atomic(folder, path.name, data, 0o640)
