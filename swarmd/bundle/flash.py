"""Flashing: put a verified bundle, the trust anchor and one node's private key on a drone.

Files in the target directory (``/var/lib/swarmd`` on a drone)::

    bundle.swb        the bundle the daemon loads            0644
    bundle.swb.prev   the one it replaced, for rollback      0644
    node.key          this node's private keys (Ed25519 +  0600  (node.key.prev on rotation)
                      X25519, docs/bundle-format.md)
    node.name         this node's participant name           0644
    swarm.pub         the trusted swarm signing public key   0644  (written once; see below)

Every file goes in by temp file + fsync + rename, so a power cut leaves either the old or the
new file, never a torn one; the previous bundle is hard-linked to ``bundle.swb.prev`` before
the rename, so ``bundle.swb`` never disappears, not even for an instant. After writing, the
files are read back and verified the way the daemon will (trust anchor on the target, hash,
signature, node key matching the bundle, key mode 0600); if that fails, the previous bundle
is restored.

Trust on first flash: ``swarm.pub`` is written when the target has none. When it has one and
the bundle is signed by another key, flashing refuses unless ``replace_trust`` (key rotation),
so a laptop with the wrong keys cannot silently re-anchor a drone.

Serials (docs/security.md, "Bundle rollback"): the daemon refuses at start a bundle whose
serial is below its floor (``bundle-floor-<node>`` beside node.key), or the floor's serial
with another hash (exit 78). ``flash`` refuses, before writing, a bundle below the serial of
the one the target carries or below its floor where readable (``allow_lower_serial``
overrides it; the daemon still refuses). ``rollback`` reads the target's floor and refuses
to restore a ``bundle.swb.prev`` the daemon would refuse: a rollback past a started daemon
is done by rebuilding the older mission with a higher serial.

The ssh form uses the system ``ssh``/``scp`` (the operator's agent, known_hosts and config
apply) and needs only POSIX sh, coreutils and tar on the drone.
"""

from __future__ import annotations

import contextlib
import hashlib
import io
import os
import re
import shlex
import subprocess
import tarfile
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Final

from swarmd.bundle.errors import BundleError, FlashError, KeyFileError, SerialRefused
from swarmd.bundle.floor import FILE_PATTERN as FLOOR_FILE_PATTERN
from swarmd.bundle.floor import FILE_PREFIX as FLOOR_FILE_PREFIX
from swarmd.bundle.floor import Floor, FloorError, floor_path, parse_floor, serial_of
from swarmd.bundle.floor import check as check_floor
from swarmd.bundle.keys import (
    PRIVATE_MODE,
    PUBLIC_MODE,
    fingerprint,
    fsync_dir,
    parse_node_keys,
    parse_public_key,
    public_pem,
    write_file_atomic,
)
from swarmd.bundle.loader import read_bundle
from swarmd.bundle.model import Bundle

BUNDLE_FILE: Final = "bundle.swb"
PREVIOUS_SUFFIX: Final = ".prev"
NODE_KEY_FILE: Final = "node.key"
NODE_NAME_FILE: Final = "node.name"
TRUST_FILE: Final = "swarm.pub"
DEFAULT_TARGET_DIR: Final = "/var/lib/swarmd"
# scp's remote side may hand the path to a shell (legacy protocol); a plain alphabet keeps
# quoting out of the picture entirely
_REMOTE_DIR_RE: Final = re.compile(r"[A-Za-z0-9_./+-]+")
_SSH_TIMEOUT_S: Final = 60.0
# options every flash passes: never prompt (a flash runs unattended from a checklist)
_SSH_DEFAULTS: Final = ("BatchMode=yes", "ConnectTimeout=10")


@dataclass(frozen=True, slots=True)
class Target:
    """Where to flash: a local directory (``host is None``) or ``[user@]host:DIR``."""

    directory: str
    host: str | None = None

    def __str__(self) -> str:
        return self.directory if self.host is None else f"{self.host}:{self.directory}"


