"""``swarmd check-config`` judges the folders the daemon writes under the unit's sandbox.

The defect (session 15): the shipped unit (systemd/swarmd.service) runs the daemon under
``ProtectSystem=strict``, ``ProtectHome=yes`` and ``PrivateTmp=yes``: it may write only
below ``StateDirectory=swarmd`` and ``RuntimeDirectory=swarmd``. ``check-config`` runs
outside that sandbox, so a config whose ``dataplane.state_dir`` (or node.key's folder, or
the control socket's) lay elsewhere passed it, and ``swarmd run`` then stopped with exit 73
("on a read-only mount"). Now ``check-config`` reads the unit (``--unit PATH``, else the
installed one) and refuses each such folder in ``run``'s one-line style, with ``run``'s
exit code. On main every test here fails: ``swarmd.unitsandbox`` and ``--unit`` do not
exist, and ``check-config`` said ``ok`` for each refused config below.
"""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

import pytest

from swarmd.cli.sandbox_check import find_unit
from swarmd.exitcodes import EX_CANTCREAT, EX_UNAVAILABLE
from swarmd.unitsandbox import Sandbox, UnitSyntaxError, parse_unit
from tests.daemon_support import loopback_config, run_domain, run_swarmd, write_bundle

ROOT = Path(__file__).resolve().parent.parent
SHIPPED = ROOT / "systemd" / "swarmd.service"
WAIT_S = 20.0


def _sandbox(text: str, existing: frozenset[str] = frozenset()) -> Sandbox:
    return Sandbox.of(parse_unit(text), lambda path: path in existing)


# ---- the reader, on systemd's documented syntax ---------------------------------------------


def test_the_reader_follows_systemds_syntax() -> None:
    """systemd.syntax(7): sections, ``Key=value`` with blanks around ``=``, ``#``/``;``
    comments, a trailing backslash joining lines (comments between them dropped)."""
    text = (
        "# a comment\n"
        "[Unit]\n"
        "Description = swarmd\n"
        "; another\n"
        "[Service]\n"
        "ReadWritePaths=/a \\\n"
        "# dropped inside the continuation\n"
        "  /b\n"
        "ProtectSystem =strict\n"
    )
    assert parse_unit(text) == [
        ("Unit", "Description", "swarmd", 3),
        ("Service", "ReadWritePaths", "/a  /b", 6),
        ("Service", "ProtectSystem", "strict", 9),
    ]
    with pytest.raises(UnitSyntaxError, match="line 2"):
        parse_unit("[Service]\nnot an assignment\n")


def test_the_shipped_unit_lets_the_daemon_write_its_two_folders_only() -> None:
    sandbox = _sandbox(SHIPPED.read_text("utf-8"))
    assert sandbox.read_write == ("/var/lib/swarmd", "/run/swarmd")
    for ok in ("/var/lib/swarmd", "/var/lib/swarmd/sub", "/run/swarmd"):
        assert sandbox.why_not_writable(ok) is None, ok
    for refused, word in (
        ("/srv/swarmd", "ProtectSystem=strict"),
        ("/var/lib", "ProtectSystem=strict"),
        ("/var/lib/swarmd2", "ProtectSystem=strict"),  # a prefix of the name is not below it
        ("/etc/swarmd", "ProtectSystem=strict"),
        ("/home/pilot/state", "ProtectHome=yes"),
        ("/root/state", "ProtectHome=yes"),
        ("/tmp/state", "PrivateTmp=yes"),
        ("/var/tmp/state", "PrivateTmp=yes"),
    ):
        why = sandbox.why_not_writable(refused)
        assert why is not None and word in why, (refused, why)


