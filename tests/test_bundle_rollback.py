"""Rollback of the firmware bundle (docs/security.md, "Bundle rollback"): attacker tests.

The attacker can put an older bundle, still validly signed by the swarm key, where the
daemon reads it (a flasher, a backup restore, a mis-deploy): after a member was revoked
(a lost or captured drone) and the swarm re-signed a bundle without it, that older bundle
would re-admit the revoked member. The defence: a ``serial`` inside the signed body and a
floor the daemon keeps in its state folder (``bundle-floor-<node>``, beside node.key and the
boot epoch); start-up refuses a lower serial, and an equal serial with another content hash.

Every bundle here is a real, validly signed one: the test builds the mission, then sets the
body's ``serial`` (or another field) and seals it again with the swarm's key, exactly what
the builder does, so only the serial policy can refuse it. The daemon is started on its real
start-up path (``Daemon.start``, and ``swarmd run`` / ``check-config`` as processes).
"""

from __future__ import annotations

import asyncio
import hashlib
import json
import os
import random
import subprocess
from pathlib import Path
from typing import Any

import pytest
from structlog.testing import capture_logs
from swarmd_lab.testing import drain, peer_datagram

from swarmd.bundle.build import build_dev_bundle
from swarmd.bundle.encoding import HEADER_SIZE, canonical_json, seal, split
from swarmd.bundle.errors import BundleError
from swarmd.bundle.keys import dev_signing_key
from swarmd.bundle.loader import load_bundle
from swarmd.bundle.mission import load_mission
from swarmd.config import load_config
from swarmd.discovery import (
    DiscoveryEngine,
    EngineConfig,
    ForeignParticipantSeen,
    PeerDiscovered,
)
from swarmd.discovery.inputs import LinkSample
from swarmd.exitcodes import EX_CONFIG, StartupError
from tests.daemon_support import (
    SWARM3,
    BundleFiles,
    in_process_daemon,
    loopback_config,
    run_domain,
    run_swarmd,
    write_bundle,
)

WAIT_S = 20.0
SWARM = "testswarm"  # write_bundle's default swarm: its dev key signs every bundle here


@pytest.fixture
def files(workdir: Path) -> BundleFiles:
    # domain + 11: never the ports of the other daemon test files in the same run
    return write_bundle(workdir, 2, domain_id=run_domain() + 11)


def _resealed(files: BundleFiles, edit: dict[str, Any], *, drop: tuple[str, ...] = ()) -> bytes:
    """The fixture's bundle with body fields set (``edit``) or removed (``drop``), signed
    again with the swarm's key: a genuine bundle the swarm could have built."""
    env = split(files.path.read_bytes())
    value = json.loads(env.body)
    for key in drop:
        value.pop(key, None)
    for key, new in edit.items():
        if isinstance(new, dict):
            value[key] = {**value[key], **new}
        else:
            value[key] = new
    return seal(canonical_json(value), dev_signing_key(SWARM), dev=True)


def _put(files: BundleFiles, data: bytes) -> None:
    """What the attacker does: replace the bundle file the config names."""
    files.path.write_bytes(data)


def _start(workdir: Path, files: BundleFiles, node: str = "uav1") -> None:
    """Load the bundle as ``swarmd run`` does and start the daemon on loopback, then stop
    it; raises whatever start-up raises (``BundleError`` from the loader, ``StartupError``)."""
    config = load_config(loopback_config(workdir, files, node))
    bundle = load_bundle(files.path, files.trusted_key, allow_dev=True)
    daemon = in_process_daemon(config, bundle, node)

    async def main() -> None:
        try:
            await daemon.start()
        finally:
            await daemon.stop("test")

    asyncio.run(main())


def _refusal(workdir: Path, files: BundleFiles) -> StartupError:
    with pytest.raises(StartupError) as info:
        _start(workdir, files)
    return info.value


def _floor(workdir: Path, node: str = "uav1") -> Path:
    # the folder of node.key (here: the bundle's, no bundle.node_key set), as the epoch
    return workdir / f"bundle-floor-{node}"


def _run(*args: str) -> subprocess.CompletedProcess[str]:
    return run_swarmd(*args, timeout_s=WAIT_S)


def test_an_older_signed_bundle_is_refused_after_a_newer_one_was_accepted(
    workdir: Path, files: BundleFiles
) -> None:
    older, newer = _resealed(files, {"serial": 4}), _resealed(files, {"serial": 5})
    _put(files, newer)
    _start(workdir, files)  # accepted: the floor is now 5
    _put(files, older)  # the rollback: a genuine serial-4 bundle, validly signed
    refused = _refusal(workdir, files)
    line = str(refused)
    assert refused.exit_code == EX_CONFIG  # systemd's RestartPreventExitStatus=78
    assert "\n" not in line
    assert line.startswith(f"bundle rejected: {files.path}: ")  # the bundle file
    assert "field serial: 4 is below" in line and "floor 5" in line  # field, value, floor
    assert str(_floor(workdir)) in line
    assert "; fix: " in line and "--serial 6" in line
    _put(files, newer)
    _start(workdir, files)  # the newer bundle still starts: the refusal moved nothing


