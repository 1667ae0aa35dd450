"""Keys for the bundle: the swarm signing key and two keys per node.

Layout of a keys directory (``swarmctl bundle keygen --out DIR``)::

    DIR/swarm-signing.key     PKCS#8 PEM, mode 0600   signs bundles (stays on the ground laptop)
    DIR/swarm-signing.pub     SubjectPublicKeyInfo PEM the trust anchor each drone is given
    DIR/nodes/<name>.key      two PKCS#8 PEM blocks,  flashed to that drone only (node.key):
                              mode 0600               Ed25519 (signs its SPDP), then X25519
                                                      (static Diffie-Hellman for pairwise MACs)
    DIR/nodes/<name>.pub      two public PEM blocks   embedded in the bundle for every node

Embedding every node's public keys in the signed bundle is what lets authenticated discovery
and data run without any key exchange on the air (paper Appendix B measured how much a
runtime Diffie-Hellman exchange costs on the channel): a node signs with its Ed25519 key and
derives a key shared with each peer from its X25519 key and the peer's public one
(``swarmd.auth.keys``, docs/security.md).

A node key file with only the Ed25519 block was written before authenticated discovery
(bundle format 1); it is refused with a line naming the fix (``NodeKeyFormatError``).

Dev keys (``--unsigned-dev``) are derived from public strings, so anyone can recompute them:
they only make dev bundles byte-for-byte reproducible and catch accidental corruption.
"""

from __future__ import annotations

import contextlib
import errno
import hashlib
import os
import re
import stat
from dataclasses import dataclass, field
from pathlib import Path
from typing import Final

from cryptography.exceptions import UnsupportedAlgorithm
from cryptography.hazmat.primitives import serialization
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey, Ed25519PublicKey
from cryptography.hazmat.primitives.asymmetric.x25519 import X25519PrivateKey, X25519PublicKey

from swarmd.bundle.errors import KeyFileError
from swarmd.bundle.safeopen import (
    TEMP_TOKEN_BYTES,
    Folder,
    open_folder,
    unreadable_why,
    write_atomic,
    writers_problem,
)

SIGNING_KEY_FILE: Final = "swarm-signing.key"
SIGNING_PUB_FILE: Final = "swarm-signing.pub"
NODES_DIR: Final = "nodes"
PRIVATE_MODE: Final = 0o600
PUBLIC_MODE: Final = 0o644
PUBLIC_KEY_BYTES: Final = 32
_DEV_DOMAIN: Final = b"swarmd insecure dev key v1|"
_PEM_BLOCK: Final = re.compile(
    rb"-----BEGIN ([A-Z ]+)-----\r?\n.*?-----END \1-----\r?\n?", re.DOTALL
)
REKEY_FIX: Final = (
    "run 'swarmctl bundle keygen --out DIR --mission MISSION' (adds the X25519 key, keeps the "
    "Ed25519 one), rebuild with 'swarmctl bundle build' and re-flash with 'swarmctl bundle flash'"
)


def raw_public(key: Ed25519PrivateKey | Ed25519PublicKey) -> bytes:
    """The 32 raw bytes of a public key (RFC 8032 encoding)."""
    pub = key.public_key() if isinstance(key, Ed25519PrivateKey) else key
    return pub.public_bytes(serialization.Encoding.Raw, serialization.PublicFormat.Raw)


def fingerprint(public_key: bytes) -> str:
    """A short, stable label for a public key: ``SHA256:`` + the first 8 bytes in hex."""
    return "SHA256:" + hashlib.sha256(public_key).digest()[:8].hex()


def private_pem(key: Ed25519PrivateKey) -> bytes:
    return key.private_bytes(
        serialization.Encoding.PEM,
        serialization.PrivateFormat.PKCS8,
        serialization.NoEncryption(),
    )


def public_pem(public_key: bytes) -> bytes:
    return Ed25519PublicKey.from_public_bytes(public_key).public_bytes(
        serialization.Encoding.PEM, serialization.PublicFormat.SubjectPublicKeyInfo
    )


def dev_signing_key(swarm: str) -> Ed25519PrivateKey:
    """The publicly derivable signing key of ``--unsigned-dev`` bundles (no secrecy at all)."""
    return Ed25519PrivateKey.from_private_bytes(
        hashlib.sha256(_DEV_DOMAIN + b"signing|" + swarm.encode()).digest()
    )