def test_later_assignments_win_and_an_empty_one_resets_a_list() -> None:
    text = (
        "[Service]\nProtectSystem=strict\nReadWritePaths=/srv/a /srv/b\n"
        "ReadWritePaths=\nReadWritePaths=/srv/c\nStateDirectory=x\nStateDirectory=\n"
        "PrivateTmp=yes\nPrivateTmp=no\n"
        "[Install]\nReadWritePaths=/srv/a\n"  # another section's key means nothing here
    )
    sandbox = _sandbox(text)
    assert sandbox.read_write == ("/srv/c",)
    assert sandbox.why_not_writable("/srv/a") is not None
    assert sandbox.why_not_writable("/srv/c/state") is None
    assert sandbox.why_not_writable("/var/lib/x") is not None
    assert sandbox.why_not_writable("/tmp/state") is not None  # strict: /tmp is "/" too
    assert _sandbox("[Service]\nPrivateTmp=yes\nPrivateTmp=no\n").why_not_writable("/tmp/a") is None


def test_path_prefixes_specifiers_quotes_and_old_names() -> None:
    """systemd.exec(5): ``-`` ignores a missing path, ``+`` is relative to
    ``RootDirectory=`` (the host's root here), ``*Directories=`` are the old names;
    systemd.unit(5): ``%S`` is /var/lib."""
    text = (
        "[Service]\nProtectSystem=strict\n"
        'ReadWritePaths=-/srv/missing -/srv/present "+/srv/with space" %S/other\n'
        "ReadWriteDirectories=/opt/old\n"
    )
    sandbox = _sandbox(text, existing=frozenset({"/srv/present"}))
    assert sandbox.read_write == ("/srv/present", "/srv/with space", "/var/lib/other", "/opt/old")
    assert sandbox.why_not_writable("/srv/missing") is not None


def test_the_most_specific_rule_wins_and_inaccessible_hides_what_is_below() -> None:
    text = (
        "[Service]\nReadOnlyPaths=/srv\nReadWritePaths=/srv/rw\n"
        "InaccessiblePaths=/data\nReadWritePaths=/data/rw\nProtectSystem=full\n"
        "ReadWritePaths=/etc/swarmd\n"
    )
    sandbox = _sandbox(text)
    assert sandbox.why_not_writable("/srv/rw/state") is None  # nested inside read-only
    assert sandbox.why_not_writable("/srv/other") is not None
    why = sandbox.why_not_writable("/data/rw")  # "not possible to nest ... inside it"
    assert why is not None and "InaccessiblePaths=/data" in why
    assert sandbox.why_not_writable("/usr/local/state") is not None  # full: /usr, /etc
    assert sandbox.why_not_writable("/etc/swarmd") is None
    assert sandbox.why_not_writable("/etc/other") is not None
    assert sandbox.why_not_writable("/srv2") is None  # ProtectSystem=full leaves it
    # one path both read-write and read-only: judged not writable (never a false "ok")
    both = _sandbox("[Service]\nReadWritePaths=/srv/x\nReadOnlyPaths=/srv/x\n")
    assert both.why_not_writable("/srv/x") is not None


def test_dynamic_user_implies_strict_read_only_home_and_private_tmp() -> None:
    sandbox = _sandbox("[Service]\nDynamicUser=yes\nStateDirectory=swarmd\n")
    assert sandbox.why_not_writable("/var/lib/swarmd") is None
    for path in ("/srv/x", "/home/x", "/tmp/x"):
        assert sandbox.why_not_writable(path) is not None, path


def test_protect_home_read_only_lets_a_nested_read_write_path_through() -> None:
    text = "[Service]\nProtectHome=read-only\nReadWritePaths=/home/pilot/swarmd\n"
    sandbox = _sandbox(text)
    assert sandbox.why_not_writable("/home/pilot/swarmd") is None
    assert sandbox.why_not_writable("/home/pilot") is not None
    yes = _sandbox("[Service]\nProtectHome=yes\nReadWritePaths=/home/pilot/swarmd\n")
    assert yes.why_not_writable("/home/pilot/swarmd") is not None  # inaccessible hides it


# ---- which unit ------------------------------------------------------------------------------