def test_an_older_bundle_is_refused_by_the_daemon_process_and_check_config(
    workdir: Path, files: BundleFiles
) -> None:
    _put(files, _resealed(files, {"serial": 9}))
    _start(workdir, files)
    _put(files, _resealed(files, {"serial": 8}))
    cfg = loopback_config(workdir, files)
    for command in ("check-config", "run"):
        proc = _run(command, "--config", str(cfg))
        assert proc.returncode == EX_CONFIG, (command, proc.stderr)
        assert proc.stdout == ""
        assert proc.stderr.count("\n") == 1, proc.stderr
        assert proc.stderr.startswith(f"swarmd: bundle rejected: {files.path}: field serial: 8")
    assert json.loads(_floor(workdir).read_text())["serial"] == 9


def test_check_config_does_not_raise_the_floor(workdir: Path, files: BundleFiles) -> None:
    """check-config answers "would this start?" and changes nothing: a newer bundle checked
    but never run must not lock out the bundle the drone runs now."""
    _put(files, _resealed(files, {"serial": 2}))
    _start(workdir, files)
    _put(files, _resealed(files, {"serial": 3}))
    proc = _run("check-config", "--config", str(loopback_config(workdir, files)))
    assert proc.returncode == 0, proc.stderr
    assert json.loads(_floor(workdir).read_text())["serial"] == 2


def test_the_same_serial_with_other_content_is_refused(workdir: Path, files: BundleFiles) -> None:
    """Two different bundles must not share a serial: the second one could be the one
    that still lists the revoked member, built from a stale copy of the mission."""
    first = _resealed(files, {"serial": 3})
    other = _resealed(files, {"serial": 3, "discovery": {"lease_ms": 30000}})
    assert split(first).content_sha256 != split(other).content_sha256
    _put(files, first)
    _start(workdir, files)
    _start(workdir, files)  # the same bundle again: a plain restart
    _put(files, other)
    line = str(_refusal(workdir, files))
    assert line.startswith(f"bundle rejected: {files.path}: field serial: 3 ")
    assert split(first).content_sha256.hex() in line  # which bundle holds serial 3
    assert "--serial 4" in line


def test_a_bundle_without_a_serial_starts_once_and_is_refused_after_a_serial(
    workdir: Path, files: BundleFiles
) -> None:
    """A bundle built before serials (no ``serial`` in its body) is serial 0: a drone that
    runs one when swarmd is upgraded keeps flying (no floor yet); once a bundle with a
    serial was accepted, it is refused like any older bundle."""
    legacy = _resealed(files, {}, drop=("serial",))
    assert "serial" not in json.loads(split(legacy).body)
    _put(files, legacy)
    _start(workdir, files)
    _start(workdir, files)  # a restart on the same legacy bundle
    _put(files, _resealed(files, {"serial": 1}))
    _start(workdir, files)
    _put(files, legacy)
    line = str(_refusal(workdir, files))
    assert "field serial: missing" in line and "floor 1" in line


def test_a_legacy_bundle_with_other_content_is_refused_after_a_legacy_one(
    workdir: Path, files: BundleFiles
) -> None:
    _put(files, _resealed(files, {}, drop=("serial",)))
    _start(workdir, files)
    _put(files, _resealed(files, {"discovery": {"lease_ms": 30000}}, drop=("serial",)))
    assert "field serial: missing" in str(_refusal(workdir, files))


def test_a_tampered_floor_file_stops_start_up(workdir: Path, files: BundleFiles) -> None:
    """A floor that does not parse is not "no floor": start-up stops with one line naming
    the file and the fix (check the bundle, then delete the file), and nothing is written."""
    _put(files, _resealed(files, {"serial": 5}))
    _start(workdir, files)
    for garbage in (b"not json", b'{"serial": -1, "sha256": "00"}', b'{"serial": "5"}'):
        _floor(workdir).write_bytes(garbage)
        refused = _refusal(workdir, files)
        line = str(refused)
        assert refused.exit_code == EX_CONFIG
        assert "\n" not in line
        assert str(_floor(workdir)) in line and "; fix: " in line and "delete" in line
        assert _floor(workdir).read_bytes() == garbage


def test_a_symlinked_floor_is_refused_not_followed(
    workdir: Path, files: BundleFiles, tmp_path: Path
) -> None:
    """Review (session 11): the floor is read under the state file's rules, as the XRCE
    key is (``O_NOFOLLOW``, a regular file): a symlink in its place, to a file that holds a
    lower floor (a folder another user may write, a restored backup), must not lower it.
    Followed, the serial-1 bundle started again after serial 5 (the rollback)."""
    older = _resealed(files, {"serial": 1})
    _put(files, older)
    _start(workdir, files)
    low = tmp_path / "elsewhere-floor"
    low.write_bytes(_floor(workdir).read_bytes())  # the serial-1 floor, kept aside
    _put(files, _resealed(files, {"serial": 5}))
    _start(workdir, files)  # the floor is now 5
    _floor(workdir).unlink()
    _floor(workdir).symlink_to(low)
    _put(files, older)
    refused = _refusal(workdir, files)
    line = str(refused)
    assert refused.exit_code == EX_CONFIG
    assert "\n" not in line and str(_floor(workdir)) in line and "; fix: " in line
    assert _floor(workdir).is_symlink()  # nothing written through it