def dev_node_key(swarm: str, name: str) -> Ed25519PrivateKey:
    """A node's publicly derivable announcement key in a dev bundle (no secrecy at all)."""
    return Ed25519PrivateKey.from_private_bytes(
        hashlib.sha256(_DEV_DOMAIN + b"node|" + swarm.encode() + b"|" + name.encode()).digest()
    )


def dev_node_x25519_key(swarm: str, name: str) -> X25519PrivateKey:
    """A node's publicly derivable X25519 key in a dev bundle (no secrecy at all)."""
    seed = _DEV_DOMAIN + b"node-x25519|" + swarm.encode() + b"|" + name.encode()
    return X25519PrivateKey.from_private_bytes(hashlib.sha256(seed).digest())


def raw_x25519_public(key: X25519PrivateKey | X25519PublicKey) -> bytes:
    """The 32 raw bytes of an X25519 public key (RFC 7748)."""
    pub = key.public_key() if isinstance(key, X25519PrivateKey) else key
    return pub.public_bytes(serialization.Encoding.Raw, serialization.PublicFormat.Raw)


@dataclass(frozen=True, slots=True)
class NodeKeys:
    """One node's two private keys, as node.key holds them."""

    ed25519: Ed25519PrivateKey
    x25519: X25519PrivateKey

    @property
    def public(self) -> tuple[bytes, bytes]:
        """(Ed25519 announcement public key, X25519 public key), raw."""
        return raw_public(self.ed25519), raw_x25519_public(self.x25519)

    def pem(self) -> bytes:
        """The node.key file: the Ed25519 PKCS#8 block, then the X25519 one."""
        x = self.x25519.private_bytes(
            serialization.Encoding.PEM,
            serialization.PrivateFormat.PKCS8,
            serialization.NoEncryption(),
        )
        return private_pem(self.ed25519) + x

    def public_pem(self) -> bytes:
        """The nodes/<name>.pub file: both public keys as SubjectPublicKeyInfo blocks."""
        ed, x = self.public
        return public_pem(ed) + X25519PublicKey.from_public_bytes(x).public_bytes(
            serialization.Encoding.PEM, serialization.PublicFormat.SubjectPublicKeyInfo
        )


def dev_node_keys(swarm: str, name: str) -> NodeKeys:
    """Both publicly derivable keys of a node in a dev bundle."""
    return NodeKeys(dev_node_key(swarm, name), dev_node_x25519_key(swarm, name))


def _pem_blocks(data: bytes) -> list[bytes]:
    return [m.group(0) for m in _PEM_BLOCK.finditer(data)]


def parse_node_keys(data: bytes, source: str) -> NodeKeys:
    """A node key file (Ed25519 + X25519 PKCS#8 blocks); ``KeyFileError`` (one line) otherwise.

    A file with an Ed25519 key and no X25519 key predates authenticated discovery: the
    error names the field and the fix (new keys, rebuild, re-flash)."""
    ed: Ed25519PrivateKey | None = None
    x: X25519PrivateKey | None = None
    for block in _pem_blocks(data):
        try:
            key = serialization.load_pem_private_key(block, password=None)
        except (ValueError, TypeError, UnsupportedAlgorithm):
            continue
        if isinstance(key, Ed25519PrivateKey) and ed is None:
            ed = key
        elif isinstance(key, X25519PrivateKey) and x is None:
            x = key
    if ed is None:
        raise KeyFileError(
            source,
            "no Ed25519 private key (not a node key file)",
            "give the node key written by 'swarmctl bundle keygen'",
        )
    if x is None:
        raise KeyFileError(
            source,
            "field x25519 private key missing: this node key was made before authenticated "
            "discovery (bundle format 1)",
            REKEY_FIX,
        )
    return NodeKeys(ed, x)


def load_node_keys(path: str | Path) -> NodeKeys:
    """Read a node key file (``nodes/<name>.key`` or a drone's ``node.key``)."""
    return parse_node_keys(_read(path, "run 'swarmctl bundle keygen --out DIR'"), str(path))