def parse_target(text: str) -> Target:
    """``DIR`` or ``[user@]host:DIR`` (scp's rule: a ':' before any '/' means a host)."""
    colon = text.find(":")
    slash = text.find("/")
    if colon > 0 and (slash == -1 or colon < slash):
        host, directory = text[:colon], text[colon + 1 :]
        if not directory:
            directory = DEFAULT_TARGET_DIR
        if not _REMOTE_DIR_RE.fullmatch(directory):
            raise FlashError(
                f"{text}: remote directory {directory!r} has characters flash does not quote; "
                "fix: use letters, digits and ._/+-"
            )
        if host.startswith("-") or not host:
            raise FlashError(f"{text}: {host!r} is not a host; fix: write [user@]host:DIR")
        return Target(directory, host)
    return Target(text)


@dataclass(frozen=True, slots=True)
class FlashPayload:
    """What one node receives."""

    node: str
    bundle_data: bytes
    bundle: Bundle
    node_key_pem: bytes
    dev: bool

    @property
    def trust_pem(self) -> bytes:
        return public_pem(self.bundle.signing_public_key)


@dataclass(frozen=True, slots=True)
class FlashResult:
    node: str
    target: str
    content_sha256: str
    replaced_previous: bool
    trust_written: bool


@dataclass(frozen=True, slots=True)
class TargetState:
    """What a drone carries, verified the way its daemon will load it."""

    target: str
    node: str
    content_sha256: str
    swarm: str


def read_back(target: Target, ssh: Ssh | None = None) -> dict[str, tuple[bytes, int]]:
    """name -> (bytes, mode) of the flashed files (absent files are left out)."""
    names = (BUNDLE_FILE, TRUST_FILE, NODE_KEY_FILE, NODE_NAME_FILE)
    if target.host is None:
        d = Path(target.directory)
        out: dict[str, tuple[bytes, int]] = {}
        for name in names:
            with contextlib.suppress(FileNotFoundError):
                out[name] = ((d / name).read_bytes(), os.stat(d / name).st_mode & 0o7777)
        return out
    # one round trip: tar keeps the bytes and the key's mode; missing files are skipped
    listing = " ".join(names)
    raw = (ssh or Ssh()).run(
        target.host,
        f"cd {_q(target.directory)} && set -- && for f in {listing}; do "
        '[ -f "$f" ] && set -- "$@" "$f"; done; tar -cf - "$@"\n',
        "read back",
    )
    members: dict[str, tuple[bytes, int]] = {}
    try:
        with tarfile.open(fileobj=io.BytesIO(raw), mode="r:") as tar:
            for info in tar.getmembers():
                f = tar.extractfile(info)
                if f is not None and info.name in names:
                    members[info.name] = (f.read(), info.mode)
    except tarfile.TarError as exc:
        raise FlashError(f"{target}: cannot read the files back: {exc}") from None
    return members


def check_target(
    target: Target,
    *,
    expected_node: str | None = None,
    allow_dev: bool = False,
    ssh: Ssh | None = None,
) -> TargetState:
    """Verify a flashed drone: bundle against its own swarm.pub, node key against the
    bundle, key mode 0600. Raises ``FlashError`` (one line) naming the first problem."""
    files = read_back(target, ssh)
    where = str(target)
    for name in (BUNDLE_FILE, TRUST_FILE, NODE_KEY_FILE, NODE_NAME_FILE):
        if name not in files:
            raise FlashError(f"{where}: {name} is missing; fix: flash this node")
    trusted = _parse_trust(files[TRUST_FILE][0], where)
    try:
        bundle = read_bundle(
            files[BUNDLE_FILE][0],
            source=f"{where}/{BUNDLE_FILE}",
            trusted_key=trusted,
            allow_dev=allow_dev,
        )
    except BundleError as exc:
        raise FlashError(str(exc)) from None
    node = files[NODE_NAME_FILE][0].decode(errors="replace").strip()
    if expected_node is not None and node != expected_node:
        raise FlashError(f"{where}: carries node {node!r}, expected {expected_node!r}")
    try:
        participant = bundle.participant(node)
    except KeyError:
        raise FlashError(f"{where}: node {node!r} is not in the flashed bundle") from None
    key_pem, mode = files[NODE_KEY_FILE]
    try:
        keys = parse_node_keys(key_pem, f"{where}/{NODE_KEY_FILE}")
    except KeyFileError as exc:
        raise FlashError(str(exc)) from None
    if keys.public != (participant.announce_public_key, participant.x25519_public_key):
        raise FlashError(
            f"{where}/{NODE_KEY_FILE}: does not match {node!r}'s keys in the bundle; "
            "fix: flash the node with the keys directory the bundle was built from"
        )
    if mode & 0o777 != PRIVATE_MODE:
        raise FlashError(
            f"{where}/{NODE_KEY_FILE}: mode {mode & 0o777:o}, expected 600; fix: chmod 600"
        )
    return TargetState(where, node, bundle.content_sha256.hex(), bundle.swarm)


