"""Flash over ssh for real: an ``sshd`` on its own port inside a network namespace this test
creates, the operator's side (``swarmctl``) in a second namespace on the same bridge, the
system ``ssh``/``scp`` in between. The LAN fixture stops sshd and deletes the namespaces on
every exit path (and fails the test if one leaked)."""

from __future__ import annotations

import os
import socket
import stat
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import pytest
from swarmd_lab.netns import Lan, Namespace

from swarmd.bundle.loader import load_bundle
from tests.daemon_support import SWARM3

SSH_PORT = 2222
SSHD = "/usr/sbin/sshd"

pytestmark = [
    pytest.mark.netns,
    pytest.mark.skipif(not os.path.exists(SSHD), reason="openssh-server is not installed"),
]


def _ssh_keygen(path: Path) -> None:
    subprocess.run(
        ["ssh-keygen", "-q", "-t", "ed25519", "-N", "", "-f", str(path)],
        check=True,
        capture_output=True,
        timeout=30,
    )


def _wait_listening(
    ns: Namespace, address: str, port: int, sshd: subprocess.Popen[bytes], log: Path
) -> None:
    for _ in range(200):
        if sshd.poll() is not None:
            pytest.fail(f"sshd exited with {sshd.returncode}: {log.read_text()}")
        with ns.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
            s.settimeout(0.5)
            if s.connect_ex((address, port)) == 0:
                return
        subprocess.run(["sleep", "0.05"], check=True)
    pytest.fail("sshd did not start listening")


@pytest.fixture
def sshd_lan(tmp_path: Path, lan_factory: Callable[..., Lan]) -> tuple[Lan, list[str]]:
    """host 0 runs sshd on port 2222; returns the LAN and the ssh options for host 1."""
    lan = lan_factory(2)
    server = lan[0]
    d = tmp_path / "sshd"
    d.mkdir()
    _ssh_keygen(d / "host_key")
    _ssh_keygen(d / "client_key")
    (d / "authorized_keys").write_text((d / "client_key.pub").read_text())
    (d / "sshd_config").write_text(
        f"Port {SSH_PORT}\n"
        f"ListenAddress {server.address}\n"
        f"HostKey {d / 'host_key'}\n"
        f"AuthorizedKeysFile {d / 'authorized_keys'}\n"
        f"PidFile {d / 'sshd.pid'}\n"
        "PermitRootLogin prohibit-password\n"
        "PasswordAuthentication no\n"
        "KbdInteractiveAuthentication no\n"
        "UsePAM no\n"
        "StrictModes no\n"
        "Subsystem sftp /usr/lib/openssh/sftp-server\n"
    )
    # sshd's privilege-separation directory; the Debian service unit would create it
    os.makedirs("/run/sshd", mode=0o755, exist_ok=True)
    log = d / "sshd.log"
    with log.open("wb") as log_file:
        # the LAN fixture stops sshd (a child of its namespace) and deletes the namespaces
        proc = server.popen([SSHD, "-D", "-e", "-f", str(d / "sshd_config")], stderr=log_file)
    _wait_listening(lan[1], server.address, SSH_PORT, proc, log)
    options = [
        f"Port={SSH_PORT}",
        f"IdentityFile={d / 'client_key'}",
        "IdentitiesOnly=yes",
        "StrictHostKeyChecking=no",
        "UserKnownHostsFile=/dev/null",
        "LogLevel=ERROR",
    ]
    return lan, options


def swarmctl_in(ns: Namespace, *argv: str) -> subprocess.CompletedProcess[str]:
    return ns.run(
        [sys.executable, "-m", "swarmd.cli.swarmctl", "bundle", *argv], timeout=120, check=False
    )


def _ssh_args(options: list[str]) -> list[str]:
    return [arg for opt in options for arg in ("--ssh-option", opt)]


