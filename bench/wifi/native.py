"""The testbed's two native pieces, built on demand into a gitignored cache.

- ``fastdds_peer`` (``peers/fastdds_peer.cpp``): the Fast DDS workload peer, linked against
  Debian's Fast DDS 2.9.1 (``libfastrtps-dev``);
- ``dilate.so`` (``dilate.c``): the LD_PRELOAD library behind ``--dilation`` (time dilation,
  docs/testbed.md).

``scripts/setup.sh`` builds both (``python -m bench.wifi.native``); the harness rebuilds a
piece whose source is newer than its binary. A piece that cannot be built (no compiler, no
Fast DDS headers) has a reason, and the contenders or options that need it say so.
"""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path
from typing import Final

HERE: Final = Path(__file__).resolve().parent
CACHE: Final = HERE.parents[1] / ".cache" / "bench-wifi"
FASTDDS_SRC: Final = HERE / "peers" / "fastdds_peer.cpp"
DILATE_SRC: Final = HERE / "dilate.c"
FASTDDS_HEADER: Final = Path("/usr/include/fastdds/dds/domain/DomainParticipant.hpp")


class BuildError(RuntimeError):
    """A native piece could not be built; the message says why."""


def _fresh(binary: Path, source: Path) -> bool:
    return binary.exists() and binary.stat().st_mtime >= source.stat().st_mtime


def _build(argv: list[str], binary: Path) -> Path:
    CACHE.mkdir(parents=True, exist_ok=True)
    tmp = binary.with_suffix(".tmp")
    proc = subprocess.run([*argv, "-o", str(tmp)], capture_output=True, text=True, check=False)
    if proc.returncode != 0:
        raise BuildError(f"{argv[0]} failed for {binary.name}: {proc.stderr.strip()[-600:]}")
    tmp.replace(binary)
    return binary


def fastdds_peer() -> Path:
    """The Fast DDS workload peer binary, built if missing or stale."""
    binary = CACHE / "fastdds_peer"
    if _fresh(binary, FASTDDS_SRC):
        return binary
    if shutil.which("g++") is None:
        raise BuildError("g++ not found (scripts/setup.sh installs it)")
    if not FASTDDS_HEADER.exists():
        raise BuildError("Fast DDS headers missing: apt-get install libfastrtps-dev")
    argv = ["g++", "-O2", "-std=c++17", str(FASTDDS_SRC), "-lfastrtps", "-lfastcdr"]
    return _build(argv, binary)


def dilate_library() -> Path:
    """The time-dilation LD_PRELOAD library, built if missing or stale."""
    binary = CACHE / "dilate.so"
    if _fresh(binary, DILATE_SRC):
        return binary
    if shutil.which("gcc") is None:
        raise BuildError("gcc not found (scripts/setup.sh installs it)")
    argv = ["gcc", "-shared", "-fPIC", "-O2", "-Wall", str(DILATE_SRC), "-ldl"]
    return _build(argv, binary)


def fastdds_discovery_server() -> list[str] | None:
    """argv prefix of Fast DDS's Discovery Server CLI (fastdds-tools), or None."""
    cli = shutil.which("fastdds")
    return [cli, "discovery"] if cli else None


def main() -> int:
    failed = 0
    for name, build in (("fastdds_peer", fastdds_peer), ("dilate.so", dilate_library)):
        try:
            build()
        except BuildError as exc:
            print(f"bench/wifi native: {name}: {exc}", file=sys.stderr)
            failed += 1
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