def parse_node_public_keys(data: bytes, source: str) -> tuple[bytes, bytes]:
    """(Ed25519, X25519) raw public keys from a ``nodes/<name>.pub`` file."""
    ed: bytes | None = None
    x: bytes | None = None
    for block in _pem_blocks(data):
        try:
            key = serialization.load_pem_public_key(block)
        except (ValueError, TypeError, UnsupportedAlgorithm):
            continue
        if isinstance(key, Ed25519PublicKey) and ed is None:
            ed = raw_public(key)
        elif isinstance(key, X25519PublicKey) and x is None:
            x = raw_x25519_public(key)
    if ed is None:
        raise KeyFileError(source, "no Ed25519 public key", "use keygen's nodes/<name>.pub")
    if x is None:
        raise KeyFileError(
            source,
            "field x25519 public key missing: made before authenticated discovery",
            REKEY_FIX,
        )
    return ed, x


def load_node_public_keys(path: str | Path) -> tuple[bytes, bytes]:
    return parse_node_public_keys(_read(path, "run 'swarmctl bundle keygen'"), str(path))


def load_private_key(path: str | Path) -> Ed25519PrivateKey:
    """Read a PKCS#8 PEM Ed25519 private key; ``KeyFileError`` (one line) otherwise."""
    data = _read(path, "run 'swarmctl bundle keygen --out DIR' to make keys")
    return parse_private_key(data, str(path))


def parse_private_key(data: bytes, source: str) -> Ed25519PrivateKey:
    """An Ed25519 private key from unencrypted PKCS#8 PEM; ``source`` labels errors."""
    try:
        key = serialization.load_pem_private_key(data, password=None)
    except (ValueError, TypeError, UnsupportedAlgorithm):
        raise KeyFileError(
            source,
            "not an unencrypted PEM private key",
            "give a key file written by 'swarmctl bundle keygen'",
        ) from None
    if not isinstance(key, Ed25519PrivateKey):
        raise KeyFileError(source, "not an Ed25519 key", "use 'swarmctl bundle keygen' keys")
    return key


def load_public_key(path: str | Path) -> bytes:
    """Read a public key file as raw bytes: PEM (SubjectPublicKeyInfo) or 64 hex digits."""
    return parse_public_key(_read(path, "give the swarm's swarm-signing.pub"), str(path))


def parse_public_key(data: bytes, source: str) -> bytes:
    """Raw bytes of a public key given as PEM or 64 hex digits; ``source`` labels errors."""
    text = data.strip()
    if len(text) == 2 * PUBLIC_KEY_BYTES:
        with contextlib.suppress(ValueError):
            return bytes.fromhex(text.decode("ascii", "replace"))
    try:
        key = serialization.load_pem_public_key(text)
    except (ValueError, TypeError, UnsupportedAlgorithm):
        raise KeyFileError(
            source,
            "not a PEM public key or 64 hex digits",
            "give the swarm-signing.pub written by 'swarmctl bundle keygen'",
        ) from None
    if not isinstance(key, Ed25519PublicKey):
        raise KeyFileError(source, "not an Ed25519 public key", "use keygen's .pub file")
    return raw_public(key)


def node_key_path(keys_dir: str | Path, name: str) -> Path:
    return Path(keys_dir) / NODES_DIR / f"{name}.key"


def node_public_path(keys_dir: str | Path, name: str) -> Path:
    return Path(keys_dir) / NODES_DIR / f"{name}.pub"


def _read(path: str | Path, fix: str) -> bytes:
    try:
        return Path(path).read_bytes()
    except FileNotFoundError:
        raise KeyFileError(str(path), "key file not found", fix) from None
    except OSError as exc:
        raise KeyFileError(str(path), f"cannot read key file: {exc.strerror}", fix) from None


