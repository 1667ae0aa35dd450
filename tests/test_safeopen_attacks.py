"""A local user against the state and key files between their folder's check and their read
(docs/security.md, "A state or key folder whose parent another user writes"; review 15).

swarmd judged each state folder (node.key's, ``dataplane.state_dir``) by its path, then
opened its files by path with a plain, unbounded ``open``. A user who may rename entries in
the folder's parent swaps the judged folder for their own between the two (here: made
deterministic by swapping, as user ``nobody``, from inside the check itself), or a FIFO,
a symlink or a huge file sits at a file's name. Now the folder is opened once and judged on
that descriptor, and each file is opened relative to it ``O_NOFOLLOW | O_NONBLOCK``,
checked a regular file of a trusted owner, and read up to its kind's cap
(``swarmd.bundle.safeopen``).
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import tracemalloc
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from types import FrameType, SimpleNamespace
from typing import Any, TypeVar, cast

import pytest

from swarmd import daemon_setup, statefile
from swarmd.auth import epoch as epoch_mod
from swarmd.auth.epoch import EpochError, next_epoch
from swarmd.auth.windows import load_windows, windows_path
from swarmd.bundle import floor as floor_mod
from swarmd.bundle.errors import BundleError
from swarmd.bundle.floor import FloorError, floor_path
from swarmd.bundle.keys import dev_node_keys
from swarmd.bundle.model import Bundle
from swarmd.cli.swarmd_main import main as swarmd_main
from swarmd.config import BundleConfig, DaemonConfig
from swarmd.config import model as config_model
from swarmd.daemon_setup import NodeSecretsError, load_node_secrets
from swarmd.dataplane.ledger import MAX_EXECUTED_COMMANDS, MAX_SEEN_OUTCOMES
from swarmd.dataplane.types import MAX_NAME_CHARS, MAX_REASON_CHARS, CommandResult
from swarmd.exitcodes import EX_CONFIG
from swarmd.px4.provision import SigningKeyError, signing_key_for
from swarmd.px4.signing import px4_key_file
from swarmd.statefile import NodeState, StateDirError, boot, state_path
from swarmd.swarm.commander import MAX_DECIDED_COMMANDS, KeptDecision
from tests.daemon_support import (
    SWARMD,
    BundleFiles,
    as_nobody,
    clean_env,
    loopback_config,
    write_bundle,
)

CLOCK = 1_800_000_000.0  # the wall clock the epochs are drawn from
PLANTED_EPOCH = 4_000_000_000  # a high epoch: the node would skip ahead to it
HANG_BOUND_S = 10.0  # a FIFO read blocks forever; this test fails instead
needs_root = pytest.mark.skipif(os.geteuid() != 0, reason="needs root to act as user nobody")


class Blocked(BaseException):
    """The body blocked (on a FIFO): not an ``OSError`` (``TimeoutError`` is one, and the
    code under test takes an ``OSError`` as an unreadable file), so nothing swallows it."""


@contextmanager
def _within(seconds: float) -> Iterator[None]:
    """Fail (not hang) when the body blocks longer than ``seconds`` (an open of a FIFO);
    the alarm repeats each second after, should a handler catch it anyway."""

    def expired(signum: int, frame: FrameType | None) -> None:
        raise Blocked("blocked on the planted file")

    previous = signal.signal(signal.SIGALRM, expired)
    signal.setitimer(signal.ITIMER_REAL, seconds, 1.0)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)


T = TypeVar("T")
E = TypeVar("E", bound=Exception)


def _attempt(call: Callable[[], T], error: type[E]) -> T | E:
    """What ``call`` returned, or the ``error`` it raised (either is a defence here)."""
    try:
        return call()
    except error as exc:
        return exc


PLANT = (
    "import os, sys\n"
    "os.mkdir(sys.argv[1], 0o700)\n"
    "for name, body in zip(sys.argv[2::2], sys.argv[3::2]):\n"
    "    path = os.path.join(sys.argv[1], name)\n"
    "    if body == 'FIFO':\n"
    "        os.mkfifo(path, 0o600)\n"
    "    else:\n"
    "        fd = os.open(path, os.O_WRONLY | os.O_CREAT, 0o600)\n"
    "        os.write(fd, body.encode())\n"
    "        os.close(fd)\n"
)
SWAP = "import os, sys\nos.rename(sys.argv[1], sys.argv[2])\nos.rename(sys.argv[3], sys.argv[1])\n"


@pytest.fixture
def parent(workdir: Path) -> Path:
    """The misconfiguration: the state folder's parent is writable by every user (no
    sticky bit), so nobody may rename the folder in it; the folder itself is root's 0700."""
    os.chmod(workdir, 0o755)  # noqa: S103 - nobody must reach the folders under it
    shared = workdir / "shared"
    shared.mkdir()
    os.chmod(shared, 0o777)  # noqa: S103 - the misconfiguration under attack
    return shared


