"""``swarmd check-config`` refuses what ``swarmd run`` refuses at start, with the same line.

``run``'s start (``Daemon.start``) checks, before it binds anything, that the node's
address is the bundle's pinned ``ipv4`` and that a ROS 2 relay has a graph to serve. An
operator who runs ``check-config`` on the bench must not read ``ok`` for a config the
drone then stops with exit 78 (docs/operations.md, "Exit codes"). Neither config here
gets as far as a socket: both processes stop at the check.

The state ``run`` writes at start (the boot epoch in node.key's folder, the data plane's
state file in ``dataplane.state_dir``, an XRCE agent's key file: exit 73) and what it builds
on it (the data plane's reading of the bundle: 78; the PX4 link and its signing key: 71,
78) are judged by ``check-config`` by reading only: each case below runs both commands on
one bad setup, and ``check-config`` changes nothing on disk (``run`` stops on these after
it bound its discovery sockets, or before: either way never at a socket of its own).
"""

from __future__ import annotations

import os
import pwd
import shutil
import subprocess
import tempfile
from collections.abc import Iterator
from pathlib import Path

import pytest

from swarmd.auth.freshness import U32_MAX
from swarmd.exitcodes import EX_CANTCREAT, EX_CONFIG, EX_OSERR
from tests.daemon_support import (
    SWARMD,
    BundleFiles,
    clean_env,
    loopback_config,
    relay_config,
    run_domain,
    run_swarmd,
    write_bundle,
    write_mission_bundle,
)

WAIT_S = 20.0
OTHER_USER = "nobody"  # a user the check judges for, and `run` runs as (setpriv)


def _run(*args: str) -> subprocess.CompletedProcess[str]:
    return run_swarmd(*args, timeout_s=WAIT_S)


def _both_refuse(cfg: Path, code: int = EX_CONFIG) -> str:
    """``check-config`` and ``run`` on ``cfg``: both exit ``code`` with one identical line
    (``run`` logs its ``stopped`` event before it)."""
    check = _run("check-config", "--config", str(cfg))
    run = _run("run", "--config", str(cfg))
    assert check.returncode == code, check
    assert run.returncode == code, run
    assert check.stdout == ""
    assert check.stderr.count("\n") == 1, check.stderr
    assert run.stderr.splitlines()[-1] == check.stderr.rstrip("\n")
    return check.stderr


def test_check_config_refuses_an_address_other_than_the_bundles_pin(workdir: Path) -> None:
    # domain + 13: never the ports of the other daemon test files in the same run
    files = write_bundle(workdir, 2, domain_id=run_domain() + 13, ipv4=["10.42.0.11", "10.42.0.12"])
    line = _both_refuse(loopback_config(workdir, files))  # announces 127.0.0.1
    assert "field network.ipv4" in line
    assert "127.0.0.1" in line and "10.42.0.11" in line


def test_check_config_accepts_the_pinned_address(workdir: Path) -> None:
    """The control: the same bundle pinning the address the config announces is ``ok``."""
    files = write_bundle(workdir, 2, domain_id=run_domain() + 13, ipv4=["127.0.0.1", "10.42.0.12"])
    proc = _run("check-config", "--config", str(loopback_config(workdir, files)))
    assert proc.returncode == 0, proc.stderr
    assert ": ok (node uav1" in proc.stdout


def test_check_config_refuses_a_relay_without_a_ros2_graph(workdir: Path) -> None:
    files = write_bundle(workdir, 2, domain_id=run_domain() + 13)  # no ros2: section
    line = _both_refuse(loopback_config(workdir, files, extra=relay_config()))
    assert "field ros2.relay" in line


def _files(workdir: Path) -> BundleFiles:
    return write_bundle(workdir, 2, domain_id=run_domain() + 13)


def _dataplane(state_dir: Path) -> str:
    return f"dataplane:\n  enabled: true\n  state_dir: {state_dir}\n"


