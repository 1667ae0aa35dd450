"""``swarmd check-config`` judges the written folders as the user the unit runs swarmd as.

The defect (session 15): ``check-config`` judged node.key's folder and
``dataplane.state_dir`` for ``--user``, else (as root) for ``swarmd`` when that user
existed, else for root, whatever the unit said. A unit (or a drop-in) with ``User=drone``,
``SupplementaryGroups=`` reset or ``DynamicUser=yes`` made it say ``ok`` for folders the
daemon then could not write (``run`` stops with 73). Now it reads ``User=``, ``Group=``,
``SupplementaryGroups=`` and ``DynamicUser=`` from the unit it reads the sandbox from
(systemd.exec(5): a later assignment wins, an empty one resets) and judges for that
identity; the ``ok`` line names whose view and where it came from.

The user and groups are real: created here with ``useradd``/``groupadd`` (root) and removed
on every exit path. This host has no user swarmd (the refusal of the shipped unit's
``User=swarmd`` is skipped where it has one). On main each case refused below said ``ok``
(judged for root); checked with this file on an export of main.
"""

from __future__ import annotations

import grp
import os
import pwd
import shutil
import subprocess
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

from swarmd.bundle.keys import dev_node_keys
from swarmd.cli.sandbox_check import Unit, _cat_files, find_unit
from swarmd.cli.unit_user import unit_user
from swarmd.exitcodes import EX_CANTCREAT, EX_CONFIG
from swarmd.unitsandbox import UnitIdentity, parse_unit
from tests.daemon_support import loopback_config, run_domain, run_swarmd, write_bundle

ROOT = Path(__file__).resolve().parent.parent
SHIPPED = ROOT / "systemd" / "swarmd.service"
WAIT_S = 20.0
TOOLS = ("useradd", "userdel", "groupadd", "groupdel")


# ---- the reader: systemd.exec(5)'s rules, on text ----------------------------------------------


def test_the_shipped_units_identity() -> None:
    identity = UnitIdentity.of(parse_unit(SHIPPED.read_text("utf-8")))
    assert identity.user is not None and identity.user.value == "swarmd"
    assert identity.group is not None and identity.group.value == "swarmd"
    assert [s.value for s in identity.supplementary] == ["dialout"]
    assert identity.dynamic is None
    assert identity.chowned == ("/var/lib/swarmd", "/run/swarmd")  # not /etc/swarmd
    line = SHIPPED.read_text("utf-8").splitlines()[identity.user.line - 1]
    assert line == "User=swarmd"


def test_a_later_assignment_wins_and_an_empty_one_resets() -> None:
    text = (
        "[Service]\nUser=a\nUser=b\nGroup=g\nGroup=\nSupplementaryGroups=x y\n"
        "SupplementaryGroups=\nSupplementaryGroups=z\nSupplementaryGroups=w\n"
        "DynamicUser=yes\nDynamicUser=no\nStateDirectory=s\n"
        "[Install]\nUser=c\n"  # another section's key means nothing here
    )
    identity = UnitIdentity.of(parse_unit(text))
    assert identity.user is not None and (identity.user.value, identity.user.line) == ("b", 3)
    assert identity.group is None
    assert [s.value for s in identity.supplementary] == ["z", "w"]
    assert identity.dynamic is None
    assert UnitIdentity.of(parse_unit("[Service]\nUser=a\nUser=\n")).user is None
    dynamic = UnitIdentity.of(parse_unit("[Service]\nDynamicUser=on\nStateDirectory=s\n"))
    assert dynamic.dynamic is not None
    # the state folder lives below private/ (a symlink at /var/lib/s): both are given
    assert dynamic.chowned == ("/var/lib/s", "/var/lib/private/s")


def test_a_line_is_named_in_the_file_that_holds_it(tmp_path: Path) -> None:
    """The unit and its drop-ins are read as one text (as ``systemctl cat`` shows them);
    a refusal names the file and its own line."""
    unit = tmp_path / "swarmd.service"
    unit.write_text("[Service]\nUser=swarmd\n")
    (tmp_path / "swarmd.service.d").mkdir()
    (tmp_path / "swarmd.service.d" / "x.conf").write_text("# why\n[Service]\nUser=drone\n")
    found = find_unit(str(unit))
    assert found is not None
    identity = UnitIdentity.of(parse_unit(found.text))
    assert identity.user is not None
    assert found.where(identity.user.line) == f"{tmp_path}/swarmd.service.d/x.conf:3"


