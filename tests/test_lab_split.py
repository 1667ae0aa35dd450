"""The drone package is only what flies (issue 11): the lab tools are a second distribution.

``swarmd`` (the wheel a Jetson installs) never imports ``swarmd_lab``, numpy or matplotlib;
``swarmd_lab`` (lab/pyproject.toml) holds the simulator, the demo, the namespace builder and
the vehicle simulator. Checked in fresh interpreters and on the wheel setuptools builds.
"""

from __future__ import annotations

import ast
import json
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
LAB_ONLY = ("numpy", "matplotlib", "swarmd_lab")


def _loaded_after(code: str) -> list[str]:
    """The lab-only modules in ``sys.modules`` after running ``code`` in a fresh interpreter."""
    lab = f"sorted(m for m in sys.modules if m.split('.')[0] in {LAB_ONLY!r})"
    probe = f"{code}\nprint(json.dumps({lab}))"
    out = subprocess.run(
        [sys.executable, "-c", "import json, sys\n" + probe],
        capture_output=True,
        text=True,
        check=True,
        cwd=ROOT,
    ).stdout
    loaded: list[str] = json.loads(out.strip().splitlines()[-1])
    return loaded


def test_swarmd_run_and_swarmctl_never_load_the_lab() -> None:
    # what `swarmd run` imports (its entry point and the lazily imported daemon), and swarmctl
    code = (
        "import swarmd.cli.swarmd_main, swarmd.cli.swarmctl\n"
        "import swarmd.daemon, swarmd.bundle.loader, swarmd.discovery.config\n"
        "swarmd.cli.swarmctl.build_parser()\n"
    )
    assert _loaded_after(code) == []


def test_no_module_of_the_drone_package_loads_the_lab() -> None:
    code = (
        "import importlib, pkgutil, swarmd\n"
        "for m in pkgutil.walk_packages(swarmd.__path__, 'swarmd.'):\n"
        "    importlib.import_module(m.name)\n"
    )
    assert _loaded_after(code) == []


def test_the_lab_still_sees_the_drone_package() -> None:
    # the other direction is allowed, and the probe can tell (a test that cannot fail is a defect)
    assert _loaded_after("import swarmd_lab.sim.runner") != []


def test_the_drone_wheel_contains_no_lab_module(tmp_path: Path) -> None:
    src = tmp_path / "src"
    src.mkdir()
    for name in ("pyproject.toml", "README.md"):
        shutil.copy(ROOT / name, src / name)
    ignore = shutil.ignore_patterns("__pycache__", "*.egg-info")
    for tree in ("swarmd", "lab"):
        shutil.copytree(ROOT / tree, src / tree, ignore=ignore)
    # and the lab package at the top level too, where `include = ["swarmd*"]` would pick it up
    shutil.copytree(ROOT / "lab" / "swarmd_lab", src / "swarmd_lab", ignore=ignore)
    (tmp_path / "dist").mkdir()
    build = (
        "import sys; from setuptools import build_meta\n"
        f"print(build_meta.build_wheel({str(tmp_path / 'dist')!r}))\n"
    )
    subprocess.run(
        [sys.executable, "-c", build], cwd=src, check=True, capture_output=True, text=True
    )
    (wheel,) = (tmp_path / "dist").glob("swarmd-*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    tops = {n.split("/")[0] for n in names if not n.startswith("swarmd-")}
    assert tops == {"swarmd"}
    assert "swarmd/daemon.py" in names
    lab = [n for n in names if any(f"/{part}/" in n for part in ("sim", "demo"))]
    lab += [n for n in names if n.endswith(("netns.py", "sim_model.py", "vehicle_sim.py"))]
    assert lab == []
    entry_points = next(n for n in names if n.endswith("entry_points.txt"))
    console = zipfile.ZipFile(wheel).read(entry_points).decode()
    assert "swarmd-vehicle-sim" not in console


def _imports_of(path: Path, module: str, known: set[str]) -> set[str]:
    """The drone-package modules ``module`` imports anywhere (lazy imports included)."""
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    named: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            named.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parts = package.split(".")
                parts = parts[: len(parts) - (node.level - 1)]
                base = ".".join([*parts, *([node.module] if node.module else [])])
            named.add(base)
            named.update(f"{base}.{alias.name}" for alias in node.names)
    found: set[str] = set()
    for name in named:
        parts = name.split(".")
        found.update(p for i in range(1, len(parts) + 1) if (p := ".".join(parts[:i])) in known)
    return found


def test_every_module_of_the_drone_package_is_reached_by_swarmd_or_swarmctl() -> None:
    """A module nothing the drone runs imports is test tooling or dead code: it belongs in
    swarmd_lab or tests/ (issue 11), not in the wheel. Read from the import statements, so a
    lazily imported backend counts as reached."""
    paths = {}
    for path in (ROOT / "swarmd").rglob("*.py"):
        parts = list(path.relative_to(ROOT).with_suffix("").parts)
        paths[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    reached: set[str] = set()
    todo = ["swarmd.cli.swarmd_main", "swarmd.cli.swarmctl"]  # the console scripts
    while todo:
        module = todo.pop()
        if module not in reached:
            reached.add(module)
            todo += _imports_of(paths[module], module, set(paths))
    assert "swarmd.daemon" in reached and "swarmd.rtps.spdp" in reached  # the walk works
    assert sorted(set(paths) - reached) == []