def test_the_installed_unit_and_its_dropins_are_found(tmp_path: Path) -> None:
    """Without ``--unit``: the first ``swarmd.service`` of systemd's unit folders, its
    drop-ins appended by file name (an earlier folder's name hides a later one's)."""
    etc, lib = tmp_path / "etc", tmp_path / "lib"
    (lib / "swarmd.service.d").mkdir(parents=True)
    (etc / "swarmd.service.d").mkdir(parents=True)
    shutil.copy(SHIPPED, lib / "swarmd.service")
    (etc / "swarmd.service.d" / "50-state.conf").write_text("[Service]\nReadWritePaths=/srv/s\n")
    (lib / "swarmd.service.d" / "50-state.conf").write_text("[Service]\nReadWritePaths=/x\n")
    (lib / "swarmd.service.d" / "60-tmp.conf").write_text("[Service]\nPrivateTmp=no\n")
    dirs = (str(etc), str(lib))
    unit = find_unit(None, dirs, systemctl=False)
    assert unit is not None and unit.source == str(lib / "swarmd.service")
    sandbox = _sandbox(unit.text)
    assert "/srv/s" in sandbox.read_write and "/x" not in sandbox.read_write
    assert not sandbox.private_tmp
    assert find_unit(None, (str(tmp_path / "none"),), systemctl=False) is None


# ---- swarmd check-config ----------------------------------------------------------------------


def _check(cfg: Path, *unit: str) -> subprocess.CompletedProcess[str]:
    return run_swarmd("check-config", "--config", str(cfg), *unit, timeout_s=WAIT_S)


def _unit(workdir: Path, extra: str) -> Path:
    """The shipped unit with a drop-in of ``extra`` (its ``[Service]`` lines), the daemon
    run as root (this host may have no user swarmd; the identity's own tests are
    tests/test_check_config_unit_user.py)."""
    unit = workdir / "unit" / "swarmd.service"
    (unit.parent / "swarmd.service.d").mkdir(parents=True)
    shutil.copy(SHIPPED, unit)
    root = "User=\nGroup=\nSupplementaryGroups=\n"
    (unit.parent / "swarmd.service.d" / "override.conf").write_text(f"[Service]\n{root}{extra}")
    return unit


def _config(workdir: Path, state: Path) -> Path:
    files = write_bundle(workdir, 2, domain_id=run_domain() + 15)
    dataplane = f"dataplane:\n  enabled: true\n  state_dir: {state}\n"
    return loopback_config(workdir, files, extra=dataplane)


def test_check_config_refuses_under_the_shipped_unit_what_run_cannot_write(workdir: Path) -> None:
    """The workdir is below /tmp: the shipped unit's ``PrivateTmp=yes`` gives the daemon a
    /tmp of its own, so node.key's folder (the bundle's here) is not the one on disk."""
    cfg = _config(workdir, workdir / "state")
    # --user root: this host may lack the unit's User=swarmd, which the check would refuse
    # first (tests/test_check_config_unit_user.py); the sandbox's judgement is the same
    proc = _check(cfg, "--unit", str(SHIPPED), "--user", "root")
    assert proc.returncode == EX_CANTCREAT, proc
    assert proc.stdout == "" and proc.stderr.count("\n") == 1, proc.stderr
    line = proc.stderr
    assert line.startswith(f"swarmd: {cfg}:") and "field bundle.path" in line
    assert "PrivateTmp=yes" in line and "fix: " in line


def test_check_config_refuses_a_state_dir_outside_the_units_writable_paths(
    workdir: Path,
) -> None:
    """The unit lets the daemon write the workdir's keys and socket, not the state folder:
    ``run`` would stop on a read-only mount (73). The fix names the field and the unit."""
    state = workdir / "state"
    unit = _unit(workdir, f"PrivateTmp=no\nReadWritePaths={workdir}\nReadOnlyPaths={state}\n")
    proc = _check(_config(workdir, state), "--unit", str(unit))
    assert proc.returncode == EX_CANTCREAT, proc
    line = proc.stderr
    assert "field dataplane.state_dir" in line and f"ReadOnlyPaths={state}" in line
    assert f"ReadWritePaths={state}" in line  # the fix's drop-in line