def test_systemctl_cats_file_headers_name_the_files() -> None:
    """``systemctl cat``: ``# PATH`` before each file, a blank line between files; a
    comment inside a unit (the shipped one's ``# /dev/ttyTHS1 ...``) is not a header."""
    shipped = SHIPPED.read_text("utf-8")
    text = (
        f"# /etc/systemd/system/swarmd.service\n{shipped}\n"
        "# /etc/systemd/system/swarmd.service.d/override.conf\n[Service]\nUser=drone\n"
    )
    unit = Unit("systemctl cat swarmd.service", text, _cat_files(text))
    identity = UnitIdentity.of(parse_unit(unit.text))
    assert identity.user is not None
    where = "/etc/systemd/system/swarmd.service.d/override.conf:2"
    assert unit.where(identity.user.line) == where
    assert [path for _, path in unit.files] == [
        "/etc/systemd/system/swarmd.service",
        "/etc/systemd/system/swarmd.service.d/override.conf",
    ]
    assert identity.group is not None
    number = shipped.splitlines().index("Group=swarmd") + 1
    assert unit.where(identity.group.line) == f"/etc/systemd/system/swarmd.service:{number}"


# ---- a real user and group ----------------------------------------------------------------------


@dataclass(frozen=True)
class Drone:
    """A user (with its own group) and a group it is not a member of."""

    user: str
    own_group: str
    group: str
    member_of: str  # a group whose /etc/group line lists the user


# shadow-utils lock /etc/passwd and /etc/group (lckpwdf: 15 s, then exit 1/10); another
# process on the machine adding a user (a test of another checkout) can hold the lock
LOCKED_TRIES = 4


def _sh(*argv: str) -> None:
    for _ in range(LOCKED_TRIES - 1):
        done = subprocess.run(argv, check=False, capture_output=True, timeout=WAIT_S)  # noqa: S603
        if done.returncode == 0 or b"lock" not in done.stderr.lower():
            break
    else:
        done = subprocess.run(argv, check=False, capture_output=True, timeout=WAIT_S)  # noqa: S603
    done.check_returncode()


def _gone(drone: Drone) -> bool:
    try:
        pwd.getpwnam(drone.user)
    except KeyError:
        pass
    else:
        return False
    names = (drone.own_group, drone.group, drone.member_of)
    return all(g.gr_name not in names for g in grp.getgrall())


@pytest.fixture
def drone() -> Iterator[Drone]:
    if os.geteuid() != 0 or any(shutil.which(tool) is None for tool in TOOLS):
        pytest.skip("needs root and useradd/groupadd")
    tag = f"swt{os.getpid() % 100_000}"
    made = Drone(f"{tag}u", f"{tag}u", f"{tag}g", f"{tag}m")
    try:
        _sh("groupadd", "--system", made.group)
        _sh("groupadd", "--system", made.member_of)
        _sh("groupadd", "--system", made.own_group)
        _sh("useradd", "--system", "--no-create-home", "--shell", "/usr/sbin/nologin",
            "-g", made.own_group, "-G", made.member_of, made.user)  # fmt: skip
        yield made
    finally:
        for _ in range(LOCKED_TRIES):
            for argv in (
                ("userdel", made.user),
                ("groupdel", made.own_group),
                ("groupdel", made.group),
                ("groupdel", made.member_of),
            ):
                subprocess.run(argv, check=False, capture_output=True, timeout=WAIT_S)  # noqa: S603
            if _gone(made):
                break
        assert _gone(made), "the test's user or groups were left behind"


@pytest.fixture
def varlib() -> Iterator[Path]:
    """A folder of this test's below /var/lib, where ``StateDirectory=`` names lie."""
    base = Path(f"/var/lib/swt-{os.getpid()}")
    base.mkdir(mode=0o755)
    try:
        yield base
    finally:
        shutil.rmtree(base, ignore_errors=True)


def test_the_units_groups_are_resolved_as_systemd_does(drone: Drone, tmp_path: Path) -> None:
    """initgroups: ``Group=``'s (else the user's own), the groups listing the user, and
    ``SupplementaryGroups=``."""
    unit = tmp_path / "swarmd.service"
    unit.write_text(f"[Service]\nUser={drone.user}\nSupplementaryGroups={drone.group}\n")
    found = find_unit(str(unit))
    assert found is not None
    user = unit_user(found)
    gid = {name: grp.getgrnam(name).gr_gid for name in (drone.own_group, drone.group)}
    member = grp.getgrnam(drone.member_of).gr_gid
    assert user.uid == pwd.getpwnam(drone.user).pw_uid
    assert user.gids == frozenset({gid[drone.own_group], gid[drone.group], member})
    assert user.source == f"User= of {unit}"
    unit.write_text(f"[Service]\nUser={drone.user}\nGroup={drone.group}\n")
    found = find_unit(str(unit))
    assert found is not None
    assert unit_user(found).gids == frozenset({gid[drone.group], member})


