"""``swarmctl bundle rollback`` and ``flash`` against a drone's serial floor (docs/security.md,
"Bundle rollback"; docs/operations.md, "Bundle serial").

swarmd refuses at start a bundle below its floor (``bundle-floor-<node>`` beside node.key),
or the floor's serial with another hash (exit 78). The operator's own tool must not put such
a bundle in place and report success: rollback reads the target's floor and refuses; flash
refuses a serial below the target's current bundle or its floor unless
``--allow-lower-serial``. Local targets through the CLI, ssh targets through a stand-in for
ssh that runs the very scripts in a local ``sh`` (the sshd test is test_bundle_flash_ssh.py).
"""

from __future__ import annotations

import hashlib
import json
import shutil
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import pytest

from swarmd.bundle.errors import FlashError, SerialRefused
from swarmd.bundle.flash import FlashPayload, Ssh, Target, flash, rollback
from swarmd.bundle.keys import load_node_keys, node_key_path
from swarmd.bundle.loader import load_bundle, read_bundle
from swarmd.cli.swarmctl import main as swarmctl
from swarmd.exitcodes import EX_CONFIG
from tests.daemon_support import SWARM3, bundle_cli

NODE = "drone-1"


def build(
    tmp_path: Path, keys: Path, capsys: pytest.CaptureFixture[str], serial: int, depth: int = 8
) -> Path:
    """A genuine bundle with ``serial``; ``depth`` changes the content (another hash)."""
    mission = tmp_path / f"m{depth}.yaml"
    mission.write_text(SWARM3.read_text().replace("history_depth: 8", f"history_depth: {depth}"))
    out = tmp_path / f"s{serial}-d{depth}.swb"
    code, _, err = bundle_cli(
        capsys, "build", str(mission), "-o", str(out),
        "--sign-key", str(keys / "swarm-signing.key"), "--serial", str(serial),
    )  # fmt: skip
    assert code == 0, err
    return out


def sha(path: Path) -> str:
    bundle = read_bundle(path.read_bytes(), allow_dev=True, require_anchor=False)
    return bundle.content_sha256.hex()


def put_floor(drone: Path, serial: int, sha256: str) -> None:
    """What swarmd writes at start (swarmd.bundle.floor.raise_floor)."""
    body = json.dumps({"serial": serial, "sha256": sha256}).encode()
    (drone / f"bundle-floor-{NODE}").write_bytes(body + b"\n")


def flash_cli(capsys: pytest.CaptureFixture[str], bundle: Path, drone: Path, keys: Path,
              *extra: str) -> tuple[int, str, str]:  # fmt: skip
    return bundle_cli(
        capsys, "flash", str(bundle), "--node", NODE, "--target", str(drone),
        "--keys", str(keys), *extra,
    )  # fmt: skip


def flashed_twice(
    tmp_path: Path, keys: Path, capsys: pytest.CaptureFixture[str], old_serial: int, new_serial: int
) -> tuple[Path, Path, Path]:
    """A drone directory flashed with ``old_serial`` then ``new_serial`` (another content):
    ``(drone, old, new)``, the old one kept as bundle.swb.prev."""
    drone = tmp_path / "drone"
    old = build(tmp_path, keys, capsys, old_serial)
    new = build(tmp_path, keys, capsys, new_serial, depth=9)
    assert flash_cli(capsys, old, drone, keys)[0] == 0
    assert flash_cli(capsys, new, drone, keys)[0] == 0
    return drone, old, new


# -- rollback -----------------------------------------------------------------------------------