def test_flash_over_ssh_writes_verifies_keeps_previous_and_rolls_back(
    tmp_path: Path, sshd_lan: tuple[Lan, list[str]]
) -> None:
    lan, options = sshd_lan
    server, operator = lan[0], lan[1]
    keys = tmp_path / "keys"
    assert (
        swarmctl_in(operator, "keygen", "--out", str(keys), "--mission", str(SWARM3)).returncode
        == 0
    )
    b1 = tmp_path / "b1.swb"
    sign = ["--sign-key", str(keys / "swarm-signing.key")]
    assert swarmctl_in(operator, "build", str(SWARM3), "-o", str(b1), *sign).returncode == 0

    dest = tmp_path / "drone" / "var-lib-swarmd"
    target = f"root@{server.address}:{dest}"
    proc = swarmctl_in(
        operator, "flash", str(b1), "--node", "drone-1", "--target", target,
        "--keys", str(keys), *_ssh_args(options),
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    assert "verified" in proc.stdout and "trust anchor" in proc.stdout
    assert sorted(p.name for p in dest.iterdir()) == [
        "bundle.swb",
        "node.key",
        "node.name",
        "swarm.pub",
    ]
    assert stat.S_IMODE((dest / "node.key").stat().st_mode) == 0o600
    first = load_bundle(dest / "bundle.swb", keys / "swarm-signing.pub")

    # a second mission revision: the previous bundle stays for rollback
    m2 = tmp_path / "m2.yaml"
    m2.write_text(SWARM3.read_text().replace("history_depth: 8", "history_depth: 4"))
    b2 = tmp_path / "b2.swb"
    assert swarmctl_in(operator, "build", str(m2), "-o", str(b2), *sign).returncode == 0
    proc = swarmctl_in(
        operator, "flash", str(b2), "--node", "drone-1", "--target", target,
        "--keys", str(keys), *_ssh_args(options),
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    assert "previous kept" in proc.stdout
    assert (dest / "bundle.swb").read_bytes() == b2.read_bytes()
    assert (dest / "bundle.swb.prev").read_bytes() == b1.read_bytes()
    assert not [p for p in dest.iterdir() if p.name.startswith(".")]  # staging removed

    proc = swarmctl_in(
        operator, "check", str(b2), "--node", "drone-1", "--target", target, *_ssh_args(options)
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "1/1 drones carry the same bundle" in proc.stdout

    proc = swarmctl_in(operator, "rollback", "--target", target, *_ssh_args(options))
    assert proc.returncode == 0, proc.stderr
    assert load_bundle(dest / "bundle.swb", keys / "swarm-signing.pub") == first
    proc = swarmctl_in(
        operator, "check", str(b2), "--node", "drone-1", "--target", target, *_ssh_args(options)
    )
    assert proc.returncode == 1 and "FAIL drone-1" in proc.stdout


def test_flash_all_over_ssh_uses_each_participants_address(
    tmp_path: Path, sshd_lan: tuple[Lan, list[str]]
) -> None:
    lan, options = sshd_lan
    server, operator = lan[0], lan[1]
    mission = tmp_path / "m.yaml"
    # only the lead has an address (the sshd host); the others are skipped by --all
    mission.write_text(
        SWARM3.read_text()
        .replace("ipv4: 10.42.0.10", f"ipv4: {server.address}")
        .replace("    ipv4: 10.42.0.11\n", "")
    )
    dev = tmp_path / "dev.swb"
    assert (
        swarmctl_in(operator, "build", str(mission), "-o", str(dev), "--unsigned-dev").returncode
        == 0
    )
    dest = tmp_path / "fleet"
    proc = swarmctl_in(
        operator, "flash", str(dev), "--all", "--target", f"root@{{ipv4}}:{dest}/{{name}}",
        *_ssh_args(options), "--json",
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    assert sorted(p.name for p in dest.iterdir()) == ["lead"]
    assert (dest / "lead" / "node.name").read_text() == "lead\n"


def test_unreachable_host_is_one_line_and_exit_73(
    tmp_path: Path, sshd_lan: tuple[Lan, list[str]]
) -> None:
    lan, options = sshd_lan
    dev = tmp_path / "dev.swb"
    assert (
        swarmctl_in(lan[1], "build", str(SWARM3), "-o", str(dev), "--unsigned-dev").returncode == 0
    )
    proc = swarmctl_in(
        lan[1], "flash", str(dev), "--node", "lead", "--target", f"root@{lan[0].address}:/tmp/x",
        "--ssh-option", "Port=1", *_ssh_args(options[1:]),
    )  # fmt: skip
    assert proc.returncode == 73
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "prepare failed" in lines[0] and "Traceback" not in proc.stderr
