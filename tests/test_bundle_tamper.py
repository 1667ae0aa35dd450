"""Tamper, truncation and trust: every byte of header, body and signature is covered, and a
rejected bundle is one line (and exit 78 for a process), never a traceback."""

from __future__ import annotations

import hashlib
import json
import subprocess
import sys
from pathlib import Path

import pytest
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey

from swarmd.bundle.build import build_bundle, build_dev_bundle
from swarmd.bundle.encoding import (
    HEADER_SIZE,
    OFFSET_FLAGS,
    OFFSET_LENGTH,
    OFFSET_SHA256,
    OFFSET_SIGNER,
    OFFSET_VERSION,
    SIGNATURE_SIZE,
    canonical_json,
    seal,
    split,
)
from swarmd.bundle.errors import BundleError
from swarmd.bundle.keys import dev_node_keys, public_pem, raw_public
from swarmd.bundle.loader import load_bundle, load_bundle_or_exit, read_bundle
from swarmd.bundle.mission import load_mission
from swarmd.exitcodes import EX_CONFIG

REPO = Path(__file__).resolve().parent.parent
SIGNING = Ed25519PrivateKey.from_private_bytes(b"\x07" * 32)
TRUSTED = raw_public(SIGNING)


@pytest.fixture(scope="module")
def built() -> bytes:
    mission = load_mission(REPO / "firmware_bundle" / "missions" / "swarm3.yaml")
    keys = {p.name: dev_node_keys("t", p.name).public for p in mission.participants}
    return build_bundle(mission, SIGNING, keys).data


def _region(offset: int, size: int) -> str:
    if offset < HEADER_SIZE:
        return "header"
    return "body" if offset < size - SIGNATURE_SIZE else "signature"


def _expected_problem(offset: int, size: int) -> str:
    """Which check must catch a flipped byte at ``offset`` (see loader's docstring)."""
    if offset < OFFSET_VERSION:
        return "not a swarmd bundle"
    if offset < OFFSET_FLAGS:
        return "unsupported bundle format version"
    if offset < OFFSET_LENGTH:
        return "unknown header flags" if offset == OFFSET_FLAGS else "bad signature"
    if offset < OFFSET_SHA256:
        return "body length"
    if offset < OFFSET_SIGNER:
        return "content hash mismatch"
    if offset < HEADER_SIZE:
        return "signed by"
    if offset < size - SIGNATURE_SIZE:
        return "content hash mismatch"
    return "bad signature"


def test_untampered_bundle_loads(built: bytes) -> None:
    assert read_bundle(built, trusted_key=TRUSTED).size == 3


def test_every_flipped_byte_is_rejected_by_the_right_check(built: bytes) -> None:
    seen = set()
    for offset in range(len(built)):
        tampered = bytearray(built)
        tampered[offset] ^= 0x01
        with pytest.raises(BundleError) as info:
            read_bundle(bytes(tampered), source="b.swb", trusted_key=TRUSTED)
        message = str(info.value)
        assert "\n" not in message and message.startswith("b.swb: ")
        expected = _expected_problem(offset, len(built))
        # a length that grows reads as "truncated", one that shrinks as "trailing bytes"
        if expected == "body length":
            assert "truncated" in message or "trailing bytes" in message, (offset, message)
        else:
            assert expected in message, (offset, message)
        seen.add(_region(offset, len(built)))
    assert seen == {"header", "body", "signature"}


def test_flipped_signer_key_without_key_anchor_fails_the_signature(built: bytes) -> None:
    env = split(built)
    for offset in range(OFFSET_SIGNER, HEADER_SIZE):
        tampered = bytearray(built)
        tampered[offset] ^= 0x80
        with pytest.raises(BundleError, match="bad signature"):
            read_bundle(bytes(tampered), expected_sha256=env.content_sha256)


def test_every_truncation_and_extension_is_rejected(built: bytes) -> None:
    for length in range(len(built)):
        with pytest.raises(BundleError, match="truncated"):
            read_bundle(built[:length], trusted_key=TRUSTED)
    with pytest.raises(BundleError, match="1 trailing bytes"):
        read_bundle(built + b"\x00", trusted_key=TRUSTED)


