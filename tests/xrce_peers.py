"""Where the XRCE-DDS peers are: ``../shared/peers/xrce`` beside the clone (or beside the main
checkout of a git worktree), built by ``scripts/setup.sh`` into ``.cache/xrce/bin``.

Tests skip only when the peers directory itself is absent; a missing binary when the
sources are there is a set-up failure and fails the test.
"""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent


def peers_dir() -> Path | None:
    env = os.environ.get("XRCE_PEERS")
    candidates = [Path(env)] if env else []
    candidates.append(REPO.parent / "shared" / "peers" / "xrce")
    try:
        common = subprocess.run(
            ["git", "-C", str(REPO), "rev-parse", "--git-common-dir"],
            capture_output=True, text=True, check=False, timeout=10,
        ).stdout.strip()  # fmt: skip
    except OSError:
        common = ""
    if common:
        candidates.append((REPO / common).resolve().parent.parent / "shared" / "peers" / "xrce")
    for c in candidates:
        if (c / "build.sh").is_file():
            return c
    return None


def peer_binary(name: str) -> Path:
    """The built peer ``name``; skips without the peers directory, fails without the build."""
    if peers_dir() is None:
        pytest.skip("XRCE peers not found (../shared/peers/xrce beside the clone)")
    path = REPO / os.environ.get("XRCE_OUT", ".cache/xrce") / "bin" / name
    assert path.exists(), f"{path} missing: run scripts/setup.sh (it builds the XRCE peers)"
    return path


def peer_env() -> dict[str, str]:
    """The environment the peers run in: MicroXRCEAgent finds its own library in the cache."""
    lib = REPO / os.environ.get("XRCE_OUT", ".cache/xrce") / "install" / "agent" / "lib"
    return dict(os.environ, LD_LIBRARY_PATH=str(lib))