# ---- swarmd check-config ------------------------------------------------------------------------


def _check(cfg: Path, unit: Path, *more: str) -> subprocess.CompletedProcess[str]:
    return run_swarmd(
        "check-config", "--config", str(cfg), "--unit", str(unit), *more, timeout_s=WAIT_S
    )


def _unit(workdir: Path, lines: str, *, shipped_identity: bool = False) -> Path:
    """The shipped unit, with a drop-in letting it write the workdir (so only the user's
    judgement can refuse) and ``lines``; its identity reset to root first unless
    ``shipped_identity``."""
    unit = workdir / "unit" / "swarmd.service"
    (unit.parent / "swarmd.service.d").mkdir(parents=True, exist_ok=True)
    shutil.copy(SHIPPED, unit)
    reset = "" if shipped_identity else "User=\nGroup=\nSupplementaryGroups=\n"
    text = f"[Service]\n{reset}PrivateTmp=no\nReadWritePaths={workdir}\n{lines}"
    (unit.parent / "swarmd.service.d" / "override.conf").write_text(text)
    return unit


def _config(workdir: Path, state: Path, node_dir: Path | None = None) -> Path:
    """A loopback config with the data plane's state in ``state``; ``node_dir``: node.key's
    folder (the boot epoch's), else the bundle's (the workdir, root's, 0755)."""
    files = write_bundle(workdir, 2, domain_id=run_domain() + 16)
    cfg = loopback_config(
        workdir, files, extra=f"dataplane:\n  enabled: true\n  state_dir: {state}\n"
    )
    if node_dir is not None:
        key = node_dir / "node.key"
        key.write_bytes(dev_node_keys("testswarm", "uav1").pem())
        key.chmod(0o600)
        text = cfg.read_text().replace(
            "  allow_dev: true\n", f"  allow_dev: true\n  node_key: {key}\n"
        )
        cfg.write_text(text)
    return cfg


def test_a_user_that_cannot_write_the_boot_epochs_folder_is_refused(
    workdir: Path, drone: Drone
) -> None:
    """node.key's folder (here the bundle's: root's, 0755) cannot be written by the unit's
    ``User=``: ``run`` under that unit stops with 73. On main: ``ok`` (judged for root)."""
    cfg = _config(workdir, workdir / "state")
    unit = _unit(workdir, f"User={drone.user}\n")
    proc = _check(cfg, unit)
    assert proc.returncode == EX_CANTCREAT, proc
    assert proc.stdout == "" and proc.stderr.count("\n") == 1, proc.stderr
    assert f"user {drone.user} cannot write in {workdir}" in proc.stderr
    assert "field bundle.path" in proc.stderr or "bundle.node_key" in proc.stderr
    # --user still overrides, and the ok line says so
    as_root = _check(cfg, unit, "--user", "root")
    assert as_root.returncode == 0, as_root.stderr
    assert "judged as root (--user)" in as_root.stdout


def test_supplementary_groups_decide_whether_the_state_folder_can_be_made(
    workdir: Path, drone: Drone, varlib: Path
) -> None:
    """``dataplane.state_dir`` is missing; its parent is root's with group rwx for a group
    the user gets only through ``SupplementaryGroups=``. Reset by a later empty
    assignment, ``run`` could not create it. node.key's folder is the unit's
    ``StateDirectory=``: systemd gives it to the user at start."""
    node_dir = varlib / "node"
    node_dir.mkdir(mode=0o700)  # root's now; systemd chowns it at start
    parent = workdir / "shared"
    parent.mkdir()
    os.chown(parent, 0, grp.getgrnam(drone.group).gr_gid)
    parent.chmod(0o770)
    cfg = _config(workdir, parent / "state", node_dir)
    state_dir = f"StateDirectory={varlib.name}/node\n"
    lines = f"User={drone.user}\nSupplementaryGroups={drone.group}\n{state_dir}"
    unit = _unit(workdir, lines)
    ok = _check(cfg, unit)
    assert ok.returncode == 0, ok.stderr
    dropin = unit.parent / "swarmd.service.d" / "override.conf"
    assert f"judged as {drone.user} (User= of {dropin})" in ok.stdout
    refused = _check(cfg, _unit(workdir, lines + "SupplementaryGroups=\n"))
    assert refused.returncode == EX_CANTCREAT, refused
    assert "dataplane.state_dir" in refused.stderr
    assert f"user {drone.user} cannot create folders in {parent}" in refused.stderr
    assert not (parent / "state").exists()