def _verify_flashed(payload: FlashPayload, target: Target, ssh: Ssh | None) -> None:
    try:
        state = check_target(target, expected_node=payload.node, allow_dev=payload.dev, ssh=ssh)
    except FlashError as exc:
        raise FlashError(f"verification after writing failed: {exc}") from None
    if state.content_sha256 != payload.bundle.content_sha256.hex():
        raise FlashError(f"{target}: the flashed bundle's hash differs from the one sent")


def _parse_trust(pem: bytes, where: str) -> bytes:
    try:
        return parse_public_key(pem, f"{where}/{TRUST_FILE}")
    except KeyFileError as exc:
        raise FlashError(f"{exc.file}: {exc.problem}; fix: remove it and flash again") from None


def _check_trust(existing: bytes | None, payload: FlashPayload, where: str, replace: bool) -> bool:
    """True when swarm.pub must be (re)written."""
    if existing is None:
        return True
    current = _parse_trust(existing, where)
    if current == payload.bundle.signing_public_key:
        return False
    if replace:
        return True
    raise FlashError(
        f"{where}: the drone trusts swarm key {fingerprint(current)} but the bundle is signed by "
        f"{fingerprint(payload.bundle.signing_public_key)}; fix: sign with the swarm key, or pass "
        "--replace-trust-key if you are rotating the swarm key"
    )


# -- local ------------------------------------------------------------------------------------


def flash_local(
    payload: FlashPayload, target: Target, *, replace_trust: bool = False
) -> FlashResult:
    """Flash into a local directory (a mounted SD card, a bench, a test)."""
    d = Path(target.directory)
    try:
        d.mkdir(parents=True, exist_ok=True)
        trust_path = d / TRUST_FILE
        existing = trust_path.read_bytes() if trust_path.exists() else None
        write_trust = _check_trust(existing, payload, str(target), replace_trust)
        if write_trust:
            write_file_atomic(trust_path, payload.trust_pem, PUBLIC_MODE)
        write_file_atomic(d / NODE_NAME_FILE, f"{payload.node}\n".encode(), PUBLIC_MODE)
        _keep_previous(d / NODE_KEY_FILE, payload.node_key_pem)
        write_file_atomic(d / NODE_KEY_FILE, payload.node_key_pem, PRIVATE_MODE)
        replaced = _keep_previous(d / BUNDLE_FILE, payload.bundle_data)
        write_file_atomic(d / BUNDLE_FILE, payload.bundle_data, PUBLIC_MODE)
    except OSError as exc:
        raise FlashError(f"{target}: cannot write: {exc.strerror} ({exc.filename})") from None
    try:
        _verify_flashed(payload, target, None)
    except FlashError:
        if replaced:  # back to what the drone carried a moment ago: no serial check
            _restore_local(target)
        raise
    return FlashResult(
        payload.node, str(target), payload.bundle.content_sha256.hex(), replaced, write_trust
    )


def _keep_previous(path: Path, new: bytes) -> bool:
    """Hard-link the current file to ``<path>.prev`` (atomically) unless it equals ``new``."""
    if not path.exists() or path.read_bytes() == new:
        return False
    tmp = path.with_name(f".{path.name}.prev.tmp-{os.getpid()}")
    with contextlib.suppress(FileNotFoundError):
        tmp.unlink()
    os.link(path, tmp)
    os.replace(tmp, path.with_name(path.name + PREVIOUS_SUFFIX))
    fsync_dir(path.parent)
    return True


def rollback_local(target: Target) -> None:
    """Put ``bundle.swb.prev`` (and ``node.key.prev``) back in place, unless the target's
    floor says its swarmd would refuse it (``SerialRefused``, nothing moved)."""
    files = _serial_files(target, None, strict=True)
    _check_rollback(files, target)
    _restore_local(target)