def _swap_after(
    monkeypatch: pytest.MonkeyPatch, module: Any, name: str, state: Path, theirs: Path
) -> Path:
    """Wrap ``module.name`` (the folder's check) so that, once it has passed, user nobody
    swaps ``state`` for ``theirs``: the race between the check and the read, made
    deterministic. Returns where the real folder went."""
    aside = state.with_name("aside")
    real: Callable[..., Any] = getattr(module, name)
    done: list[bool] = []

    def checked_then_swapped(*args: Any, **kwargs: Any) -> Any:
        result = real(*args, **kwargs)
        if not done:
            done.append(True)
            as_nobody(SWAP, str(state), str(aside), str(theirs))
        return result

    monkeypatch.setattr(module, name, checked_then_swapped)
    return aside


def _root_folder(parent: Path, files: dict[str, str]) -> Path:
    state = parent / "state"
    state.mkdir(mode=0o700)
    for name, body in files.items():
        (state / name).write_text(body)
    return state


@needs_root
def test_an_epoch_folder_swapped_after_its_check_is_not_read_or_written(
    parent: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """On main the epoch came from the attacker's file (4,000,000,001: every later epoch
    of this node above what its peers expect) and the new one was written into their
    folder."""
    name = epoch_mod.epoch_path(parent, "uav1").name
    state = _root_folder(parent, {name: "100\n"})
    theirs = parent / "theirs"
    as_nobody(PLANT, str(theirs), name, f"{PLANTED_EPOCH}\n")
    aside = _swap_after(monkeypatch, epoch_mod, "refuse_shared_dir", state, theirs)
    result = _attempt(lambda: next_epoch(state, "uav1", CLOCK), EpochError)
    if isinstance(result, EpochError):  # the folder written through is judged again: theirs
        assert "\n" not in str(result)
        assert str(state) in str(result)
    else:
        assert result.epoch == int(CLOCK)  # the real folder's (100), not the planted one
        assert (aside / name).read_text() == f"{int(CLOCK)}\n"
    assert (state / name).read_text() == f"{PLANTED_EPOCH}\n"  # theirs: untouched
    assert sorted(p.name for p in state.iterdir()) == [name]  # nothing written there


@needs_root
def test_a_state_folder_swapped_after_its_check_is_not_read_or_written(
    parent: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """On main the node's boot counter and executed ids came from the planted file (boot
    42, the real ``("lead", 7)`` forgotten) and the state was saved into their folder."""
    name = state_path(parent, "uav1").name
    real = json.dumps({"boot": 5, "executed": [["lead", 7]]})
    state = _root_folder(parent, {name: real})
    theirs = parent / "theirs"
    as_nobody(PLANT, str(theirs), name, json.dumps({"boot": 41, "executed": []}))
    aside = _swap_after(monkeypatch, statefile, "refuse_shared_dir", state, theirs)
    loaded = _attempt(lambda: boot(state, "uav1", wall_now=CLOCK), StateDirError)
    if isinstance(loaded, StateDirError):
        assert "\n" not in str(loaded)
        assert str(state) in str(loaded)
    else:
        assert loaded.boot == 6
        assert loaded.executed == [("lead", 7)]
        assert json.loads((aside / name).read_text())["boot"] == 6
    assert json.loads((state / name).read_text())["boot"] == 41  # theirs: untouched
    assert sorted(p.name for p in state.iterdir()) == [name]


def _bundle(serial: int) -> Bundle:
    # the floor reads a bundle's serial and content hash only
    return cast(Bundle, SimpleNamespace(serial=serial, content_sha256=bytes(32)))


@needs_root
def test_a_floor_folder_swapped_after_its_check_cannot_lower_the_floor(
    parent: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The rollback through the race: the real floor is serial 7; the attacker's folder
    holds a floor of 1, so a serial-3 bundle (a revoked member still in it) passed on main
    and the floor was rewritten, in their folder, to 3."""
    name = floor_path(parent, "uav1").name
    floor = json.dumps({"serial": 7, "sha256": "ab" * 32})
    state = _root_folder(parent, {name: floor})
    theirs = parent / "theirs"
    as_nobody(PLANT, str(theirs), name, json.dumps({"serial": 1, "sha256": "cd" * 32}))
    _swap_after(monkeypatch, floor_mod, "refuse_shared_dir", state, theirs)
    with pytest.raises(BundleError, match="serial"):
        floor_mod.enforce(_bundle(3), source="b.swb", state_dir=state, node="uav1", commit=True)
    assert json.loads((state / name).read_text())["serial"] == 1  # theirs: untouched


def _key_config(node_key: Path, files: BundleFiles) -> DaemonConfig:
    bundle = BundleConfig(path=str(files.path), node_key=str(node_key), allow_dev=True)
    return DaemonConfig(file="swarmd.yaml", node="uav1", interface="lo", bundle=bundle)


@needs_root
def test_a_node_key_folder_swapped_after_its_check_is_not_read(
    parent: Path, workdir: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """On main the key's check (its mode, by path) passed on the real node.key, then the
    read opened the FIFO nobody planted in their folder and waited forever."""
    files = write_bundle(workdir / "etc", 2, domain_id=0)
    pem = dev_node_keys("testswarm", "uav1").pem().decode()
    state = _root_folder(parent, {"node.key": pem})
    os.chmod(state / "node.key", 0o600)
    theirs = parent / "theirs"
    as_nobody(PLANT, str(theirs), "node.key", "FIFO")
    # main checked node.key's mode by path, then read it by path
    _swap_after(monkeypatch, daemon_setup, "refuse_shared_secret", state, theirs)
    config = _key_config(state / "node.key", files)
    with _within(HANG_BOUND_S):
        secrets = _attempt(lambda: load_node_secrets(config, files.bundle), NodeSecretsError)
    if isinstance(secrets, NodeSecretsError):
        assert "\n" not in str(secrets)
    else:
        assert secrets.public == dev_node_keys("testswarm", "uav1").public


def _private_folder(tmp_path: Path) -> Path:
    state = tmp_path / "state"
    state.mkdir(mode=0o700)
    return state


def test_a_fifo_at_each_state_file_name_neither_blocks_nor_is_read(tmp_path: Path) -> None:
    """A FIFO in the node's own folder (planted by the race above, or by a mistake): the
    epoch and the state file were read with a plain open, which waits for a writer that
    never comes (on main: the test's bound fired for both). Now each is unreadable: the
    epoch comes from the clock, the state file is replaced, both with a line."""
    state = _private_folder(tmp_path)
    os.mkfifo(epoch_mod.epoch_path(state, "uav1"), 0o600)
    os.mkfifo(state_path(state, "uav1"), 0o600)
    os.mkfifo(floor_path(state, "uav1"), 0o600)
    os.mkfifo(windows_path(state, "uav1"), 0o600)
    with _within(HANG_BOUND_S):
        result = next_epoch(state, "uav1", CLOCK)
        loaded = boot(state, "uav1", wall_now=CLOCK)
        with pytest.raises(FloorError):
            floor_mod.read_floor(floor_path(state, "uav1"), "b.swb")
        windows = load_windows(windows_path(state, "uav1"))
    assert result.epoch == int(CLOCK) and result.recovered_from is not None
    assert loaded.boot == 1 and loaded.recovered_from is not None
    assert windows.highs == {} and windows.problem is not None
    # both replaced by regular files through the atomic writer
    assert epoch_mod.epoch_path(state, "uav1").read_text() == f"{int(CLOCK)}\n"
    assert json.loads(state_path(state, "uav1").read_text())["boot"] == 1


@pytest.mark.parametrize("kind", ["node.key", "px4-signing.key"])
def test_a_fifo_at_a_key_files_name_is_refused_not_waited_on(tmp_path: Path, kind: str) -> None:
    """node.key and the PX4 signing key in a root folder, a FIFO of the right mode: on
    main the mode check passed and the read waited forever."""
    folder = _private_folder(tmp_path)
    os.mkfifo(folder / kind, 0o600)
    with _within(HANG_BOUND_S):
        if kind == "node.key":
            files = write_bundle(tmp_path / "etc", 2, domain_id=0)
            with pytest.raises(NodeSecretsError):
                load_node_secrets(_key_config(folder / kind, files), files.bundle)
        else:
            with pytest.raises(SigningKeyError):
                signing_key_for(swarm="s", node="uav1", key_file=str(folder / kind), seed=b"")


def test_a_symlink_at_each_state_file_name_is_not_followed(tmp_path: Path) -> None:
    """A symlink at the epoch's or the state file's name points at a file elsewhere (any
    file the daemon can read): on main both were followed (the epoch jumped to the
    target's number, the boot counter to its 41). Now neither is followed."""
    state = _private_folder(tmp_path)
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    (elsewhere / "epoch").write_text(f"{PLANTED_EPOCH}\n")
    (elsewhere / "state").write_text(json.dumps({"boot": 41, "executed": []}))
    epoch_mod.epoch_path(state, "uav1").symlink_to(elsewhere / "epoch")
    state_path(state, "uav1").symlink_to(elsewhere / "state")
    assert next_epoch(state, "uav1", CLOCK).epoch == int(CLOCK)
    assert boot(state, "uav1", wall_now=CLOCK).boot == 1
    assert (elsewhere / "epoch").read_text() == f"{PLANTED_EPOCH}\n"  # the target: untouched


@pytest.mark.parametrize("kind", ["node.key", "px4-signing.key"])
def test_a_symlink_at_a_key_files_name_is_refused(tmp_path: Path, kind: str) -> None:
    """A valid key reached through a symlink: on main it was read (the key is whatever
    the link points at, in a folder never judged)."""
    folder = _private_folder(tmp_path)
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    if kind == "node.key":
        files = write_bundle(tmp_path / "etc", 2, domain_id=0)
        (elsewhere / kind).write_bytes(dev_node_keys("testswarm", "uav1").pem())
        os.chmod(elsewhere / kind, 0o600)
        (folder / kind).symlink_to(elsewhere / kind)
        with pytest.raises(NodeSecretsError, match="symlink"):
            load_node_secrets(_key_config(folder / kind, files), files.bundle)
    else:
        (elsewhere / kind).write_text("ab" * 32 + "\n")
        os.chmod(elsewhere / kind, 0o600)
        (folder / kind).symlink_to(elsewhere / kind)
        with pytest.raises(SigningKeyError, match="symlink"):
            signing_key_for(swarm="s", node="uav1", key_file=str(folder / kind), seed=b"")


HUGE_BYTES = 64 * 1024 * 1024  # a sparse file: no disk, but main read all of it
READ_PEAK_BOUND = 4 * 1024 * 1024  # what the bounded reads may allocate, with margin


@pytest.mark.parametrize("which", ["epoch", "state"])
def test_an_oversized_epoch_or_state_file_is_not_read_whole(tmp_path: Path, which: str) -> None:
    """64 MiB at the epoch's or the state file's name: on main both were read whole
    (``read_text``: 64 MiB and its decoded string; a sparse file of terabytes ends the
    daemon). Now a file over its cap is refused at its size, with one line, and replaced."""
    state = _private_folder(tmp_path)
    path = epoch_mod.epoch_path(state, "uav1") if which == "epoch" else state_path(state, "uav1")
    with path.open("wb") as f:
        f.truncate(HUGE_BYTES)
    tracemalloc.start()
    try:
        if which == "epoch":
            why = epoch_mod.read_epoch(path)[1]
        else:
            why = statefile.load(path, CLOCK).recovered_from
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < READ_PEAK_BOUND, peak
    assert why is not None and "\n" not in why and "cap" in why


def test_the_largest_state_file_is_far_under_its_cap(tmp_path: Path) -> None:
    """The cap must never refuse a file swarmd wrote: every list at its cap, every string
    at its longest, and each reason character one JSON writes as six (``\\u00e9``)."""
    from swarmd.swarm.commander import MAX_DISARM_MARKS  # here: as safeopen below

    long_name = "n" * MAX_NAME_CHARS
    reason = "\u00e9" * (MAX_REASON_CHARS // 2)  # two UTF-8 octets each
    big = 2**63 - 1
    state = NodeState(
        state_path(tmp_path, "uav1"),
        boot=2**31 - 1,
        executed=[(long_name, big)] * MAX_EXECUTED_COMMANDS,
        outcomes=[(long_name, big, CommandResult.FAILED.value, reason)] * MAX_SEEN_OUTCOMES,
        decisions=[KeptDecision(2**31 - 1, long_name, big, long_name, "failed", reason, CLOCK, 1e9)]
        * MAX_DECIDED_COMMANDS,
        told_unsaved=[(long_name, big)] * MAX_DECIDED_COMMANDS,
        disarm_unconfirmed=[(long_name, big)] * MAX_DISARM_MARKS,
    )
    state.save()
    from swarmd.bundle import safeopen  # here: the attack tests above also run on main

    size = state.path.stat().st_size
    print(f"largest state file: {size} bytes, cap {safeopen.STATE_FILE_CAP}")
    assert size * 4 < safeopen.STATE_FILE_CAP


def test_the_key_caps_are_far_above_the_real_keys(tmp_path: Path) -> None:
    """node.key (two PEM blocks) and the PX4 key file (64 hex digits): the figures in
    ``safeopen``'s comments."""
    from swarmd.bundle import safeopen

    node_key = dev_node_keys("testswarm", "uav1").pem()
    print(f"node.key: {len(node_key)} bytes, cap {safeopen.NODE_KEY_CAP}")
    assert len(node_key) * 100 < safeopen.NODE_KEY_CAP
    assert len(str(2**32 - 1)) + 1 <= 11 < safeopen.EPOCH_CAP
    px4_key = px4_key_file(bytes(32), 2**64 - 1)  # what 'swarmctl px4 key --out' writes
    print(f"px4 key file: {len(px4_key)} bytes (as hex: 65), cap {safeopen.SIGNING_KEY_CAP}")
    assert max(len(px4_key), 65) * 100 < safeopen.SIGNING_KEY_CAP


def test_a_symlinked_folder_is_followed_only_from_a_folder_others_cannot_write(
    tmp_path: Path,
) -> None:
    """systemd's ``DynamicUser=`` makes ``/var/lib/swarmd`` a symlink to
    ``/var/lib/private/swarmd``: followed, as its folder is root's. The same symlink in a
    folder every user writes is refused (one line, the folder and the field)."""
    real = _private_folder(tmp_path)
    trusted = tmp_path / "trusted"
    trusted.mkdir(mode=0o755)
    (trusted / "swarmd").symlink_to(real)
    assert next_epoch(trusted / "swarmd", "uav1", CLOCK).epoch == int(CLOCK)
    shared = tmp_path / "shared"
    shared.mkdir()
    os.chmod(shared, 0o777)  # noqa: S103 - the misconfiguration under attack
    (shared / "swarmd").symlink_to(real)
    with pytest.raises(EpochError) as caught:
        next_epoch(shared / "swarmd", "uav1", CLOCK)
    line = str(caught.value)
    assert "\n" not in line and str(shared / "swarmd") in line and "bundle.node_key" in line


@pytest.mark.parametrize("which", ["bundle", "trusted_key", "config"])
def test_a_fifo_at_the_bundle_its_key_or_the_config_is_refused_by_check_config(
    workdir: Path, which: str
) -> None:
    """The bundle, the swarm key or the config, a FIFO at its name in a root folder (the
    path checks pass: root's, mode 0644): on main ``check-config`` waited on the open until
    the test's bound killed it. Now each is opened ``O_NONBLOCK`` and must be a regular
    file (the bundle and key through their judged folder): one line, 78."""
    files = write_bundle(workdir / "etc", 2, domain_id=0)
    config = loopback_config(workdir, files)
    path = {"bundle": files.path, "trusted_key": files.trusted_key, "config": config}[which]
    path.unlink()
    os.mkfifo(path, 0o644)
    try:
        proc = subprocess.run(
            [SWARMD, "check-config", "--config", str(config)],
            capture_output=True,
            text=True,
            timeout=HANG_BOUND_S + 20,
            env=clean_env(),
            check=False,
        )
    except subprocess.TimeoutExpired:
        pytest.fail("check-config waited on the FIFO")
    assert proc.returncode == EX_CONFIG, proc.stderr
    assert proc.stderr.count("\n") == 1 and str(path) in proc.stderr, proc.stderr


@needs_root
def test_a_config_swapped_between_its_read_and_its_check_is_refused(
    parent: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """The config is read, then judged by path: nobody, who may rename entries in the
    config folder's parent, has their own folder there when the daemon reads (their
    config: node uav2) and the real one back when it checks. On main ``check-config``
    said ok for uav2. Now the file read is judged (its ``fstat`` at the read)."""
    files = write_bundle(parent.parent / "bundle", 2, domain_id=0)
    real = parent / "etc"
    real.mkdir(mode=0o755)
    config = loopback_config(real, files)
    text = config.read_text()
    theirs_text = text.replace("node: uav1", "node: uav2")
    assert theirs_text != text
    theirs = parent / "theirs"
    as_nobody(PLANT, str(theirs), config.name, theirs_text)
    os.chmod(theirs, 0o755)  # noqa: S103 - nobody's own folder, readable as /etc/swarmd is
    aside = parent / "aside"
    as_nobody(SWAP, str(real), str(aside), str(theirs))  # theirs at the config's path
    real_check: Callable[..., Any] = config_model.trust_problem
    swapped: list[bool] = []

    def swap_back_then_check(path: Any, also: frozenset[int] = frozenset()) -> Any:
        if not swapped:  # the config was read; the real folder is back for its check
            swapped.append(True)
            as_nobody(SWAP, str(real), str(theirs), str(aside))
        return real_check(path, also)

    monkeypatch.setattr(config_model, "trust_problem", swap_back_then_check)
    code = swarmd_main(["check-config", "--config", str(config)])
    out, err = capsys.readouterr()
    assert swapped
    assert "uav2" not in out
    assert code == EX_CONFIG, (out, err)
    assert err.count("\n") == 1 and str(config) in err
