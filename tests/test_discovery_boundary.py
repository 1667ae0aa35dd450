"""The sans-IO boundary: swarmd.rtps, swarmd.discovery and swarmd.auth never touch asyncio,
sockets or time."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
FORBIDDEN = {"asyncio", "socket", "time", "selectors", "threading", "trio"}


def test_importing_the_core_pulls_in_no_asyncio_or_socket() -> None:
    code = (
        "import sys\n"
        "import swarmd.rtps, swarmd.discovery, swarmd.discovery.testing, swarmd.discovery.memnet\n"
        "import swarmd.auth.keys, swarmd.auth.freshness, swarmd.auth.epoch\n"
        "bad = ('asyncio', 'socket', 'selectors')\n"
        "print(','.join(sorted(m for m in bad if m in sys.modules)))\n"
    )
    result = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=ROOT
    )
    assert result.stdout.strip() == ""


def test_no_module_of_the_core_imports_io_or_clock_modules() -> None:
    # `time` is always in sys.modules (the interpreter imports it at start), so the runtime
    # check above cannot see it; this reads the import statements instead.
    offenders = []
    for package in ("rtps", "discovery", "auth"):
        for path in sorted((ROOT / "swarmd" / package).glob("*.py")):
            tree = ast.parse(path.read_text(), str(path))
            for node in ast.walk(tree):
                if isinstance(node, ast.Import):
                    names = [a.name for a in node.names]
                elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                    names = [node.module]
                else:
                    continue
                offenders += [
                    f"{path.name}:{node.lineno} {n}" for n in names if n.split(".")[0] in FORBIDDEN
                ]
    assert offenders == []
