"""Shared fixtures.

netns: ``lan_factory`` builds isolated LANs of network namespaces (``swarmd_lab.netns.Lan``)
and removes them after the test, failing the test if any namespace leaked; tests that
use it carry ``@pytest.mark.netns`` and are skipped, with the reason, when not root or
without iproute2. ``cyclone_factory`` starts stock Cyclone DDS participants in them.

bundles: ``keys`` is a swarm3 keys directory made by ``swarmctl bundle keygen``.

attacks: ``lab_module`` and ``lab`` come from ``tests/attacker/lab.py`` (``pytest_plugins``).
"""

from __future__ import annotations

import os
import shutil
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from swarmd_lab.netns import Lan, Namespace, cleanup_dead_runs, list_namespaces, unavailable_reason

from tests.daemon_support import SWARM3, bundle_cli
from tests.peers.cyclone import CyclonePeer

# the attack tests' fixtures (``lab_module``: one attacked swarm per module; ``lab``: it,
# restarted after a test that damaged it), found by pytest for every module that asks for
# them instead of imported into each (tests/attacker/lab.py)
pytest_plugins = ["tests.attacker.lab", "tests.interrupt"]

LanFactory = Callable[..., Lan]
CycloneFactory = Callable[[Namespace], CyclonePeer]


def pytest_runtest_setup(item: pytest.Item) -> None:
    if item.get_closest_marker("netns") is not None:
        reason = unavailable_reason()
        if reason is not None:
            pytest.skip(reason)


# the name bases of the suite's namespaces: ``Lan``'s default and the attack swarms'
# (tests/attacker/lab.py); never ``swf``, the Wi-Fi testbed's, which a benchmark may hold
SUITE_BASES = ("swn", "atk", "spf")


def sweep_dead_runs() -> list[str]:
    """Remove the suite's namespaces left by killed earlier runs (only those whose creating
    process is gone); return their names."""
    return [name for base in SUITE_BASES for name in cleanup_dead_runs(base)]


@pytest.fixture(scope="session", autouse=True)
def _sweep_dead_namespaces() -> None:
    if unavailable_reason() is None:
        sweep_dead_runs()


@pytest.fixture
def lan_factory(workdir: Path) -> Iterator[LanFactory]:
    """``make(n, subnet=None) -> Lan``: an entered LAN of n hosts, closed after the test.

    It asks for ``workdir`` so that pytest, which tears fixtures down in the reverse order,
    closes the LAN (SIGTERM to its daemons, which write their replay windows into the
    workdir as they stop) before the workdir is removed. Before, a test that named
    ``lan_factory`` first left its workdir behind with those files in it (hundreds of
    ``/tmp/swt-*`` directories holding only ``auth-windows-*``)."""
    lans: list[Lan] = []

    def make(size: int, subnet: str | None = None) -> Lan:
        lan = Lan(size, subnet=subnet)
        lans.append(lan)
        return lan.__enter__()

    yield make
    for lan in reversed(lans):
        lan.close()
    leaked = [n for n in list_namespaces() for lan in lans if n.startswith(lan.prefix + "-")]
    assert not leaked, f"network namespaces leaked: {leaked}"


@pytest.fixture
def lan2(lan_factory: LanFactory) -> Lan:
    """Two hosts on one bridge: ``lan2[0]`` (10.77.X.1) and ``lan2[1]`` (10.77.X.2)."""
    return lan_factory(2)


@pytest.fixture
def cyclone_factory(tmp_path: Path, lan_factory: LanFactory) -> Iterator[CycloneFactory]:
    """``start(ns) -> CyclonePeer``: a running stock Cyclone participant, stopped after the test.

    Depends on ``lan_factory`` so the peers stop (and send DATA(p[UD])) before the LAN goes.
    """
    peers: list[CyclonePeer] = []

    def start(ns: Namespace) -> CyclonePeer:
        peer = CyclonePeer(ns, tmp_path / f"cyclone-{len(peers)}.trace")
        peers.append(peer)
        return peer.start()

    yield start
    for peer in peers:
        peer.stop()


@pytest.fixture
def workdir(tmp_path: Path) -> Iterator[Path]:
    """A short scratch directory: AF_UNIX socket paths must stay under 108 bytes, and
    pytest's ``tmp_path`` can be longer."""
    short = Path(f"/tmp/swt-{os.getpid()}-{tmp_path.name[-24:]}")
    short.mkdir(parents=True, exist_ok=True)
    try:
        yield short
    finally:
        shutil.rmtree(short, ignore_errors=True)


@pytest.fixture
def keys(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> Path:
    """A keys directory for the swarm3 mission (``swarmctl bundle keygen``): the swarm's
    signing key and each node's keys (tests/test_bundle_cli.py, test_bundle_serial_guard.py)."""
    k = tmp_path / "keys"
    code, _, err = bundle_cli(capsys, "keygen", "--out", str(k), "--mission", str(SWARM3))
    assert code == 0, err
    return k


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item: pytest.Item, call: pytest.CallInfo[None]) -> Iterator[None]:
    """Keep each phase's report on the item (``item.rep_call``), so a fixture can tell after
    the test whether it passed (tests/attacker/lab.py restarts a damaged swarm)."""
    outcome = yield
    report = outcome.get_result()  # type: ignore[attr-defined]
    setattr(item, f"rep_{report.when}", report)