def write_file_atomic(path: Path, data: bytes, mode: int) -> None:
    """Write ``data`` to ``path`` via a same-directory temp file, fsync and rename
    (``safeopen.write_atomic``, every step through one descriptor of the folder).

    The temp file is created with ``mode`` already set, so a private key is never readable
    by others, not even for the instant between create and chmod. Its name is random and
    it is created ``O_EXCL | O_NOFOLLOW``: with a predictable name (it was
    ``.<name>.tmp-<pid>``) a symlink planted there by anyone who can write the folder made
    us truncate and overwrite what it pointed at (docs/security-history.md,
    "Local boundaries (session 10 review)"); now a planted name is never opened, only missed.
    The folder is not judged here (the keygen's, the flasher's): the state files' writers
    judge theirs first and write through ``safeopen.write_atomic`` with that descriptor.
    """
    path.parent.mkdir(parents=True, exist_ok=True)
    folder = open_folder(path.parent, follow=True)
    if folder is None:
        raise FileNotFoundError(errno.ENOENT, "folder vanished", str(path.parent))
    with folder:
        write_atomic(folder, path.name, data, mode)


def remove_left_temps(path: Path, folder: Folder | None = None) -> int:
    """Remove the temporary files ``write_file_atomic`` left beside ``path`` when its
    process died mid-write (``kill -9``, a power cut: tests/test_cmd_state_kill.py), and
    return how many. Call it at start-up, before anything of this daemon writes ``path``.

    Only this file's own temp names (``.<name>.tmp-<16 hex>``: another node's file and its
    writer, in a shared folder, are never touched), only regular files (``lstat``: a
    symlink or a folder of that name is left, never followed) owned by this process's
    uid. ``folder``: ``path``'s folder as its caller opened and judged it (None: opened
    here), so the names listed and removed are in the folder judged (``safeopen``)."""
    pattern = re.compile(re.escape(f".{path.name}.tmp-") + f"[0-9a-f]{{{2 * TEMP_TOKEN_BYTES}}}")
    opened = folder if folder is not None else open_folder(path.parent, follow=True)
    if opened is None:
        return 0
    removed = 0
    try:
        handle = opened.handle()
        try:
            entries = list(os.scandir(handle))
        finally:
            os.close(handle)
        for entry in entries:
            if not pattern.fullmatch(entry.name):
                continue
            try:
                info = os.stat(entry.name, dir_fd=opened.fd, follow_symlinks=False)
                if not stat.S_ISREG(info.st_mode) or info.st_uid != os.geteuid():
                    continue
                os.unlink(entry.name, dir_fd=opened.fd)
            except FileNotFoundError:
                continue
            removed += 1
    finally:
        if folder is None:
            opened.close()
    return removed


def others_can_write(directory: Path, also: frozenset[int] = frozenset()) -> str | None:
    """Why another local user could write ``directory`` (a folder: plant or swap files in
    it; a file: rewrite it), or None when nobody but root, swarmd and this daemon's user can
    (``also``: the uids of the daemon's user as ``check-config`` judges it for a unit).

    swarmd's state (boot counter, executed command ids, epoch, replay windows, node.key)
    and its trust anchors (config, bundle, swarm key) are only as trustworthy as where
    they are read from: writable by a group or by everyone, or owned by another user, lets
    that user plant a state file or a key the daemon believes (docs/security-history.md,
    "Local boundaries (session 10 review)"). Root owning it is fine (root is out of scope). A
    missing or unreachable path is not refused here: the caller creates it, as its own,
    or fails to with its own one line. By path: the state folders are judged on their
    descriptor (``refuse_shared_dir``, ``safeopen.writers_problem``), the same rules.
    """
    try:
        st = os.stat(directory)
    except OSError:
        return None
    return writers_problem(st, also)


# what may stay of a node name in a state file's name (the rest becomes "_"): a name is the
# operator's text, and "/" would put the file in another folder
_STATE_NAME_UNSAFE: Final = re.compile(r"[^A-Za-z0-9._-]")


def node_state_path(state_dir: str | Path, pattern: str, node: str) -> Path:
    """A node's state file in ``state_dir``: ``pattern`` (``"auth-epoch-{node}"``) with
    ``node`` made safe for a file name. The boot epoch, the replay windows, the bundle floor
    and the data plane's state file are all named so."""
    return Path(state_dir) / pattern.format(node=_STATE_NAME_UNSAFE.sub("_", node))


def open_state_dir(directory: Path, field: str, error: type[OSError]) -> Folder | None:
    """The state folder ``directory`` opened once (``safeopen.open_folder``: its last
    component not followed), None when it does not exist yet; ``error`` (one line naming
    the folder, ``field`` and the fix) when it cannot be opened as a folder. The caller
    judges it (``refuse_shared_dir``) and reads and writes its files through it."""
    try:
        return open_folder(directory)
    except OSError as exc:
        raise error(
            f"{directory} cannot be opened as a folder ({unreadable_why(exc)}), so swarmd's "
            f"state cannot be judged there; fix: point {field} at a real folder only swarmd "
            "writes (/var/lib/swarmd)"
        ) from None