def test_check_config_refuses_a_state_dir_others_can_write(workdir: Path) -> None:
    state = workdir / "state"
    state.mkdir()
    state.chmod(0o770)  # the group could plant a state file (session 10)
    cfg = loopback_config(workdir, _files(workdir), extra=_dataplane(state))
    line = _both_refuse(cfg, EX_CANTCREAT)
    assert "dataplane.state_dir" in line and str(state) in line


def test_check_config_refuses_a_state_dir_that_cannot_be_created(workdir: Path) -> None:
    blocker = workdir / "blocker"
    blocker.write_text("")  # a file where the state folder's parent should be
    cfg = loopback_config(workdir, _files(workdir), extra=_dataplane(blocker / "state"))
    line = _both_refuse(cfg, EX_CANTCREAT)
    assert "dataplane.state_dir" in line and str(blocker) in line
    assert not (blocker / "state").exists()


def test_check_config_refuses_a_state_file_that_is_a_folder(workdir: Path) -> None:
    state = workdir / "state"
    (state / "dataplane-uav1.json").mkdir(parents=True, mode=0o700)
    state.chmod(0o700)
    cfg = loopback_config(workdir, _files(workdir), extra=_dataplane(state))
    line = _both_refuse(cfg, EX_CANTCREAT)
    assert "dataplane-uav1.json" in line


def test_check_config_refuses_an_exhausted_boot_epoch(workdir: Path) -> None:
    files = _files(workdir)  # no bundle.node_key: the epoch lives beside the bundle
    (workdir / "auth-epoch-uav1").write_text(f"{U32_MAX}\n")
    line = _both_refuse(loopback_config(workdir, files), EX_CANTCREAT)
    assert "auth-epoch-uav1" in line


def test_check_config_refuses_what_the_data_plane_refuses_in_the_bundle(workdir: Path) -> None:
    mission = f"""\
swarm: testswarm
domain_id: {run_domain() + 13}
participants:
  - {{name: uav1, index: 0, role: commander, mavlink_sysid: 1}}
  - {{name: uav2, index: 1, role: member, mavlink_sysid: 2}}
topics:
  - name: swarm/ready
    type: swarmd::Command
    writers: [member]
    readers: [commander]
"""
    files = write_mission_bundle(workdir, mission, "testswarm", "wrong-type.yaml")
    cfg = loopback_config(workdir, files, extra=_dataplane(workdir / "state"))
    line = _both_refuse(cfg, EX_CONFIG)
    assert "data plane" in line and "swarm/ready" in line


@pytest.mark.parametrize(
    ("text", "mode"),
    [("00" * 32, 0o644), ("not a key", 0o600)],
    ids=["others-can-read-it", "wrong-format"],
)
def test_check_config_refuses_an_unusable_px4_signing_key(
    workdir: Path, text: str, mode: int
) -> None:
    key = workdir / "px4-signing.key"
    key.write_text(text + "\n")
    key.chmod(mode)
    px4 = (
        "px4:\n  enabled: true\n  connection: udpin:127.0.0.1:14541\n"
        f"  signing: true\n  signing_key: {key}\n"
    )
    line = _both_refuse(loopback_config(workdir, _files(workdir), extra=px4), EX_CONFIG)
    assert "px4.signing_key" in line


def test_check_config_refuses_an_xrce_client_on_a_serial_port(workdir: Path) -> None:
    px4 = "px4:\n  enabled: true\n  backend: xrce-client\n  connection: serial:/dev/ttyS0:921600\n"
    line = _both_refuse(loopback_config(workdir, _files(workdir), extra=px4), EX_OSERR)
    assert "px4.connection" in line


def test_check_config_refuses_an_unusable_xrce_key_file(workdir: Path) -> None:
    files = _files(workdir)
    (workdir / "px4-xrce-key").write_text("not a number\n")
    px4 = "px4:\n  enabled: true\n  backend: xrce-agent\n  connection: udp:127.0.0.1:888\n"
    line = _both_refuse(loopback_config(workdir, files, extra=px4), EX_CANTCREAT)
    assert "px4.xrce_key" in line and "px4-xrce-key" in line


