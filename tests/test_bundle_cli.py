"""``swarmctl bundle`` end to end in a temp dir: keygen, build, verify, show --json, flash into
directories (atomic, previous kept, key 0600, trust pinning), check and rollback."""

from __future__ import annotations

import json
import os
import stat
from pathlib import Path

import pytest

from swarmd.bundle.loader import load_bundle
from swarmd.cli.swarmctl import main as swarmctl
from swarmd.exitcodes import EX_BAD_ARGS, EX_CANTCREAT, EX_CONFIG, EX_DATAERR
from tests.daemon_support import SWARM3, bundle_cli

REPO = Path(__file__).resolve().parent.parent
SWARM10 = REPO / "firmware_bundle" / "missions" / "swarm10.yaml"


@pytest.fixture
def bundle(tmp_path: Path, keys: Path, capsys: pytest.CaptureFixture[str]) -> Path:
    out = tmp_path / "swarm3.swb"
    code, stdout, _ = bundle_cli(
        capsys, "build", str(SWARM3), "-o", str(out), "--sign-key", str(keys / "swarm-signing.key")
    )
    assert code == 0 and stdout.startswith(f"wrote {out}: swarm field-test-3, 3 participants")
    return out


def _flash(
    capsys: pytest.CaptureFixture[str],
    bundle: Path,
    node: str,
    target: Path | str,
    keys: Path,
    *extra: str,
) -> tuple[int, str, str]:
    """``swarmctl bundle flash`` of ``bundle`` for ``node`` into ``target`` with its keys
    from ``keys``; (exit code, stdout, stderr)."""
    argv = ["flash", str(bundle), "--node", node, "--target", str(target), "--keys", str(keys)]
    return bundle_cli(capsys, *argv, *extra)