def _restore_local(target: Target) -> None:
    d = Path(target.directory)
    prev = d / (BUNDLE_FILE + PREVIOUS_SUFFIX)
    if not prev.exists():
        raise FlashError(f"{target}: no {prev.name} to roll back to")
    for name in (NODE_KEY_FILE, BUNDLE_FILE):
        old = d / (name + PREVIOUS_SUFFIX)
        if old.exists():
            os.replace(old, d / name)
    fsync_dir(d)


# -- ssh --------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Ssh:
    """The system ssh/scp with the operator's extra ``-o`` options."""

    options: tuple[str, ...] = ()

    def _opts(self) -> list[str]:
        out: list[str] = []
        # ssh keeps the first value it sees per option, so the operator's options come first
        for opt in (*self.options, *_SSH_DEFAULTS):
            out += ["-o", opt]
        return out

    def run(self, host: str, script: str, what: str) -> bytes:
        """Run ``script`` with ``sh`` on ``host`` (script on stdin: no remote quoting)."""
        argv = ["ssh", *self._opts(), "--", host, "sh", "-s"]
        return self._call(argv, script.encode(), what, host)

    def copy(self, files: Sequence[Path], host: str, remote_dir: str, what: str) -> None:
        argv = ["scp", "-q", "-p", *self._opts(), "--", *map(str, files), f"{host}:{remote_dir}/"]
        self._call(argv, b"", what, host)

    def _call(self, argv: list[str], stdin: bytes, what: str, host: str) -> bytes:
        try:
            proc = subprocess.run(  # noqa: S603 - argv list; the host and paths are validated
                argv, input=stdin, capture_output=True, timeout=_SSH_TIMEOUT_S, check=False
            )
        except FileNotFoundError:
            raise FlashError(f"{argv[0]} not found; fix: install openssh-client") from None
        except subprocess.TimeoutExpired:
            raise FlashError(f"{host}: {what}: timed out after {_SSH_TIMEOUT_S:g} s") from None
        if proc.returncode != 0:
            err = proc.stderr.decode(errors="replace").strip().splitlines()
            detail = err[-1] if err else f"exit status {proc.returncode}"
            raise FlashError(
                f"{host}: {what} failed: {detail}; fix: check that 'ssh {host}' works "
                "(address, key, --ssh-option)"
            )
        return proc.stdout


def _q(text: str) -> str:
    return shlex.quote(text)