def test_bundle_signed_by_another_key_is_rejected(built: bytes) -> None:
    body = split(built).body
    forged = seal(body, Ed25519PrivateKey.generate())
    with pytest.raises(BundleError, match="but this node trusts"):
        read_bundle(forged, trusted_key=TRUSTED)
    # a forger who rewrites the signer field cannot make the signature verify
    tampered = bytearray(forged)
    tampered[OFFSET_SIGNER:HEADER_SIZE] = TRUSTED
    with pytest.raises(BundleError, match="bad signature"):
        read_bundle(bytes(tampered), trusted_key=TRUSTED)


def test_trust_needs_an_anchor_and_pinned_hash_is_one(built: bytes) -> None:
    with pytest.raises(BundleError, match="no trust anchor"):
        read_bundle(built)
    digest = split(built).content_sha256
    assert read_bundle(built, expected_sha256=digest).content_sha256 == digest
    with pytest.raises(BundleError, match="is not the pinned"):
        read_bundle(built, expected_sha256=hashlib.sha256(b"other").digest())


def test_dev_bundle_needs_allow_dev() -> None:
    mission = load_mission(REPO / "firmware_bundle" / "missions" / "swarm3.yaml")
    dev = build_dev_bundle(mission)
    key = dev.bundle.signing_public_key
    with pytest.raises(BundleError, match="unsigned-dev"):
        read_bundle(dev.data, trusted_key=key)
    assert read_bundle(dev.data, trusted_key=key, allow_dev=True) == dev.bundle


def test_validly_signed_but_inconsistent_body_is_rejected(built: bytes) -> None:
    """A body from a buggy builder: signed, but its GUID prefix is not the derived one."""
    value = json.loads(split(built).body)
    value["participants"][1]["guid_prefix"] = "00" * 12
    bad = seal(canonical_json(value), SIGNING)
    with pytest.raises(BundleError, match="GUID prefix .* is not the derived one"):
        read_bundle(bad, trusted_key=TRUSTED)
    value = json.loads(split(built).body)
    del value["participants"][1]["endpoints"]
    with pytest.raises(BundleError, match="invalid bundle body: .*missing 'endpoints'"):
        read_bundle(seal(canonical_json(value), SIGNING), trusted_key=TRUSTED)


def test_load_bundle_reads_key_files_and_reports_missing_files(
    tmp_path: Path, built: bytes
) -> None:
    path = tmp_path / "bundle.swb"
    path.write_bytes(built)
    pub = tmp_path / "swarm.pub"
    pub.write_bytes(public_pem(TRUSTED))
    assert load_bundle(path, pub).size == 3
    hexkey = tmp_path / "swarm.hex"
    hexkey.write_text(TRUSTED.hex() + "\n")
    assert load_bundle(path, hexkey).size == 3
    with pytest.raises(BundleError, match="bundle file not found"):
        load_bundle(tmp_path / "nope.swb", pub)
    with pytest.raises(BundleError, match="trusted key: key file not found"):
        load_bundle(path, tmp_path / "nope.pub")


def test_load_bundle_or_exit_prints_one_line_and_exits_78(
    tmp_path: Path, built: bytes, capsys: pytest.CaptureFixture[str]
) -> None:
    path = tmp_path / "bundle.swb"
    path.write_bytes(built[:-1])
    with pytest.raises(SystemExit) as info:
        load_bundle_or_exit(path, TRUSTED)
    assert info.value.code == EX_CONFIG
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"swarmd: bundle rejected: {path}: truncated")


def test_verify_process_exits_78_with_one_line_and_no_traceback(
    tmp_path: Path, built: bytes
) -> None:
    path = tmp_path / "bundle.swb"
    tampered = bytearray(built)
    tampered[HEADER_SIZE + 10] ^= 0xFF
    path.write_bytes(bytes(tampered))
    proc = subprocess.run(
        [sys.executable, "-m", "swarmd.cli.swarmctl", "bundle", "verify", str(path)],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert proc.returncode == EX_CONFIG
    assert proc.stdout == ""
    lines = proc.stderr.splitlines()
    assert len(lines) == 1 and "Traceback" not in proc.stderr
    assert lines[0].startswith(f"swarmctl: bundle rejected: {path}: content hash mismatch")