def test_keygen_writes_private_keys_0600_and_keeps_existing(
    keys: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    for path in [keys / "swarm-signing.key", *sorted((keys / "nodes").glob("*.key"))]:
        assert stat.S_IMODE(path.stat().st_mode) == 0o600, path
    assert sorted(p.name for p in (keys / "nodes").iterdir()) == [
        "drone-1.key", "drone-1.pub", "drone-2.key", "drone-2.pub", "lead.key", "lead.pub",
    ]  # fmt: skip
    before = (keys / "nodes" / "lead.key").read_bytes()
    code, out, _ = bundle_cli(capsys, "keygen", "--out", str(keys), "--mission", str(SWARM3))
    assert code == 0 and "kept" in out and "created" not in out
    assert (keys / "nodes" / "lead.key").read_bytes() == before


def test_build_is_deterministic_and_verifies(
    tmp_path: Path, keys: Path, bundle: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    again = tmp_path / "again.swb"
    bundle_cli(
        capsys,
        "build",
        str(SWARM3),
        "-o",
        str(again),
        "--sign-key",
        str(keys / "swarm-signing.key"),
    )
    assert again.read_bytes() == bundle.read_bytes()
    code, out, _ = bundle_cli(
        capsys, "verify", str(bundle), "--trusted-key", str(keys / "swarm-signing.pub"), "--json"
    )
    assert code == 0
    result = json.loads(out)
    assert result["ok"] and result["trust"] == "trusted-key" and result["participants"] == 3
    assert (
        result["content_sha256"]
        == load_bundle(bundle, keys / "swarm-signing.pub").content_sha256.hex()
    )


def test_show_json_has_swarm_hash_participants_topics_and_matches(
    bundle: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    code, out, _ = bundle_cli(capsys, "show", str(bundle), "--json")
    assert code == 0
    s = json.loads(out)
    assert s["swarm"] == "field-test-3" and len(s["content_sha256"]) == 64
    assert [p["name"] for p in s["participants"]] == ["lead", "drone-1", "drone-2"]
    assert s["format_version"] == 2
    for p in s["participants"]:  # both node keys, by fingerprint (bundle format 2)
        assert p["announce_key"].startswith("SHA256:") and p["x25519_key"].startswith("SHA256:")
    ready = next(t for t in s["topics"] if t["name"] == "swarm/ready")
    assert ready["writers"] == ["drone-1", "drone-2"] and ready["readers"] == ["lead"]
    lead_ready = next(r for r in s["matches"]["lead"] if r["topic"] == "swarm/ready")
    assert lead_ready["kind"] == "reader" and lead_ready["peers"] == ["drone-1", "drone-2"]
    code, out, _ = bundle_cli(capsys, "show", str(bundle))
    assert code == 0 and "swarm/command" in out and "field-test-3" in out


def test_build_usage_and_key_errors(
    tmp_path: Path, keys: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "x.swb"
    code, _, err = bundle_cli(capsys, "build", str(SWARM3), "-o", str(out))
    assert code == EX_BAD_ARGS and "--sign-key" in err
    (keys / "nodes" / "drone-2.pub").unlink()
    code, _, err = bundle_cli(
        capsys, "build", str(SWARM3), "-o", str(out), "--sign-key", str(keys / "swarm-signing.key")
    )
    assert code == EX_DATAERR
    assert err.count("\n") == 1 and "no announcement key for participant 'drone-2'" in err
    assert not out.exists()


def test_flash_local_writes_files_atomically_and_keeps_previous(
    tmp_path: Path, keys: Path, bundle: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    drone = tmp_path / "drone-1"
    code, out, err = _flash(capsys, bundle, "drone-1", drone, keys)
    assert code == 0, err
    assert "verified" in out
    assert sorted(p.name for p in drone.iterdir()) == [
        "bundle.swb",
        "node.key",
        "node.name",
        "swarm.pub",
    ]
    assert stat.S_IMODE((drone / "node.key").stat().st_mode) == 0o600
    assert (drone / "node.key").read_bytes() == (keys / "nodes" / "drone-1.key").read_bytes()
    assert (drone / "node.name").read_text() == "drone-1\n"
    first = load_bundle(drone / "bundle.swb", drone / "swarm.pub")

    # same bundle again: nothing to roll back to is invented
    _flash(capsys, bundle, "drone-1", drone, keys)
    assert not (drone / "bundle.swb.prev").exists()
    first_inode = (drone / "bundle.swb").stat().st_ino

    # a changed mission: the new bundle replaces the file by rename; the old one is kept
    mission2 = tmp_path / "m2.yaml"
    mission2.write_text(SWARM3.read_text().replace("history_depth: 8", "history_depth: 9"))
    b2 = tmp_path / "b2.swb"
    assert (
        swarmctl(
            [
                "bundle",
                "build",
                str(mission2),
                "-o",
                str(b2),
                "--sign-key",
                str(keys / "swarm-signing.key"),
            ]
        )
        == 0
    )
    code, out, _ = _flash(capsys, b2, "drone-1", drone, keys)
    assert code == 0 and "previous kept" in out
    assert (drone / "bundle.swb.prev").stat().st_ino == first_inode
    assert (drone / "bundle.swb").read_bytes() == b2.read_bytes()
    assert not [p for p in drone.iterdir() if ".tmp" in p.name]

    code, _, _ = bundle_cli(capsys, "rollback", "--target", str(drone))
    assert code == 0
    assert load_bundle(drone / "bundle.swb", drone / "swarm.pub") == first


def test_flash_refuses_wrong_node_key_before_writing(
    tmp_path: Path, keys: Path, bundle: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    (keys / "nodes" / "drone-1.key").write_bytes((keys / "nodes" / "lead.key").read_bytes())
    drone = tmp_path / "d"
    code, _, err = _flash(capsys, bundle, "drone-1", drone, keys)
    assert code == EX_DATAERR and "not 'drone-1''s keys in the bundle" in err
    assert not drone.exists()


def test_flash_refuses_bundle_from_another_swarm_key_unless_rotating(
    tmp_path: Path, keys: Path, bundle: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    drone = tmp_path / "d"
    _flash(capsys, bundle, "lead", drone, keys)
    other = tmp_path / "other-keys"
    bundle_cli(capsys, "keygen", "--out", str(other), "--mission", str(SWARM3))
    b2 = tmp_path / "b2.swb"
    bundle_cli(
        capsys, "build", str(SWARM3), "-o", str(b2), "--sign-key", str(other / "swarm-signing.key")
    )
    before = (drone / "bundle.swb").read_bytes()
    code, _, err = _flash(capsys, b2, "lead", drone, other)
    assert code == EX_CANTCREAT and "--replace-trust-key" in err and err.count("\n") == 1
    assert (drone / "bundle.swb").read_bytes() == before
    code, _, _ = _flash(capsys, b2, "lead", drone, other, "--replace-trust-key")
    assert code == 0
    assert load_bundle(drone / "bundle.swb", other / "swarm-signing.pub").swarm == "field-test-3"


def test_flash_all_uses_the_template_and_skips_nodes_without_address(
    tmp_path: Path, keys: Path, bundle: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    template = str(tmp_path / "fleet" / "{name}-{index}")
    code, out, err = bundle_cli(
        capsys, "flash", str(bundle), "--all", "--target", template, "--keys", str(keys)
    )
    assert code == 0, err
    assert sorted(p.name for p in (tmp_path / "fleet").iterdir()) == ["drone-1-1", "lead-0"]
    code, out, _ = bundle_cli(capsys, "check", str(bundle), "--all", "--target", template, "--json")
    assert code == 0 and json.loads(out)["ok"]

    # one drone carrying another bundle is caught by the fleet check
    mission2 = tmp_path / "m2.yaml"
    mission2.write_text(SWARM3.read_text().replace("lease_s: 20", "lease_s: 21"))
    b2 = tmp_path / "b2.swb"
    bundle_cli(
        capsys, "build", str(mission2), "-o", str(b2), "--sign-key", str(keys / "swarm-signing.key")
    )
    lead = str(tmp_path / "fleet" / "lead-0")
    _flash(capsys, b2, "lead", lead, keys)
    code, out, _ = bundle_cli(capsys, "check", str(bundle), "--all", "--target", template)
    assert code == 1
    assert "FAIL lead" in out and "OK   drone-1" in out and "1/2 drones" in out


def test_check_reports_a_key_left_readable(
    tmp_path: Path, keys: Path, bundle: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    drone = tmp_path / "d"
    _flash(capsys, bundle, "lead", drone, keys)
    os.chmod(drone / "node.key", 0o644)
    code, out, _ = bundle_cli(
        capsys, "check", str(bundle), "--node", "lead", "--target", str(drone)
    )
    assert code == 1 and "mode 644, expected 600" in out


def test_dev_bundle_flashes_with_derived_keys_and_shows_as_dev(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    dev = tmp_path / "dev.swb"
    code, _, err = bundle_cli(capsys, "build", str(SWARM10), "-o", str(dev), "--unsigned-dev")
    assert code == 0 and "warning" in err
    code, _, err = bundle_cli(capsys, "verify", str(dev))
    assert code == EX_CONFIG and "unsigned-dev" in err
    assert bundle_cli(capsys, "verify", str(dev), "--allow-dev")[0] == 0
    drone = tmp_path / "d"
    code, _, err = bundle_cli(
        capsys, "flash", str(dev), "--node", "drone-03", "--target", str(drone)
    )
    assert code == 0, err
    code, out, _ = bundle_cli(capsys, "show", str(dev), "--json", "--node", "drone-03")
    s = json.loads(out)
    assert s["dev"] and list(s["matches"]) == ["drone-03"]


def test_build_serial_is_one_more_than_the_bundle_it_replaces_or_given(
    tmp_path: Path, keys: Path, bundle: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """docs/security.md, "Bundle rollback": drones refuse a serial below the highest they
    accepted, so every build must go above the bundle it replaces."""
    key, pub = str(keys / "swarm-signing.key"), keys / "swarm-signing.pub"
    assert load_bundle(bundle, pub).serial == 1  # a first build: no bundle at -o yet
    # rebuilt in place: one more than the bundle at -o
    code, out, _ = bundle_cli(capsys, "build", str(SWARM3), "-o", str(bundle), "--sign-key", key)
    assert code == 0 and "serial 2 (replaces serial 1" in out
    assert load_bundle(bundle, pub).serial == 2
    following = tmp_path / "following.swb"
    code, out, _ = bundle_cli(
        capsys, "build", str(SWARM3), "-o", str(following), "--sign-key", key,
        "--replaces", str(bundle), "--json",
    )  # fmt: skip
    assert code == 0 and json.loads(out)["serial"] == 3
    code, _, _ = bundle_cli(
        capsys, "build", str(SWARM3), "-o", str(following), "--sign-key", key, "--serial", "40"
    )
    assert code == 0 and load_bundle(following, pub).serial == 40
    code, out, _ = bundle_cli(capsys, "show", str(following), "--json")
    assert code == 0 and json.loads(out)["serial"] == 40
    for bad in ("0", "-3", "4294967296", "x"):
        code, _, err = bundle_cli(
            capsys, "build", str(SWARM3), "-o", str(following), "--sign-key", key, "--serial", bad
        )
        assert code == EX_BAD_ARGS and err.count("\n") == 1, (bad, err)
    assert load_bundle(following, pub).serial == 40  # nothing written
    code, _, err = bundle_cli(
        capsys, "build", str(SWARM3), "-o", str(following), "--sign-key", key,
        "--replaces", str(tmp_path / "missing.swb"),
    )  # fmt: skip
    assert code == EX_CONFIG and "missing.swb" in err
