"""Real third-party XRCE-DDS peers (optional) and swarmd's own PX4 stand-in (always there).

Third-party source is never kept in ``../shared`` nor built by the project's scripts. Tests
that drive PX4's client library (``px4_like_client``) or eProsima's ``MicroXRCEAgent`` run
when ``XRCE_PEERS`` names a directory holding those binaries, built elsewhere (directly in it
or in its ``bin/``; their libraries in its ``lib/``), and skip with that reason otherwise.
Every other XRCE test runs against the stand-in (``swarmd_lab.px4.xrce_vehicle``).
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest

SKIP_REASON = (
    "XRCE_PEERS is not set: the third-party XRCE-DDS peers (px4_like_client, MicroXRCEAgent) "
    "are optional and built elsewhere; set XRCE_PEERS=DIR to run this test"
)


def peers_dir() -> Path | None:
    env = os.environ.get("XRCE_PEERS")
    return Path(env) if env else None


def peer_binary(name: str) -> Path:
    """The third-party peer ``name`` from ``XRCE_PEERS``; skips when that is not set, fails
    when it is set and the binary is missing (a set-up mistake, not a reason to skip)."""
    root = peers_dir()
    if root is None:
        pytest.skip(SKIP_REASON)
    for path in (root / name, root / "bin" / name):
        if path.exists():
            return path
    raise AssertionError(f"XRCE_PEERS={root}: no {name} in it (or in its bin/)")


def peer_env() -> dict[str, str]:
    """The environment the peers run in: their own libraries from ``XRCE_PEERS/lib``."""
    root = peers_dir()
    lib = str(root / "lib") if root is not None else ""
    return dict(os.environ, LD_LIBRARY_PATH=lib)


def standin_argv(port: int, release: str = "1.16", *extra: str) -> list[str]:
    """swarmd's PX4 stand-in over uXRCE-DDS (a simulator, in the lab distribution)."""
    return [sys.executable, "-m", "swarmd_lab.px4.xrce_vehicle", "-p", str(port),
            "-V", release, "-q", *extra]  # fmt: skip