def test_check_config_refuses_a_control_socket_outside_with_runs_code(workdir: Path) -> None:
    """The control socket's folder: ``run`` stops binding it with exit 69."""
    unit = _unit(workdir, f"PrivateTmp=no\nReadWritePaths={workdir}\nReadOnlyPaths={workdir}/ro\n")
    (workdir / "ro").mkdir()
    cfg = _config(workdir, workdir / "state")
    cfg.write_text(cfg.read_text().replace(f"{workdir}/ctl.sock", f"{workdir}/ro/ctl.sock"))
    proc = _check(cfg, "--unit", str(unit))
    assert proc.returncode == EX_UNAVAILABLE, proc
    assert "field control.socket" in proc.stderr


def test_check_config_is_ok_when_the_unit_lets_it_write_and_says_which_unit(
    workdir: Path,
) -> None:
    """The control: the same config under a unit that lets it write every folder."""
    unit = _unit(workdir, f"PrivateTmp=no\nReadWritePaths={workdir}\n")
    proc = _check(_config(workdir, workdir / "state"), "--unit", str(unit))
    assert proc.returncode == 0, proc.stderr
    assert f"judged under {unit}" in proc.stdout


def test_check_config_without_a_unit_says_the_sandbox_was_not_judged(workdir: Path) -> None:
    if find_unit(None) is not None:
        pytest.skip("this host has a swarmd unit installed: the default reads it")
    proc = _check(_config(workdir, workdir / "state"))
    assert proc.returncode == 0, proc.stderr
    assert "sandbox not judged" in proc.stdout


def _systemd_runs() -> str | None:
    """Why the real-sandbox test cannot run here, or None."""
    if os.geteuid() != 0:
        return "needs root"
    if shutil.which("systemd-run") is None:
        return "no systemd-run"
    if not Path("/run/systemd/system").is_dir():
        return "systemd is not PID 1 here (no /run/systemd/system)"
    return None


@pytest.mark.skipif(_systemd_runs() is not None, reason=str(_systemd_runs()))
def test_the_real_sandbox_refuses_what_check_config_refuses(workdir: Path) -> None:
    """Where systemd runs (root): ``swarmd check-config`` itself run under
    ``systemd-run -p ProtectSystem=strict`` sees the state folder read-only (73), as the
    check made outside with the same unit says."""
    state = Path("/srv") / f"swarmd-test-{os.getpid()}"
    cfg = _config(workdir, state)
    unit = _unit(workdir, f"PrivateTmp=no\nReadWritePaths={workdir}\n")
    outside = _check(cfg, "--unit", str(unit))
    swarmd = shutil.which("swarmd") or str(ROOT / ".venv" / "bin" / "swarmd")
    inside = subprocess.run(  # noqa: S603 - a fixed argv
        [
            "systemd-run",
            "--wait",
            "--pipe",
            "--quiet",
            "-p",
            "ProtectSystem=strict",
            "-p",
            f"ReadWritePaths={workdir}",
            swarmd,
            "check-config",
            "--config",
            str(cfg),
            "--unit",
            "/dev/null",
        ],  # fmt: skip
        capture_output=True,
        text=True,
        timeout=WAIT_S,
        check=False,
    )
    assert outside.returncode == EX_CANTCREAT, outside
    assert inside.returncode == EX_CANTCREAT, inside
    assert not state.exists()


def test_an_unreadable_unit_is_a_usage_error_and_a_bad_one_a_config_error(
    workdir: Path,
) -> None:
    cfg = _config(workdir, workdir / "state")
    missing = _check(cfg, "--unit", str(workdir / "no.service"))
    assert missing.returncode == 64 and "--unit" in missing.stderr, missing
    bad = workdir / "bad.service"
    bad.write_text("[Service]\nProtectSystem strict\n")
    proc = _check(cfg, "--unit", str(bad))
    assert proc.returncode == 78 and "line 2" in proc.stderr, proc
