"""The pinned environment (issue 17): what CI installs is the lock, and what flies installs.

``requirements/test.lock`` holds every package ``make test`` installs at one version with its
hashes, ``requirements/runtime-aarch64.lock`` the drone's runtime set for a Jetson Nano
(aarch64, manylinux2014, wheels only) at the same versions. ``pyproject.toml`` keeps ranges
for the drone's runtime dependencies. These tests fail when the three drift apart, when the
venv was not installed from the lock, or when a locked runtime package has no wheel a Jetson
can install (docs/dependencies.md).
"""

from __future__ import annotations

import re
import subprocess
import sys
import tomllib
from importlib import metadata
from pathlib import Path

import pytest
from packaging.requirements import Requirement
from packaging.utils import canonicalize_name

REPO = Path(__file__).resolve().parent.parent
TEST_LOCK = REPO / "requirements" / "test.lock"
RUNTIME_LOCK = REPO / "requirements" / "runtime-aarch64.lock"
PIN = re.compile(r"^([A-Za-z0-9._-]+)==([^\s\\;]+)")


def _locked(path: Path) -> dict[str, tuple[str, int]]:
    """name -> (version, number of hashes) for every pin of a lock file."""
    pins: dict[str, tuple[str, int]] = {}
    name = ""
    for line in path.read_text().splitlines():
        m = PIN.match(line)
        if m:
            name = canonicalize_name(m.group(1))
            assert name not in pins, f"{path.name}: {name} pinned twice"
            pins[name] = (m.group(2), 0)
        elif line.strip().startswith("--hash=sha256:") and name:
            version, hashes = pins[name]
            pins[name] = (version, hashes + 1)
        elif line.strip() and not line.lstrip().startswith("#"):
            assert line.startswith("    "), f"{path.name}: unexpected line {line!r}"
    return pins


def _runtime_requirements() -> list[Requirement]:
    project = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]
    return [Requirement(r) for r in project["dependencies"]]


def test_every_locked_package_is_pinned_with_hashes() -> None:
    for lock in (TEST_LOCK, RUNTIME_LOCK):
        pins = _locked(lock)
        assert pins, f"{lock.name} pins nothing"
        unhashed = [n for n, (_, hashes) in pins.items() if hashes == 0]
        assert not unhashed, f"{lock.name}: no hashes for {unhashed}"


def test_the_drone_keeps_ranges_and_the_locks_satisfy_them() -> None:
    test_pins = _locked(TEST_LOCK)
    runtime_pins = _locked(RUNTIME_LOCK)
    for req in _runtime_requirements():
        name = canonicalize_name(req.name)
        assert not any(s.operator in ("==", "===") for s in req.specifier), (
            f"pyproject.toml pins {req}: the drone's dependencies keep ranges; pins go in the lock"
        )
        for lock, pins in ((TEST_LOCK, test_pins), (RUNTIME_LOCK, runtime_pins)):
            assert name in pins, f"{lock.name} lacks runtime dependency {name}: run 'make lock'"
            assert req.specifier.contains(pins[name][0], prereleases=True), (
                f"{lock.name} has {name}=={pins[name][0]}, outside {req}: run 'make lock'"
            )


def test_the_drone_gets_the_versions_ci_tested() -> None:
    """Every package of the Jetson's runtime set is the one the test environment ran."""
    test_pins = _locked(TEST_LOCK)
    for name, (version, _) in _locked(RUNTIME_LOCK).items():
        assert name in test_pins, f"{name} is in the drone's set but was never tested"
        assert test_pins[name][0] == version, (
            f"{name}: drone {version}, tested {test_pins[name][0]}: run 'make lock'"
        )


def test_the_venv_was_installed_from_the_lock() -> None:
    """The interpreter running this suite holds exactly the locked versions."""
    if Path(sys.prefix).name != ".venv":
        pytest.skip(
            f"not the locked venv ({sys.prefix}); make test-latest runs unlocked on purpose"
        )
    wrong = []
    for name, (version, _) in _locked(TEST_LOCK).items():
        try:
            installed = metadata.version(name)
        except metadata.PackageNotFoundError:
            wrong.append(f"{name} missing")
            continue
        if installed != version:
            wrong.append(f"{name} {installed} (lock {version})")
    assert not wrong, "venv differs from requirements/test.lock: " + ", ".join(wrong)


def test_a_jetson_can_install_every_locked_runtime_package(tmp_path: Path) -> None:
    """pip fetches an aarch64 manylinux2014 (glibc 2.17) or pure-Python wheel of each
    locked runtime package, hashes checked: no sdist, no build on the drone."""
    done = subprocess.run(
        [
            sys.executable, "-m", "pip", "download", "--quiet", "--disable-pip-version-check",
            "--no-deps", "--only-binary=:all:", "--require-hashes",
            "--platform", "manylinux2014_aarch64", "--python-version", "3.11",
            "--implementation", "cp", "--abi", "cp311", "--abi", "abi3", "--abi", "none",
            "-r", str(RUNTIME_LOCK), "-d", str(tmp_path),
        ],
        capture_output=True, text=True, timeout=600, check=False,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-2000:]
    wheels = sorted(p.name for p in tmp_path.glob("*.whl"))
    assert len(wheels) == len(_locked(RUNTIME_LOCK)), wheels
    for wheel in wheels:
        tags = wheel.removesuffix(".whl").split("-")[-1]
        # pip accepts only tags manylinux2014 (glibc 2.17) covers for that --platform
        assert tags == "any" or "aarch64" in tags, wheel