@pytest.fixture
def shared_dir() -> Iterator[Path]:
    """A folder every user may enter (pytest's base is root's alone), owned by root."""
    path = Path(tempfile.mkdtemp(prefix="swarmd-checkcfg-"))
    try:
        path.chmod(0o755)
        yield path
    finally:
        shutil.rmtree(path)


@pytest.mark.skipif(
    os.geteuid() != 0 or shutil.which("setpriv") is None, reason="needs root and setpriv"
)
def test_check_config_judges_the_state_for_the_daemons_user(shared_dir: Path) -> None:
    """As root, on behalf of the unit's user: node.key's folder is root's (0755), so that
    user cannot write the boot epoch there. ``check-config --user`` says what ``run`` as that
    user says; judged for root (who can), the same setup is ``ok``."""
    cfg = loopback_config(shared_dir, _files(shared_dir))
    check = _run("check-config", "--config", str(cfg), "--user", OTHER_USER)
    gid = str(pwd.getpwnam(OTHER_USER).pw_gid)
    as_user = ["setpriv", f"--reuid={OTHER_USER}", f"--regid={gid}", "--clear-groups"]
    run = subprocess.run(  # noqa: S603 - argv list
        [*as_user, SWARMD, "run", "--config", str(cfg)],
        capture_output=True,
        text=True,
        timeout=WAIT_S,
        env=clean_env(),
        check=False,
    )
    assert check.returncode == EX_CANTCREAT, check
    assert run.returncode == EX_CANTCREAT, run
    assert check.stderr.count("\n") == 1, check.stderr
    assert run.stderr.splitlines()[-1] == check.stderr.rstrip("\n")
    assert f"user {OTHER_USER}" in check.stderr and str(shared_dir) in check.stderr
    assert _run("check-config", "--config", str(cfg), "--user", "root").returncode == 0


def _tree(root: Path) -> dict[str, tuple[int, int, int, int, bytes]]:
    """Every entry under ``root``: mode, owner, size, mtime and (files) content."""
    seen: dict[str, tuple[int, int, int, int, bytes]] = {}
    for folder, dirs, names in os.walk(root):
        for name in [*dirs, *names]:
            path = Path(folder) / name
            st = path.lstat()
            body = path.read_bytes() if path.is_file() and not path.is_symlink() else b""
            seen[str(path.relative_to(root))] = (
                st.st_mode,
                st.st_uid,
                st.st_size,
                st.st_mtime_ns,
                body,
            )
    return seen


def test_check_config_changes_nothing_on_disk(workdir: Path) -> None:
    """What ``run`` would rename, clean, chmod or write at start: a corrupt state file (run
    replaces it, so check-config warns and says ok), temporary files a crash left, an XRCE
    key others may read, the boot epoch. After ``check-config`` every byte, mode and mtime
    is as before; a state folder that does not exist yet is not created."""
    files = _files(workdir)
    state = workdir / "state"
    state.mkdir(mode=0o700)
    (state / "dataplane-uav1.json").write_text("{not json")
    (state / ".dataplane-uav1.json.tmp-0123456789abcdef").write_text("half")
    (workdir / "auth-epoch-uav1").write_text("5\n")
    (workdir / ".auth-epoch-uav1.tmp-0123456789abcdef").write_text("6")
    (workdir / "px4-xrce-key").write_text("12345\n")
    (workdir / "px4-xrce-key").chmod(0o644)
    px4 = "px4:\n  enabled: true\n  backend: xrce-agent\n  connection: udp:127.0.0.1:888\n"
    cfg = loopback_config(workdir, files, extra=_dataplane(state) + px4)
    before = _tree(workdir)
    proc = _run("check-config", "--config", str(cfg))
    assert proc.returncode == 0, proc.stderr
    assert "dataplane-uav1.json" in proc.stderr  # the state file run would replace
    assert _tree(workdir) == before
    fresh = workdir / "new" / "state"
    cfg = loopback_config(workdir, files, extra=_dataplane(fresh))
    before = _tree(workdir)
    assert _run("check-config", "--config", str(cfg)).returncode == 0
    assert _tree(workdir) == before