def flash_ssh(
    payload: FlashPayload, target: Target, ssh: Ssh, *, replace_trust: bool = False
) -> FlashResult:
    """Flash over ssh: stage with scp in the target directory, then rename into place."""
    assert target.host is not None  # noqa: S101 - callers dispatch on host
    host, d = target.host, target.directory
    # 1. make the directory and a staging dir on the same filesystem (rename stays atomic);
    #    report the current trust anchor and bundle digest
    out = ssh.run(
        host,
        f'set -eu\nd={_q(d)}\nmkdir -p "$d"\nmktemp -d "$d/.flash.XXXXXX"\n'
        f'if [ -f "$d/{BUNDLE_FILE}" ]; then sha256sum "$d/{BUNDLE_FILE}"; else echo none; fi\n'
        f'if [ -f "$d/{NODE_KEY_FILE}" ]; then sha256sum "$d/{NODE_KEY_FILE}"; else echo none; fi\n'
        f'cat "$d/{TRUST_FILE}" 2>/dev/null || true\n',
        "prepare",
    )
    lines = out.decode(errors="replace").split("\n", 3)
    if len(lines) < 4:
        raise FlashError(f"{host}: unexpected answer from the drone's shell: {out[:80]!r}")
    staging, bundle_sum, key_sum, trust_text = lines
    existing_trust = trust_text.encode() if trust_text.strip() else None
    try:
        write_trust = _check_trust(existing_trust, payload, str(target), replace_trust)
    except FlashError:
        ssh.run(host, f"rm -rf {_q(staging)}\n", "clean up")
        raise
    replaced = bundle_sum != "none" and bundle_sum.split()[0] != _sha(payload.bundle_data)
    key_rotated = key_sum != "none" and key_sum.split()[0] != _sha(payload.node_key_pem)

    # 2. copy the files into the staging dir
    with tempfile.TemporaryDirectory(prefix="swarmd-flash-") as tmp:
        t = Path(tmp)
        files = {
            BUNDLE_FILE: (payload.bundle_data, PUBLIC_MODE),
            NODE_KEY_FILE: (payload.node_key_pem, PRIVATE_MODE),
            NODE_NAME_FILE: (f"{payload.node}\n".encode(), PUBLIC_MODE),
            TRUST_FILE: (payload.trust_pem, PUBLIC_MODE),
        }
        for name, (data, mode) in files.items():
            write_file_atomic(t / name, data, mode)
        ssh.copy([t / n for n in files], host, staging, "copy")

    # 3. fsync, keep the previous files, rename into place
    script = [
        "set -eu",
        f"d={_q(d)}",
        f"s={_q(staging)}",
        f'chmod 600 "$s/{NODE_KEY_FILE}"',
        f'chmod 644 "$s/{BUNDLE_FILE}" "$s/{NODE_NAME_FILE}" "$s/{TRUST_FILE}"',
        'sync "$s"/*',  # coreutils sync FILE... fsyncs each file
    ]
    if key_rotated:
        script += _link_prev_sh(NODE_KEY_FILE)
    if replaced:
        script += _link_prev_sh(BUNDLE_FILE)
    if write_trust:
        script.append(f'mv -f "$s/{TRUST_FILE}" "$d/{TRUST_FILE}"')
    script += [
        f'mv -f "$s/{NODE_NAME_FILE}" "$d/{NODE_NAME_FILE}"',
        f'mv -f "$s/{NODE_KEY_FILE}" "$d/{NODE_KEY_FILE}"',
        f'mv -f "$s/{BUNDLE_FILE}" "$d/{BUNDLE_FILE}"',
        'sync "$d"',
        'rm -rf "$s"',
    ]
    ssh.run(host, "\n".join(script) + "\n", "install")

    # 4. read back and verify
    try:
        _verify_flashed(payload, target, ssh)
    except FlashError:
        if replaced:  # back to what the drone carried a moment ago: no serial check
            _restore_ssh(target, ssh, None)
        raise
    return FlashResult(
        payload.node, str(target), payload.bundle.content_sha256.hex(), replaced, write_trust
    )


def _link_prev_sh(name: str) -> list[str]:
    return [
        f'ln -f "$d/{name}" "$d/.{name}.prev.tmp"',
        f'mv -f "$d/.{name}.prev.tmp" "$d/{name}{PREVIOUS_SUFFIX}"',
    ]


