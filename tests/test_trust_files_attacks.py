"""A local user against the files swarmd trusts at start-up (session 10 review).

The config names the trust anchor (``bundle.trusted_key``: the swarm signing public key)
and the bundle it checks. In production they live in ``/etc/swarmd`` (0750 root:swarmd,
the config 0640) and ``/var/lib/swarmd`` (0700 swarmd): nobody else writes them
(``tests/test_production_layout.py``). A config that points them, or a config itself, in a
folder or a file another user can write hands that user the swarm: they swap the public key
for their own and the bundle for one they signed, and the node flies their mission (their
commander, their members' keys). Start-up now refuses such a file or folder in one line
naming it, the config field and the fix (exit 78), before trusting anything read from it.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from swarmd.exitcodes import EX_CONFIG
from tests.daemon_support import SWARMD, BundleFiles, clean_env, loopback_config, write_bundle

SYSTEM_PYTHON = shutil.which("python3", path="/usr/bin:/bin") or sys.executable
NOBODY = 65534


def _check_config(config: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [SWARMD, "check-config", "--config", str(config)],
        capture_output=True,
        text=True,
        timeout=60,
        env=clean_env(),
        check=False,
    )


def _refused(proc: subprocess.CompletedProcess[str], *named: str) -> None:
    assert proc.returncode == EX_CONFIG, (proc.stdout, proc.stderr)
    assert proc.stdout == ""
    assert proc.stderr.count("\n") == 1, proc.stderr
    for text in named:
        assert text in proc.stderr, proc.stderr
    assert "fix: " in proc.stderr


@pytest.fixture
def files(workdir: Path) -> BundleFiles:
    os.chmod(workdir, 0o755)  # noqa: S103 - nobody must reach the folders under it
    return write_bundle(workdir / "etc", 2, domain_id=0)


@pytest.mark.skipif(os.geteuid() != 0, reason="needs root to act as another local user")
def test_another_user_swaps_the_trust_anchor_in_a_folder_they_can_write(
    workdir: Path, files: BundleFiles
) -> None:
    """The whole attack, as user nobody: in a folder every user writes, replace the swarm
    key with the attacker's and the bundle with one the attacker signed (same node names,
    the attacker's swarm). Before the review ``check-config`` said ``ok (... swarm
    attackers)``: the node would have run the attacker's mission."""
    config = loopback_config(workdir, files)
    os.chmod(files.path.parent, 0o777)  # noqa: S103 - the misconfiguration under attack
    theirs = write_bundle(workdir / "attacker", 2, domain_id=0, swarm="attackers")
    swap = (
        "import os, shutil, sys\n"
        "for src, dst in ((sys.argv[1], sys.argv[2]), (sys.argv[3], sys.argv[4])):\n"
        "    shutil.copyfile(src, dst + '.new')\n"
        "    os.replace(dst + '.new', dst)\n"
    )
    subprocess.run(
        [SYSTEM_PYTHON, "-c", swap, str(theirs.trusted_key), str(files.trusted_key)]
        + [str(theirs.path), str(files.path)],
        user=NOBODY,
        group=NOBODY,
        extra_groups=[],
        timeout=60,
        check=True,
    )
    assert files.trusted_key.stat().st_uid == NOBODY  # the swap happened, as nobody
    proc = _check_config(config)
    assert "attackers" not in proc.stdout
    _refused(proc, str(files.path.parent), "fix: ")


@pytest.mark.parametrize(
    ("which", "field"),
    [("trusted_key", "bundle.trusted_key"), ("bundle", "bundle.path"), ("config", "")],
)
def test_a_trusted_file_others_can_write_is_refused(
    workdir: Path, files: BundleFiles, which: str, field: str
) -> None:
    config = loopback_config(workdir, files)
    path = {"trusted_key": files.trusted_key, "bundle": files.path, "config": config}[which]
    os.chmod(path, 0o666)  # noqa: S103 - the misconfiguration under attack
    _refused(_check_config(config), str(path), field)


def test_the_production_shape_is_accepted(workdir: Path, files: BundleFiles) -> None:
    """The refusal is about writers: 0640/0644 files in 0750/0755 folders pass (a control:
    without it the tests above would pass on a check that refuses everything)."""
    config = loopback_config(workdir, files)
    os.chmod(config, 0o640)
    os.chmod(files.path.parent, 0o750)  # noqa: S103 - /etc/swarmd's mode
    proc = _check_config(config)
    assert proc.returncode == 0, proc.stderr
    assert "ok (node uav1, swarm testswarm)" in proc.stdout
