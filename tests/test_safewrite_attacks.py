"""A local user against the last writes by path: the replay windows' saves, the XRCE key's
first write, and the floor judged without the unit's user (docs/security.md, "A state or
key folder whose parent another user writes"; review 15).

The attack of tests/test_safeopen_attacks.py, on the writers left: node.key's folder lies
in a parent every user may rename in, and user ``nobody`` swaps it for their own folder
just after its check (deterministic: the swap runs from inside the monkeypatched check).
On main the windows' save and the XRCE key's write opened the folder by path again, so
both landed in nobody's folder (the XRCE key is a secret: nobody could then read it). Now
each is written through a descriptor of the folder judged (``swarmd.bundle.safeopen``).
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

from swarmd.auth import windows as windows_mod
from swarmd.auth.freshness import Freshness
from swarmd.auth.windows import load_windows, save_windows, windows_path
from swarmd.bundle import safeopen
from swarmd.bundle.floor import floor_path
from swarmd.bundle.keys import dev_node_keys
from swarmd.px4 import xrce_key as xrce_key_mod
from swarmd.px4.xrce_key import XRCE_KEY_FILE, XrceKeyError, load_or_create
from tests.daemon_support import NOBODY, as_nobody, loopback_config, run_swarmd, write_bundle
from tests.test_safeopen_attacks import (
    PLANT,
    _attempt,
    _root_folder,
    _swap_after,
    needs_root,
    parent,  # noqa: F401 - the fixture, shared
)

HIGHS = {bytes(12): Freshness(7, 9)}


def _names(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir())


@needs_root
def test_the_xrce_key_is_not_written_into_a_folder_swapped_after_its_check(
    parent: Path,  # noqa: F811 - the fixture
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """No key yet: the folder is judged, no file is found, a key is generated. On main the
    write opened the folder by path again: the private key landed in nobody's folder."""
    state = _root_folder(parent, {})
    theirs = parent / "theirs"
    as_nobody(PLANT, str(theirs), "placeholder", "x")  # nobody's own folder
    # swapped once the folder was judged and found without a key (main: by path, then the
    # write opened it by path again)
    aside = _swap_after(monkeypatch, xrce_key_mod, "_read_key", state, theirs)
    key = _attempt(lambda: load_or_create(state), XrceKeyError)
    assert _names(state) == ["placeholder"]  # theirs: no key in it
    if isinstance(key, XrceKeyError):
        assert "\n" not in str(key)
    else:  # written through the folder judged: the real one, wherever it is now
        assert (aside / XRCE_KEY_FILE).read_text() == f"{key.value}\n"
        assert (aside / XRCE_KEY_FILE).stat().st_mode & 0o777 == 0o600


@needs_root
def test_the_windows_are_not_saved_into_a_folder_swapped_after_their_check(
    parent: Path,  # noqa: F811 - the fixture
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The daemon loads the windows at start (the folder judged), then saves them every
    ``SAVE_PERIOD_S``. On main each save opened the folder by path, unjudged: after the
    swap every save went into nobody's folder. Now each save reopens the folder and judges
    it again: nobody's is refused (the daemon logs it and counts it)."""
    name = windows_path(parent, "uav1").name
    state = _root_folder(parent, {})
    theirs = parent / "theirs"
    as_nobody(PLANT, str(theirs), "placeholder", "x")
    _swap_after(monkeypatch, windows_mod, "writers_problem", state, theirs)
    path = windows_path(state, "uav1")
    assert load_windows(path).highs == {}  # judged, then swapped
    saved = _attempt(lambda: save_windows(path, HIGHS), OSError)
    assert name not in _names(state)  # theirs: nothing written
    assert isinstance(saved, OSError)
    assert "\n" not in str(saved) and str(state) in str(saved)


@needs_root
def test_check_config_judges_the_floors_folder_as_the_units_user(workdir: Path) -> None:
    """node.key's folder and its floor are the daemon's user's (here ``nobody``): ``run``
    as that user trusts its own files, and every other check of ``check-config --user
    nobody`` judges them as nobody's. On main the floor's check alone left the user out and
    refused the folder (73: "owned by uid 65534")."""
    os.chmod(workdir, 0o755)  # noqa: S103 - nobody reaches its folder below
    files = write_bundle(workdir / "etc", 2, domain_id=0)
    node_dir = workdir / "node"
    node_dir.mkdir(mode=0o700)
    key = node_dir / "node.key"
    key.write_bytes(dev_node_keys("testswarm", "uav1").pem())
    key.chmod(0o600)
    floor = floor_path(node_dir, "uav1")
    floor.write_text(json.dumps({"serial": 0, "sha256": files.bundle.content_sha256.hex()}))
    for path in (node_dir, key, floor):
        os.chown(path, NOBODY, NOBODY)
    cfg = loopback_config(workdir, files)
    text = cfg.read_text().replace("  allow_dev: true\n", f"  allow_dev: true\n  node_key: {key}\n")
    cfg.write_text(text)
    proc = run_swarmd("check-config", "--config", str(cfg), "--user", "nobody")
    assert "owned by uid" not in proc.stderr, proc.stderr  # main: the floor's check, 73
    assert proc.returncode == 0, proc


@needs_root
def test_a_swap_after_a_saves_own_check_writes_the_real_folder(
    parent: Path,  # noqa: F811 - the fixture
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The save's own check, then the swap: the write goes through the descriptor judged,
    into the real folder (wherever nobody moved it), never into theirs."""
    state = _root_folder(parent, {})
    theirs = parent / "theirs"
    as_nobody(PLANT, str(theirs), "placeholder", "x")
    aside = _swap_after(monkeypatch, safeopen, "writers_problem", state, theirs)
    path = windows_path(state, "uav1")
    save_windows(path, HIGHS)
    assert _names(state) == ["placeholder"]  # theirs: nothing written
    assert load_windows(windows_path(aside, "uav1")).highs == HIGHS