def _sha(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def rollback_ssh(target: Target, ssh: Ssh) -> None:
    """``rollback_local`` over ssh: the floor check runs here on the files read back (one
    round trip), and the restore only if ``bundle.swb.prev`` still has the checked hash."""
    files = _serial_files(target, ssh, strict=True)
    checked = _check_rollback(files, target)
    _restore_ssh(target, ssh, _sha(checked))


def _restore_ssh(target: Target, ssh: Ssh, prev_sha256: str | None) -> None:
    assert target.host is not None  # noqa: S101 - callers dispatch on host
    prev = BUNDLE_FILE + PREVIOUS_SUFFIX
    script = [
        "set -eu",
        f"d={_q(target.directory)}",
        f'[ -f "$d/{prev}" ] || {{ echo "no {prev} to roll back to" >&2; exit 1; }}',
    ]
    if prev_sha256 is not None:  # what was checked is what is restored
        script.append(
            f'[ "$(sha256sum < "$d/{prev}" | cut -d" " -f1)" = {prev_sha256} ] || '
            f'{{ echo "{prev} changed since it was checked; run rollback again" >&2; exit 1; }}'
        )
    script += [
        f'if [ -f "$d/{NODE_KEY_FILE}{PREVIOUS_SUFFIX}" ]; then '
        f'mv -f "$d/{NODE_KEY_FILE}{PREVIOUS_SUFFIX}" "$d/{NODE_KEY_FILE}"; fi',
        f'mv -f "$d/{prev}" "$d/{BUNDLE_FILE}"',
        'sync "$d"',
    ]
    ssh.run(target.host, "\n".join(script) + "\n", "roll back")


def flash(
    payload: FlashPayload,
    target: Target,
    *,
    ssh: Ssh | None = None,
    replace_trust: bool = False,
    allow_lower_serial: bool = False,
) -> FlashResult:
    """Flash ``payload`` to ``target`` (local directory or ssh). ``SerialRefused`` before
    anything is written when its serial is below the target's (``check_flash_serial``),
    after the trust anchor check."""
    if not allow_lower_serial:
        check_flash_serial(payload, target, ssh=ssh, replace_trust=replace_trust)
    if target.host is None:
        return flash_local(payload, target, replace_trust=replace_trust)
    return flash_ssh(payload, target, ssh or Ssh(), replace_trust=replace_trust)


def rollback(target: Target, *, ssh: Ssh | None = None) -> None:
    if target.host is None:
        rollback_local(target)
    else:
        rollback_ssh(target, ssh or Ssh())


# -- the serial guard (docs/security.md, "Bundle rollback") -----------------------------------

_PREV_FILE: Final = BUNDLE_FILE + PREVIOUS_SUFFIX
_FLOOR_GLOB: Final = FLOOR_FILE_PATTERN.format(node="*")
# stands for a floor file that exists but this user cannot read (a real file never holds
# it: a name is not bytes a file can have)
_UNREADABLE: Final = "unreadable"
_Files = dict[str, bytes | str]


def _serial_files(target: Target, ssh: Ssh | None, *, strict: bool) -> _Files:
    """name -> bytes of the target's bundle, previous bundle, node name, trust anchor and
    floor files (absent ones left out). A floor file this user cannot read is ``_UNREADABLE`` when
    ``strict`` (a rollback must not pass for want of it), else left out (a flash checks
    the floor where readable, and the current bundle's serial in any case)."""
    if target.host is None:
        d = Path(target.directory)
        out: _Files = {}
        names = (BUNDLE_FILE, _PREV_FILE, NODE_NAME_FILE, TRUST_FILE)
        for path in [*(d / name for name in names), *d.glob(_FLOOR_GLOB)]:
            try:
                out[path.name] = path.read_bytes()
            except FileNotFoundError:
                continue
            except OSError as exc:
                if path.name.startswith(FLOOR_FILE_PREFIX):
                    if strict:
                        out[path.name] = _UNREADABLE
                    continue
                raise FlashError(f"{target}: cannot read {path.name}: {exc.strerror}") from None
        return out
    assert target.host is not None  # noqa: S101 - dispatched on host above
    # one round trip; an unreadable floor is named on stderr of a failing script (strict)
    # or skipped, so tar never stops on it
    unreadable = (
        '[ -r "$f" ] || { echo "cannot read $f (the floor of swarmd on this drone): run the '
        'rollback as its owner or root" >&2; exit 3; }'
        if strict
        else '[ -r "$f" ] || continue'
    )
    # a first flash: no directory, or none of the files (nothing printed, nothing to check)
    raw = (ssh or Ssh()).run(
        target.host,
        f"cd {_q(target.directory)} 2>/dev/null || exit 0; set -- && "
        f"for f in {BUNDLE_FILE} {_PREV_FILE} {NODE_NAME_FILE} {TRUST_FILE} {_FLOOR_GLOB}; do "
        f'[ -f "$f" ] || continue; {unreadable}; set -- "$@" "$f"; done; '
        '[ "$#" -eq 0 ] || tar -cf - "$@"\n',
        "read the serials" if strict else "prepare",  # a flash's first contact: its prepare
    )
    members: _Files = {}
    if not raw:
        return members
    try:
        with tarfile.open(fileobj=io.BytesIO(raw), mode="r:") as tar:
            for info in tar.getmembers():
                f = tar.extractfile(info)
                if f is not None:
                    members[info.name] = f.read()
    except tarfile.TarError as exc:
        raise FlashError(f"{target}: cannot read the files back: {exc}") from None
    return members


def _decoded(data: bytes, source: str) -> Bundle | None:
    """The bundle in ``data`` without a trust anchor (only its serial and hash are used:
    the daemon verifies the signature); None when it is no bundle."""
    try:
        return read_bundle(data, source=source, allow_dev=True, require_anchor=False)
    except BundleError:
        return None


def _floor_on(files: _Files, target: Target, node: str) -> tuple[Floor, str] | None:
    """The floor of ``node`` among the files read from ``target``, with its path."""
    path = floor_path(target.directory, node)
    raw = files.get(path.name)
    where = f"{target}/{path.name}" if target.host is not None else str(path)
    if raw is None:
        return None
    if isinstance(raw, str):  # _UNREADABLE
        raise SerialRefused(
            f"{where}: cannot read this node's bundle floor; fix: run as its owner or root"
        )
    try:
        return parse_floor(raw, path, f"{target}/{BUNDLE_FILE}"), where
    except FloorError as exc:
        raise SerialRefused(str(exc)) from None


def _check_rollback(files: _Files, target: Target) -> bytes:
    """The ``bundle.swb.prev`` to restore; ``SerialRefused`` when swarmd on the target
    would refuse it at start (below its floor, or the floor's serial with another hash)."""
    prev = files.get(_PREV_FILE)
    if not isinstance(prev, bytes):
        raise FlashError(f"{target}: no {_PREV_FILE} to roll back to")
    name = files.get(NODE_NAME_FILE)
    if isinstance(name, bytes):
        nodes = [name.decode(errors="replace").strip()]
    else:  # no node name: every floor present counts (the strictest)
        nodes = [
            n.removeprefix(FLOOR_FILE_PREFIX) for n in files if n.startswith(FLOOR_FILE_PREFIX)
        ]
    source = f"{target}/{_PREV_FILE}"
    for node in nodes:
        found = _floor_on(files, target, node)
        if found is None:
            continue
        floor, where = found
        bundle = _decoded(prev, source)
        if bundle is None:
            raise SerialRefused(
                f"{target}: rollback refused: {_PREV_FILE} is not a readable bundle, and "
                f"swarmd there keeps a floor ({where}); fix: flash the bundle you want"
            )
        try:
            check_floor(bundle, floor, source=source, path=Path(where))
        except BundleError as exc:
            raise SerialRefused(
                f"{target}: rollback refused, swarmd there would not start on it (exit 78): {exc}"
            ) from None
    return prev


def check_flash_serial(
    payload: FlashPayload, target: Target, *, ssh: Ssh | None, replace_trust: bool = False
) -> None:
    """``SerialRefused`` when ``payload``'s serial is below the serial of the bundle the
    target carries, or fails the target's floor for ``payload.node`` where readable (below
    it, or its serial with another hash: what swarmd there would refuse at start).

    The signer is checked against the drone's trust anchor first (``_check_trust``'s
    ``FlashError``): a bundle of another swarm's keys is refused for its key, not for a
    serial whose fix (``--serial``) would not help (docs/preflight.md)."""
    files = _serial_files(target, ssh, strict=False)
    trust = files.get(TRUST_FILE)
    _check_trust(trust if isinstance(trust, bytes) else None, payload, str(target), replace_trust)
    new = payload.bundle
    current_data = files.get(BUNDLE_FILE)
    current = _decoded(current_data, BUNDLE_FILE) if isinstance(current_data, bytes) else None
    override = "--allow-lower-serial flashes it anyway, and swarmd there still refuses it"
    if current is not None and serial_of(new) < serial_of(current):
        higher = serial_of(current) + 1
        raise SerialRefused(
            f"{target}: flash refused: the bundle's serial {serial_of(new)} is below the "
            f"serial {serial_of(current)} of the bundle the drone carries (sha256 "
            f"{current.content_sha256.hex()}): an older bundle; fix: flash the newest "
            f"bundle, or rebuild this mission with 'swarmctl bundle build --serial {higher}' "
            f"({override})"
        )
    try:
        found = _floor_on(files, target, payload.node)
    except SerialRefused:
        found = None  # a floor that does not parse: the daemon says so at start
    if found is None:
        return
    floor, where = found
    try:
        check_floor(new, floor, source=f"{target}/{BUNDLE_FILE}", path=Path(where))
    except BundleError as exc:
        raise SerialRefused(
            f"{target}: flash refused, swarmd there would not start on it (exit 78): {exc} "
            f"({override})"
        ) from None