def test_a_fifo_in_place_of_the_floor_stops_start_up_at_once(
    workdir: Path, files: BundleFiles
) -> None:
    """A FIFO where the floor should be must not hang start-up (a blocking open or read
    waits for a writer that never comes; systemd would kill the start after its timeout,
    with no line saying why): one line, exit 78, as for a corrupt floor. The process runs
    under ``_run``'s cap, so the hang fails the test instead of hanging the suite."""
    _put(files, _resealed(files, {"serial": 3}))
    _start(workdir, files)
    _floor(workdir).unlink()
    os.mkfifo(_floor(workdir), 0o600)
    proc = _run("check-config", "--config", str(loopback_config(workdir, files)))
    assert proc.returncode == EX_CONFIG, proc.stderr
    assert proc.stderr.count("\n") == 1 and str(_floor(workdir)) in proc.stderr, proc.stderr


def test_a_removed_floor_resets_it_and_is_logged(workdir: Path, files: BundleFiles) -> None:
    """The residual (docs/security.md): whoever can delete files in the state folder (root)
    resets the floor, and the older bundle starts. The daemon says so in its log: the node
    has booted before (its epoch file exists), yet it holds no floor."""
    _put(files, _resealed(files, {"serial": 7}))
    _start(workdir, files)
    _floor(workdir).unlink()
    _put(files, _resealed(files, {"serial": 6}))
    with capture_logs() as logs:
        _start(workdir, files)
    assert any(e["event"] == "bundle_floor_missing" for e in logs), logs
    assert json.loads(_floor(workdir).read_text())["serial"] == 6


def test_a_raised_floor_is_written_on_accept(workdir: Path, files: BundleFiles) -> None:
    _put(files, _resealed(files, {"serial": 1}))
    _start(workdir, files)
    _put(files, _resealed(files, {"serial": 40}))
    with capture_logs() as logs:
        _start(workdir, files)
    floor = json.loads(_floor(workdir).read_text())
    assert floor["serial"] == 40
    assert floor["sha256"] == split(files.path.read_bytes()).content_sha256.hex()
    raised = [e for e in logs if e["event"] == "bundle_floor_raised"]
    assert raised and raised[0]["serial"] == 40 and raised[0]["previous"] == 1


@pytest.mark.parametrize("rehash", [False, True])
def test_a_serial_edited_in_the_signed_body_is_refused_by_the_signature(
    files: BundleFiles, rehash: bool
) -> None:
    """The serial is in the signed body: raising it by hand (to pass the floor) breaks the
    content hash, and fixing the hash in the header breaks the signature."""
    data = _resealed(files, {"serial": 4})
    env = split(data)
    body = env.body.replace(b'"serial":4', b'"serial":9')
    assert body != env.body and len(body) == len(env.body)
    header = bytearray(data[:HEADER_SIZE])
    if rehash:
        header[12:44] = hashlib.sha256(body).digest()
    _put(files, bytes(header) + body + env.signature)
    with pytest.raises(BundleError) as info:
        load_bundle(files.path, files.trusted_key, allow_dev=True)
    assert ("bad signature" if rehash else "content hash mismatch") in str(info.value)


def test_peers_refuse_a_drone_that_flies_an_older_bundle() -> None:
    """On the air: the serial is in the body, so the older bundle has another content hash,
    and every peer on the newer bundle drops its DATA(p) as ``digest_mismatch`` (SPDP
    ``bundle_digest``, docs/wire.md) before it moves anything; its user data would fail
    too (pair keys are bound to the content hash, swarmd.auth.keys)."""
    mission = load_mission(SWARM3)
    older, newer = build_dev_bundle(mission, serial=1), build_dev_bundle(mission, serial=2)
    assert older.bundle.content_sha256 != newer.bundle.content_sha256
    me, peer = newer.bundle.participants[0], older.bundle.participants[1]
    assert me.ipv4 is not None and peer.ipv4 is not None  # swarm3 pins every address
    engine = DiscoveryEngine(
        newer.bundle,
        me.name,
        config=EngineConfig(),
        rng=random.Random(3),
        now=0.0,
        local_ipv4=me.ipv4,
        link=LinkSample(q=1.0),
    )
    drain(engine)
    engine.receive_datagram(peer_datagram(older.bundle, 1), (peer.ipv4, 7412), 0.1)
    events = drain(engine)
    assert [e.reason for e in events if isinstance(e, ForeignParticipantSeen)] == [
        "digest_mismatch"
    ]
    assert not any(isinstance(e, PeerDiscovered) for e in events)
    engine.receive_datagram(peer_datagram(newer.bundle, 1), (peer.ipv4, 7412), 0.2)
    assert any(isinstance(e, PeerDiscovered) for e in drain(engine))  # the control
