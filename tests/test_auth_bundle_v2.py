"""Bundle format 2 (per-node X25519 keys, node.key with both private keys) end to end.

A bundle or node key made before authenticated discovery stops the daemon at start-up with
one line naming the file, the missing field and the fix (rebuild, re-flash), exit 78;
keygen upgrades a format-1 keys directory in place (the Ed25519 keys are kept)."""

from __future__ import annotations

import struct
import subprocess
from pathlib import Path

import pytest
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey

from swarmd.auth.keys import KeyRing, NodeSecrets
from swarmd.bundle.encoding import HEADER_SIZE, split
from swarmd.bundle.errors import BundleError
from swarmd.bundle.keys import (
    dev_signing_key,
    load_node_keys,
    load_private_key,
    private_pem,
)
from swarmd.bundle.loader import load_bundle, read_bundle
from swarmd.cli.swarmctl import main as swarmctl
from swarmd.exitcodes import EX_CONFIG
from tests.daemon_support import SWARM3, SWARMD, clean_env, run_domain, write_bundle, write_config


def _as_format_1(data: bytes, key: Ed25519PrivateKey) -> bytes:
    """The same bundle with header version 1, re-signed: what a pre-change build looked like
    at the framing level (the loader must refuse it before reading the body)."""
    env = split(data)
    header = bytearray(data[:HEADER_SIZE])
    struct.pack_into(">H", header, 4, 1)
    signed = bytes(header) + env.body
    return signed + key.sign(signed)


def _swarmd(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [SWARMD, *args], capture_output=True, text=True, timeout=30, env=clean_env(), check=False
    )


def test_format_1_bundle_is_refused_naming_field_and_fix(tmp_path: Path) -> None:
    files = write_bundle(tmp_path, 2, domain_id=run_domain())
    files.path.write_bytes(_as_format_1(files.path.read_bytes(), dev_signing_key("testswarm")))
    with pytest.raises(BundleError) as info:
        load_bundle(files.path, files.trusted_key, allow_dev=True)
    line = str(info.value)
    assert "participants[].x25519_public_key" in line and "re-flash" in line
    cfg = write_config(
        tmp_path / "c.yaml", files, node="uav1", interface="lo", socket_path=str(tmp_path / "s")
    )
    proc = _swarmd("run", "--config", str(cfg))
    assert proc.returncode == EX_CONFIG
    assert proc.stderr.count("\n") == 1
    assert proc.stderr.startswith(f"swarmd: bundle rejected: {files.path}: bundle format 1")


@pytest.fixture
def flashed(tmp_path: Path) -> tuple[Path, Path]:
    """keygen + build + flash of node 'lead' into a drone directory; (keys dir, drone dir)."""
    keys, drone = tmp_path / "keys", tmp_path / "drone"
    assert swarmctl(["bundle", "keygen", "--out", str(keys), "--mission", str(SWARM3)]) == 0
    swb = tmp_path / "s.swb"
    sign = str(keys / "swarm-signing.key")
    assert swarmctl(["bundle", "build", str(SWARM3), "-o", str(swb), "--sign-key", sign]) == 0
    argv = ["bundle", "flash", str(swb), "--node", "lead", "--target", str(drone)]
    assert swarmctl([*argv, "--keys", str(keys)]) == 0
    return keys, drone


def _drone_config(tmp_path: Path, drone: Path) -> Path:
    """lead's config on ``lo``, announcing the address SWARM3 pins for it (check-config
    compares them, as run does; nothing here binds it)."""
    pinned = load_bundle(drone / "bundle.swb", drone / "swarm.pub").participant("lead").ipv4
    cfg = tmp_path / "drone.yaml"
    cfg.write_text(
        f"node: lead\nbundle:\n  path: {drone / 'bundle.swb'}\n"
        f"  trusted_key: {drone / 'swarm.pub'}\nnetwork:\n  interface: lo\n  ipv4: {pinned}\n"
        f"control:\n  socket: {tmp_path / 'ctl.sock'}\nlink:\n  sources: [static]\n"
    )
    return cfg


def test_flashed_node_key_holds_both_keys_and_matches_the_bundle(
    tmp_path: Path, flashed: tuple[Path, Path]
) -> None:
    _, drone = flashed
    bundle = load_bundle(drone / "bundle.swb", drone / "swarm.pub")
    secrets = NodeSecrets.load(drone / "node.key")
    ring = KeyRing.from_bundle(bundle, "lead", secrets)
    lead, d1 = bundle.participant("lead"), bundle.participant("drone-1")
    assert ring.verify(lead.guid_prefix, b"x", ring.sign(b"x"))
    assert ring.pair_key(d1.guid_prefix) is not None
    proc = _swarmd("check-config", "--config", str(_drone_config(tmp_path, drone)))
    assert proc.returncode == 0, proc.stderr


def test_format_1_node_key_is_refused_at_start_up(
    tmp_path: Path, flashed: tuple[Path, Path]
) -> None:
    _, drone = flashed
    key = drone / "node.key"
    key.write_bytes(private_pem(load_node_keys(key).ed25519))  # the Ed25519 block alone
    proc = _swarmd("run", "--config", str(_drone_config(tmp_path, drone)))
    assert proc.returncode == EX_CONFIG
    assert proc.stderr.count("\n") == 1
    assert proc.stderr.startswith(f"swarmd: node key rejected: {key}: field x25519 private key")
    assert "re-flash" in proc.stderr


def test_missing_or_foreign_node_key_is_refused(tmp_path: Path, flashed: tuple[Path, Path]) -> None:
    keys, drone = flashed
    cfg = _drone_config(tmp_path, drone)
    (drone / "node.key").write_bytes((keys / "nodes" / "drone-1.key").read_bytes())
    proc = _swarmd("run", "--config", str(cfg))
    assert proc.returncode == EX_CONFIG and "does not match 'lead'" in proc.stderr
    (drone / "node.key").unlink()
    proc = _swarmd("run", "--config", str(cfg))
    assert proc.returncode == EX_CONFIG and "node key not found" in proc.stderr
    assert proc.stderr.count("\n") == 1


def test_keygen_upgrades_format_1_node_keys_keeping_ed25519(tmp_path: Path) -> None:
    keys = tmp_path / "keys"
    assert swarmctl(["bundle", "keygen", "--out", str(keys), "--mission", str(SWARM3)]) == 0
    lead = keys / "nodes" / "lead.key"
    ed = load_node_keys(lead).ed25519
    lead.write_bytes(private_pem(ed))  # as keygen wrote it before this change
    assert swarmctl(["bundle", "keygen", "--out", str(keys), "--mission", str(SWARM3)]) == 0
    upgraded = load_node_keys(lead)
    assert private_pem(upgraded.ed25519) == private_pem(ed)
    assert private_pem(load_private_key(lead)) == private_pem(ed)  # first block: Ed25519
    swb = tmp_path / "s.swb"
    sign = str(keys / "swarm-signing.key")
    assert swarmctl(["bundle", "build", str(SWARM3), "-o", str(swb), "--sign-key", sign]) == 0
    b = read_bundle(swb.read_bytes(), require_anchor=False)
    assert b.participant("lead").x25519_public_key == upgraded.public[1]