def test_rollback_below_the_floor_is_refused_and_moves_nothing(
    tmp_path: Path, keys: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    drone, old, new = flashed_twice(tmp_path, keys, capsys, 1, 2)
    put_floor(drone, 2, sha(new))  # swarmd started on the new bundle
    code, out, err = bundle_cli(capsys, "rollback", "--target", str(drone))
    assert code == EX_CONFIG
    assert err.count("\n") == 1 and "below" in err and "--serial 3" in err
    assert out == ""
    assert (drone / "bundle.swb").read_bytes() == new.read_bytes()  # nothing moved
    assert (drone / "bundle.swb.prev").read_bytes() == old.read_bytes()


def test_rollback_to_the_floors_serial_with_another_hash_is_refused(
    tmp_path: Path, keys: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    drone, twin, new = flashed_twice(tmp_path, keys, capsys, 2, 3)
    other = build(tmp_path, keys, capsys, 2, depth=5)
    put_floor(drone, 2, sha(other))  # serial 2 accepted, but it was another bundle
    code, _, err = bundle_cli(capsys, "rollback", "--target", str(drone))
    assert code == EX_CONFIG and err.count("\n") == 1
    assert "share a serial" in err and "--serial 3" in err
    assert (drone / "bundle.swb").read_bytes() == new.read_bytes()


def test_rollback_the_daemon_would_accept_still_works(
    tmp_path: Path, keys: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    drone, old, new = flashed_twice(tmp_path, keys, capsys, 4, 5)
    put_floor(drone, 4, sha(old))  # swarmd never started on the new one
    code, out, err = bundle_cli(capsys, "rollback", "--target", str(drone))
    assert code == 0, err
    assert "rolled back" in out and err == ""
    assert load_bundle(drone / "bundle.swb", drone / "swarm.pub").serial == 4


def test_rollback_with_a_corrupt_floor_is_refused(
    tmp_path: Path, keys: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    drone, old, new = flashed_twice(tmp_path, keys, capsys, 1, 2)
    (drone / f"bundle-floor-{NODE}").write_bytes(b"{not json")
    code, _, err = bundle_cli(capsys, "rollback", "--target", str(drone))
    assert code == EX_CONFIG and err.count("\n") == 1 and "corrupt" in err
    assert (drone / "bundle.swb").read_bytes() == new.read_bytes()


# -- flash --------------------------------------------------------------------------------------


def test_flash_below_the_current_serial_is_refused_unless_allowed(
    tmp_path: Path, keys: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    drone = tmp_path / "drone"
    newer, older = build(tmp_path, keys, capsys, 5), build(tmp_path, keys, capsys, 4, depth=9)
    assert flash_cli(capsys, newer, drone, keys)[0] == 0
    code, out, err = flash_cli(capsys, older, drone, keys)
    assert code == EX_CONFIG and out == ""
    assert err.count("\n") == 1 and "below" in err and "--serial 6" in err
    assert (drone / "bundle.swb").read_bytes() == newer.read_bytes()
    assert not (drone / "bundle.swb.prev").exists()  # nothing written at all
    code, out, err = flash_cli(capsys, older, drone, keys, "--allow-lower-serial")
    assert code == 0, err
    assert (drone / "bundle.swb").read_bytes() == older.read_bytes()
    # the same serial with other content is not below the current bundle: allowed
    same = build(tmp_path, keys, capsys, 4, depth=3)
    assert flash_cli(capsys, same, drone, keys)[0] == 0


def test_flash_below_or_beside_the_floor_is_refused(
    tmp_path: Path, keys: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    drone = tmp_path / "drone"
    drone.mkdir()
    seven = build(tmp_path, keys, capsys, 7)
    put_floor(drone, 7, sha(seven))  # an SD card whose bundle was removed, floor kept
    five = build(tmp_path, keys, capsys, 5)
    code, _, err = flash_cli(capsys, five, drone, keys)
    assert code == EX_CONFIG and err.count("\n") == 1 and "floor 7" in err
    twin = build(tmp_path, keys, capsys, 7, depth=9)
    code, _, err = flash_cli(capsys, twin, drone, keys)
    assert code == EX_CONFIG and "share a serial" in err
    assert not (drone / "bundle.swb").exists()
    for ok in (seven, build(tmp_path, keys, capsys, 8)):
        code, _, err = flash_cli(capsys, ok, drone, keys)
        assert code == 0, err


def test_flash_help_says_the_daemon_still_refuses(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit):
        swarmctl(["bundle", "flash", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "--allow-lower-serial" in text and "still refuses" in text


# -- over ssh -----------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class LocalShell(Ssh):
    """ssh to ourselves: the scripts run in a local ``sh``, scp is a copy (modes kept)."""

    def run(self, host: str, script: str, what: str) -> bytes:
        return self._call(["sh", "-s"], script.encode(), what, host)

    def copy(self, files: Sequence[Path], host: str, remote_dir: str, what: str) -> None:
        for f in files:
            shutil.copy2(f, remote_dir)


def payload(bundle: Path, keys: Path) -> FlashPayload:
    data = bundle.read_bytes()
    b = read_bundle(data, allow_dev=True, require_anchor=False)
    pem = load_node_keys(node_key_path(keys, NODE)).pem()
    return FlashPayload(NODE, data, b, pem, False)


def test_over_ssh_rollback_and_flash_check_the_floor(
    tmp_path: Path, keys: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    drone = tmp_path / "drone"
    target, ssh = Target(str(drone), "drone-1.local"), LocalShell()
    old, new = build(tmp_path, keys, capsys, 1), build(tmp_path, keys, capsys, 2, depth=9)
    flash(payload(old, keys), target, ssh=ssh)
    flash(payload(new, keys), target, ssh=ssh)
    assert (drone / "bundle.swb.prev").read_bytes() == old.read_bytes()

    put_floor(drone, 2, sha(new))
    with pytest.raises(SerialRefused, match="below"):
        rollback(target, ssh=ssh)
    assert (drone / "bundle.swb").read_bytes() == new.read_bytes()
    with pytest.raises(SerialRefused, match="below"):
        flash(payload(old, keys), target, ssh=ssh)
    assert (drone / "bundle.swb").read_bytes() == new.read_bytes()

    put_floor(drone, 1, sha(old))  # the floor the daemon would have before the new one
    rollback(target, ssh=ssh)
    assert (drone / "bundle.swb").read_bytes() == old.read_bytes()


def test_over_ssh_rollback_restores_only_the_checked_previous(
    tmp_path: Path, keys: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The restore runs only if bundle.swb.prev still has the hash that was checked: a
    file swapped between the check and the move is not restored."""
    drone = tmp_path / "drone"
    target = Target(str(drone), "drone-1.local")
    old, new = build(tmp_path, keys, capsys, 1), build(tmp_path, keys, capsys, 2, depth=9)
    flash(payload(old, keys), target, ssh=LocalShell())
    flash(payload(new, keys), target, ssh=LocalShell())
    put_floor(drone, 1, sha(old))
    swapped = build(tmp_path, keys, capsys, 1, depth=3)

    @dataclass(frozen=True, slots=True)
    class SwapAfterRead(LocalShell):
        def run(self, host: str, script: str, what: str) -> bytes:
            out = LocalShell.run(self, host, script, what)
            if what == "read the serials":
                shutil.copy2(swapped, drone / "bundle.swb.prev")
            return out

    with pytest.raises(Exception, match="changed since it was checked"):
        rollback(target, ssh=SwapAfterRead())
    assert (drone / "bundle.swb").read_bytes() == new.read_bytes()
    digest = hashlib.sha256((drone / "bundle.swb.prev").read_bytes()).hexdigest()
    assert digest == hashlib.sha256(swapped.read_bytes()).hexdigest()


# -- the trust anchor before the serial ---------------------------------------------------------


def other_swarm(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], serial: int
) -> tuple[Path, Path]:
    """Another swarm's keys and a bundle of the same mission they sign: ``(keys, bundle)``."""
    other = tmp_path / "other-keys"
    code, _, err = bundle_cli(capsys, "keygen", "--out", str(other), "--mission", str(SWARM3))
    assert code == 0, err
    return other, build(tmp_path, other, capsys, serial, depth=6)


def test_flash_of_another_swarms_bundle_is_refused_for_its_key_before_its_serial(
    tmp_path: Path, keys: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A lower serial signed by keys the drone does not trust: the operator is told the key
    (``--replace-trust-key`` when rotating), not ``--serial``, which would not help."""
    drone = tmp_path / "drone"
    assert flash_cli(capsys, build(tmp_path, keys, capsys, 5), drone, keys)[0] == 0
    before = (drone / "bundle.swb").read_bytes()
    other, foreign = other_swarm(tmp_path, capsys, 1)
    code, out, err = flash_cli(capsys, foreign, drone, other)
    assert code != 0 and out == "" and err.count("\n") == 1
    assert "trusts swarm key" in err and "--replace-trust-key" in err
    assert "--serial" not in err
    assert (drone / "bundle.swb").read_bytes() == before
    # rotating the key on purpose: the serial guard still holds
    code, _, err = flash_cli(capsys, foreign, drone, other, "--replace-trust-key")
    assert code == EX_CONFIG and "--serial 6" in err
    assert (drone / "bundle.swb").read_bytes() == before


def test_over_ssh_the_key_is_checked_before_the_serial(
    tmp_path: Path, keys: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    drone = tmp_path / "drone"
    target, ssh = Target(str(drone), "drone-1.local"), LocalShell()
    flash(payload(build(tmp_path, keys, capsys, 5), keys), target, ssh=ssh)
    other, foreign = other_swarm(tmp_path, capsys, 1)
    with pytest.raises(FlashError, match="trusts swarm key") as info:
        flash(payload(foreign, other), target, ssh=ssh)
    assert not isinstance(info.value, SerialRefused)
    with pytest.raises(SerialRefused, match="below"):
        flash(payload(foreign, other), target, ssh=ssh, replace_trust=True)