def test_a_user_or_group_this_host_lacks_is_refused_with_the_units_line(
    workdir: Path, drone: Drone
) -> None:
    """systemd would not start the service (217/USER, 216/GROUP): one line naming the
    file, the line, the field and the fix. On main: ``ok``."""
    cfg = _config(workdir, workdir / "state")
    dropin = workdir / "unit" / "swarmd.service.d" / "override.conf"
    for lines, field, name in (
        ("User=swt-nobody-here\n", "User=", "swt-nobody-here"),
        (f"User={drone.user}\nGroup=swt-no-group\n", "Group=", "swt-no-group"),
        (
            f"SupplementaryGroups={drone.group} swt-no-group\n",
            "SupplementaryGroups=",
            "swt-no-group",
        ),
    ):
        proc = _check(cfg, _unit(workdir, lines))
        assert proc.returncode == EX_CONFIG, proc
        assert proc.stdout == "" and proc.stderr.count("\n") == 1, proc.stderr
        dropin_lines = dropin.read_text().splitlines()
        number = next(n for n, line in enumerate(dropin_lines, 1) if name in line)
        assert proc.stderr.startswith(f"swarmd: {dropin}:{number}: field {field}:"), proc.stderr
        assert repr(name) in proc.stderr and "fix: " in proc.stderr


def test_the_shipped_units_user_is_refused_where_the_host_lacks_it(workdir: Path) -> None:
    """The shipped unit (its sandbox opened to the workdir): ``User=swarmd``, from
    systemd/swarmd.service's own line. On main: ``ok``."""
    try:
        pwd.getpwnam("swarmd")
    except KeyError:
        pass
    else:
        pytest.skip("this host has a user swarmd")
    unit = _unit(workdir, "", shipped_identity=True)
    proc = _check(_config(workdir, workdir / "state"), unit)
    assert proc.returncode == EX_CONFIG, proc
    number = SHIPPED.read_text("utf-8").splitlines().index("User=swarmd") + 1
    assert proc.stderr.startswith(f"swarmd: {unit}:{number}: field User=: no user 'swarmd'")
    assert "useradd --system" in proc.stderr


def test_a_dynamic_user_writes_only_what_systemd_gives_it(workdir: Path, varlib: Path) -> None:
    """``DynamicUser=yes``: a uid allocated at each start. Its ``StateDirectory=`` is its
    own (the ``ok`` line names it); a folder of root's it may write only as any other
    user, so ``run`` would stop with 73. On main: ``ok``. The sandbox it implies
    (``PrivateTmp=``) keeps the control socket out of the workdir: /run/swt-PID, its
    ``RuntimeDirectory=``."""
    node_dir = varlib / "node"
    node_dir.mkdir(mode=0o700)
    other = varlib / "other"
    other.mkdir(mode=0o700)
    run_dir = f"swt-{os.getpid()}"
    lines = (
        f"DynamicUser=yes\nUser=swt-dyn-{os.getpid()}\nStateDirectory={varlib.name}/node\n"
        f"RuntimeDirectory={run_dir}\nReadWritePaths={other}\n"
    )
    unit = _unit(workdir, lines)

    def config(state: Path) -> Path:
        cfg = _config(workdir, state, node_dir)
        cfg.write_text(cfg.read_text().replace(f"{workdir}/ctl.sock", f"/run/{run_dir}/ctl.sock"))
        return cfg

    ok = _check(config(node_dir / "state"), unit)
    assert ok.returncode == 0, ok.stderr
    assert f"judged as swt-dyn-{os.getpid()} (DynamicUser= of" in ok.stdout
    given = ok.stdout.split("systemd gives it ", 1)[1].split(")", 1)[0].split()
    assert str(node_dir) in given and f"/run/{run_dir}" in given, ok.stdout
    refused = _check(config(other), unit)
    assert refused.returncode == EX_CANTCREAT, refused
    assert "dataplane.state_dir" in refused.stderr
    assert f"cannot write in {other}" in refused.stderr
    assert "systemd gives the dynamic user" in refused.stderr
    assert not Path(f"/run/{run_dir}").exists()