def refuse_shared_dir(
    folder: Folder | None, field: str, error: type[OSError], also: frozenset[int] = frozenset()
) -> None:
    """Raise ``error`` (one line naming the folder, the config field and the fix) when
    another local user could write ``folder`` (judged on its descriptor: the folder read and
    written afterwards is this one, whatever its path names by then; ``writers_problem``,
    ``also``). A folder that does not exist yet (None) is the caller's to create."""
    why = None if folder is None else writers_problem(folder.info, also)
    if folder is not None and why is not None:
        raise error(
            f"{folder.path} is {why}, so another user could plant swarmd's state there; "
            f"fix: chown it to swarmd and chmod 700 it, or point {field} at a folder "
            "only swarmd writes (/var/lib/swarmd)"
        )


def fsync_dir(directory: Path) -> None:
    """Make a rename in ``directory`` durable (POSIX: the directory entry needs its own fsync)."""
    fd = os.open(directory, os.O_RDONLY | os.O_DIRECTORY | os.O_CLOEXEC)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


@dataclass
class KeygenResult:
    created: list[Path] = field(default_factory=list)
    kept: list[Path] = field(default_factory=list)
    upgraded: list[Path] = field(default_factory=list)  # format-1 node keys given X25519


def _make_pair(key_path: Path, pub_path: Path, force: bool, result: KeygenResult) -> None:
    if key_path.exists() and not force:
        # Keeping existing keys means adding a drone to a mission never rotates the others.
        key = load_private_key(key_path)
        if not pub_path.exists():
            write_file_atomic(pub_path, public_pem(raw_public(key)), PUBLIC_MODE)
            result.created.append(pub_path)
        result.kept.append(key_path)
        return
    key = Ed25519PrivateKey.generate()
    write_file_atomic(key_path, private_pem(key), PRIVATE_MODE)
    write_file_atomic(pub_path, public_pem(raw_public(key)), PUBLIC_MODE)
    result.created.extend([key_path, pub_path])


def _make_node(key_path: Path, pub_path: Path, force: bool, result: KeygenResult) -> None:
    if key_path.exists() and not force:
        # Keeping existing keys means adding a drone to a mission never rotates the others.
        data = _read(key_path, "remove it, or pass --force")
        try:
            keys = parse_node_keys(data, str(key_path))
        except KeyFileError:
            # a format-1 node key (Ed25519 only): keep its Ed25519 key, add an X25519 one
            keys = NodeKeys(parse_private_key(data, str(key_path)), X25519PrivateKey.generate())
            write_file_atomic(key_path, keys.pem(), PRIVATE_MODE)
            write_file_atomic(pub_path, keys.public_pem(), PUBLIC_MODE)
            result.upgraded.append(key_path)
            return
        try:
            current = load_node_public_keys(pub_path) if pub_path.exists() else None
        except KeyFileError:
            current = None
        if current != keys.public:
            write_file_atomic(pub_path, keys.public_pem(), PUBLIC_MODE)
            result.created.append(pub_path)
        result.kept.append(key_path)
        return
    keys = NodeKeys(Ed25519PrivateKey.generate(), X25519PrivateKey.generate())
    write_file_atomic(key_path, keys.pem(), PRIVATE_MODE)
    write_file_atomic(pub_path, keys.public_pem(), PUBLIC_MODE)
    result.created.extend([key_path, pub_path])


def generate_keys(
    out_dir: str | Path, node_names: list[str] | None = None, *, force: bool = False
) -> KeygenResult:
    """Create the swarm signing key and the keys of each node name; existing keys are kept
    unless ``force`` (a format-1 node key gains its X25519 key, see ``_make_node``)."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    result = KeygenResult()
    _make_pair(out / SIGNING_KEY_FILE, out / SIGNING_PUB_FILE, force, result)
    for name in node_names or []:
        _make_node(node_key_path(out, name), node_public_path(out, name), force, result)
    return result
