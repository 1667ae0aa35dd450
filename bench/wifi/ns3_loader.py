"""Importing the PyPI ``ns3`` wheel with a working TapBridge (testbed notes, pitfall 2).

The wheel's ``libns3.44-tap-bridge.so`` has the tap-creator path of the machine that built
it compiled in (``/gcl-builds/build/src/tap-bridge/ns3.44-tap-creator``), and the creator
it ships cannot find its libraries (RPATH into that build tree). Rather than create that
path on the host, ``import_ns`` copies the library into a private folder, overwrites the
path string with one of at most the same length (NUL padded) naming a small wrapper
script that sets ``LD_LIBRARY_PATH`` to the wheel's ``lib64`` and execs the shipped
creator, and makes cppyy load the copy instead of the original.
"""

from __future__ import annotations

import importlib
import importlib.util
import os
import stat
from pathlib import Path
from typing import Any, Final

BUILD_PATH: Final = b"/gcl-builds/build/src/tap-bridge/ns3.44-tap-creator"
TAP_LIBRARY: Final = "libns3.44-tap-bridge.so"
CREATOR: Final = "ns3.44-tap-creator"


class Ns3Unavailable(RuntimeError):
    """The ns3 wheel is missing or not the version this patch knows."""


def wheel_root() -> Path:
    """The installed ``ns3`` package folder (``.../site-packages/ns3``)."""
    spec = importlib.util.find_spec("ns3")
    if spec is None or not spec.submodule_search_locations:
        raise Ns3Unavailable(
            "the ns3 wheel is not installed: pip install -e '.[testbed]' (scripts/setup.sh does)"
        )
    return Path(next(iter(spec.submodule_search_locations)))


def unavailable_reason() -> str | None:
    """Why the testbed cannot run here, or None."""
    try:
        root = wheel_root()
    except Ns3Unavailable as exc:
        return str(exc)
    if not (root / "lib64" / TAP_LIBRARY).exists():
        return f"{root}/lib64/{TAP_LIBRARY} is missing: reinstall the ns3 wheel"
    if os.geteuid() != 0:
        return "the testbed needs root (namespaces, taps, the tap creator)"
    if not Path("/dev/net/tun").exists():
        return "/dev/net/tun is missing: the kernel has no TUN/TAP support here"
    return None


def patch_tap_bridge(workdir: Path) -> Path:
    """Write the patched library and the creator wrapper under ``workdir``; the copy's path."""
    root = wheel_root()
    original = (root / "lib64" / TAP_LIBRARY).read_bytes()
    if original.count(BUILD_PATH + b"\0") != 1:
        raise Ns3Unavailable(
            f"{TAP_LIBRARY} does not hold the expected tap-creator path: the ns3 wheel "
            "version changed; update bench/wifi/ns3_loader.py"
        )
    wrapper = workdir / "tc"
    if len(bytes(wrapper)) > len(BUILD_PATH):
        raise Ns3Unavailable(f"work folder path {workdir} is too long for the patch")
    creator = root / "libexec" / "ns3" / CREATOR
    wrapper.write_text(
        "#!/bin/sh\n"
        f"LD_LIBRARY_PATH='{root / 'lib64'}'${{LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}}\n"
        "export LD_LIBRARY_PATH\n"
        f"exec '{creator}' \"$@\"\n"
    )
    wrapper.chmod(0o755)
    if not os.access(creator, os.X_OK):
        creator.chmod(creator.stat().st_mode | stat.S_IXUSR | stat.S_IXGRP | stat.S_IXOTH)
    padded = bytes(wrapper).ljust(len(BUILD_PATH), b"\0")
    patched = workdir / TAP_LIBRARY
    patched.write_bytes(original.replace(BUILD_PATH, padded))
    return patched


def import_ns(workdir: Path) -> tuple[Any, Any]:
    """``(ns, cppyy)`` with the patched TapBridge loaded; takes 10-25 s (all ns-3 headers)."""
    patched = patch_tap_bridge(workdir)
    cppyy: Any = importlib.import_module("cppyy")
    original_load = cppyy.load_library

    def load_library(name: str) -> Any:
        if os.path.basename(name) == TAP_LIBRARY:
            return original_load(str(patched))
        return original_load(name)

    cppyy.load_library = load_library
    try:
        module: Any = importlib.import_module("ns")
    finally:
        cppyy.load_library = original_load
    return module.ns, cppyy
