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
import subprocess
from pathlib import Path

import pytest

from swarmd.exitcodes import EX_CONFIG
from tests.daemon_support import (
    NOBODY,
    SWARMD,
    SYSTEM_PYTHON,
    BundleFiles,
    as_nobody,
    clean_env,
    loopback_config,
    write_bundle,
)


def _check_config(config: Path, timeout_s: float = 60.0) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [SWARMD, "check-config", "--config", str(config)],
        capture_output=True,
        text=True,
        timeout=timeout_s,
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


def _with_node_key(config: Path, node_key: Path) -> Path:
    text = config.read_text()
    config.write_text(
        text.replace("  allow_dev: true\n", f"  allow_dev: true\n  node_key: {node_key}\n")
    )
    return config


def _nobodys_folder(workdir: Path) -> Path:
    """A folder user nobody owns (0700): a home, a scratch folder an operator chose."""
    folder = workdir / "nobodys"
    folder.mkdir()
    os.chown(folder, NOBODY, NOBODY)
    folder.chmod(0o700)
    return folder


@pytest.mark.skipif(os.geteuid() != 0, reason="needs root to act as another local user")
@pytest.mark.parametrize("where", ["in-their-folder", "their-file-in-a-root-folder"])
def test_a_px4_signing_key_another_user_wrote_is_refused(
    workdir: Path, files: BundleFiles, where: str
) -> None:
    """The PX4 link's signing key is a credential like node.key: whoever knows it signs
    frames swarmd takes as the autopilot's (armed heartbeats, a landed state, an ACK), so
    a key file another user wrote, or can swap, hands that user the vehicle's side of the
    link (session 15 review). Nobody writes a key of their choice, mode 0600 as asked.
    Before the review ``check-config`` said ``ok``: only the file's mode was judged."""
    folder = _nobodys_folder(workdir) if where == "in-their-folder" else workdir / "keys"
    folder.mkdir(exist_ok=True)
    key = folder / "px4-signing.key"
    if where != "in-their-folder":
        key.touch(mode=0o600)
        os.chown(key, NOBODY, NOBODY)
    as_nobody(
        "import os, sys\n"
        "fd = os.open(sys.argv[1], os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)\n"
        "os.write(fd, b'ab' * 32 + b'\\n')\n",
        str(key),
    )
    assert key.stat().st_uid == NOBODY
    px4 = (
        "px4:\n  enabled: true\n  connection: udpin:127.0.0.1:14541\n"
        f"  signing: true\n  signing_key: {key}\n"
    )
    config = loopback_config(workdir, files, extra=px4)
    named = folder if where == "in-their-folder" else key
    _refused(_check_config(config), "px4.signing_key", str(named))


@pytest.mark.skipif(os.geteuid() != 0, reason="needs root to act as another local user")
def test_a_node_key_fifo_in_another_users_folder_is_refused_not_waited_on(
    workdir: Path, files: BundleFiles
) -> None:
    """``check-config`` run by root reads only, and must answer: a FIFO nobody planted as
    node.key (mode 0600, so the mode check passed) made it wait forever for a writer (the
    read came before the folder's check; session 15 review). Now the folder is judged
    before anything in it is opened."""
    folder = _nobodys_folder(workdir)
    node_key = folder / "node.key"
    as_nobody("import os, sys\nos.mkfifo(sys.argv[1], 0o600)\n", str(node_key))
    config = _with_node_key(loopback_config(workdir, files), node_key)
    try:
        proc = _check_config(config, timeout_s=15.0)
    except subprocess.TimeoutExpired:
        pytest.fail("check-config waited on the planted FIFO")
    _refused(proc, "bundle.node_key", str(folder))
