"""The engine split by concern (issue 20, style.md rule 19): the state copied between concerns
stays in step, every concern keeps its state in slots, and no module grows back past ~800
lines. The behaviour itself is pinned by the other discovery tests and by the simulator's
byte-identical output (docs/simulator.md, "Issue 20")."""

from __future__ import annotations

import random
from pathlib import Path

import pytest
from swarmd_lab.testing import build_swarm, make_bundle, node_ipv4

import swarmd.discovery as discovery_package
from swarmd.discovery.config import EngineConfig
from swarmd.discovery.debts import Debts
from swarmd.discovery.engine import DiscoveryEngine
from swarmd.discovery.foreign import ForeignParticipants
from swarmd.discovery.leases import Leases
from swarmd.discovery.phases import Phase
from swarmd.discovery.receive import ReceivePath
from swarmd.discovery.renewals import Renewals
from swarmd.discovery.sending import Sender

MAX_MODULE_LINES = 800  # style.md: "Around 800 lines, a module is asking to be split"


def _phase_copies(engine: DiscoveryEngine) -> tuple[Phase, bool, bool]:
    # the receive path's and the debts' view of the phase (set by DiscoveryEngine._transition)
    debts = engine._debts  # noqa: SLF001 - the copies under test are private by design
    return engine._receive.phase, debts.announcing, debts.silent  # noqa: SLF001


def _expected(phase: Phase) -> tuple[Phase, bool, bool]:
    return phase, phase in (Phase.ANNOUNCE, Phase.STEADY), phase in (Phase.BOOT, Phase.PASSIVE)


def test_the_phase_copies_follow_every_transition() -> None:
    swarm = build_swarm(6, seed=3)
    seen: set[Phase] = set()
    mismatches: list[tuple[int, float, Phase]] = []

    def check(node_id: int, now: float) -> None:
        for i, engine in enumerate(swarm.engines):
            seen.add(engine.phase)
            if _phase_copies(engine) != _expected(engine.phase):
                mismatches.append((i, now, engine.phase))

    swarm.net.after_input = check
    swarm.run_until(40.0)
    for engine in swarm.engines:
        engine.shutdown(40.0)
    check(-1, 40.0)
    assert {Phase.PASSIVE, Phase.ANNOUNCE, Phase.STEADY, Phase.STOPPED} <= seen
    assert mismatches == []


def test_an_engine_without_a_link_sample_starts_in_boot_silent() -> None:
    bundle = make_bundle(3)
    engine = DiscoveryEngine(
        bundle,
        bundle.participants[1].name,
        config=EngineConfig(),
        rng=random.Random(1),  # noqa: S311 - a seeded test
        now=0.0,
        local_ipv4=node_ipv4(1),
    )
    assert engine.phase is Phase.BOOT
    assert _phase_copies(engine) == _expected(Phase.BOOT)


@pytest.mark.parametrize(
    "concern", [Debts, ForeignParticipants, Leases, ReceivePath, Renewals, Sender]
)
def test_every_concern_keeps_its_state_in_slots(concern: type) -> None:
    # no instance dict: a misspelt attribute cannot silently become new state, and the
    # receive path reads slots (docs/discovery.md, "Cost per datagram")
    assert "__slots__" in vars(concern)
    assert "__dict__" not in {name for klass in concern.__mro__ for name in vars(klass)}


def test_no_discovery_module_is_past_800_lines() -> None:
    folder = Path(discovery_package.__file__).parent
    lengths = {p.name: len(p.read_text().splitlines()) for p in folder.glob("*.py")}
    assert "engine.py" in lengths
    assert {name: n for name, n in lengths.items() if n > MAX_MODULE_LINES} == {}
