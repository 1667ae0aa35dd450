"""The shared set-up of issue 10's attack tests (``tests/test_attacks_*_netns.py``).

The victim (``tests/attacker/swarm.py``): three real ``swarmd`` daemons in namespaces, a
real signed bundle flashed with ``swarmctl bundle flash``, the shipped
``config/swarmd.yaml`` values, and per drone a MAVLink vehicle SIMULATOR
(``swarmd-vehicle-sim``, not PX4). The attacker (``tests/attacker/host.py``) sniffs SPDP
from the real multicast group and everything else on the air, and forges with swarmd's own
codec (``tests/attacker/forge.py``). It holds no key.

Every attack test asserts the same three things:

1. the forged input is refused, and counted (a drop counter in ``status --json`` moves);
2. the vehicle simulator received nothing because of it (no MAVLink command, no state);
3. afterwards the real commander still commands every drone (``swarmctl hold`` completes).

Each test was written first as ``xfail(strict=True)`` naming the defence it waited for, and
seen failing against main before the defences (f0f3378) for the attack's own reason (each
module's docstring names them); the markers went when the defences landed. The two
fixtures below reach every attack module through ``pytest_plugins`` in tests/conftest.py
(named ``lab_module_fixture`` and ``lab_fixture``, so that a test's ``lab`` argument does
not shadow a function): ``lab_module``, one swarm per module, and ``lab``, which restarts
the swarm from the flashed files with no state after a test that left it damaged (any test
that did not pass, and the ones that fly). Every send loop and every wait is bounded.
"""

from __future__ import annotations

import json
import os
import random
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Final

import pytest
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey
from swarmd_lab.netns import Lan, list_namespaces, run_prefix

from swarmd.auth.freshness import Freshness
from swarmd.auth.keys import KeyRing, NodeSecrets
from swarmd.rtps.spdp import SpdpParticipant
from swarmd.rtps.types import GuidPrefix
from tests.attacker import forge
from tests.attacker.host import Attacker, Learned
from tests.attacker.swarm import PX4_LISTEN, FlashedSwarm, delta, refusals

LEAD, M1, M2 = 0, 1, 2  # drone indices: the commander and the two members
COMMAND: Final = "swarm/command"
READY: Final = "swarm/ready"
SETTLE_S: Final = 4.0  # how long a refused attack is given to show an effect anyway
HOLD_TIMEOUT_S: Final = 10.0
PX4_PORT: Final = int(PX4_LISTEN.rpartition(":")[2])  # the shipped config's (540)


class Lab:
    """The shared swarm and the attacker; ``dirty`` = restart the swarm after this test."""

    def __init__(self, swarm: FlashedSwarm, attacker: Attacker) -> None:
        self.swarm = swarm
        self.attacker = attacker
        self.dirty = False
        self._sn = 10_000

    def sn(self) -> int:
        """A fresh SPDP sequence number, above anything the real daemons reach in a test."""
        self._sn += 1
        return self._sn

    def prefix(self, i: int) -> GuidPrefix:
        """Drone i's GUID prefix, as the attacker learned it from SPDP."""
        name = self.swarm.names[i]
        # generous: a daemon on a loaded host may take a renewal period or two to speak
        self.attacker.wait_for(lambda: self.attacker.member(name) is not None, 60.0)
        learned = self.attacker.member(name)
        assert learned is not None, f"the attacker never heard {name}'s SPDP"
        return learned.participant.guid_prefix

    def refusals(self) -> list[dict[str, int]]:
        return [refusals(self.swarm.status(i)) for i in range(self.swarm.n)]

    def refused_since(self, before: list[dict[str, int]], i: int) -> dict[str, int]:
        return delta(refusals(self.swarm.status(i)), before[i])

    def moved(self, before: list[dict[str, int]], i: int, counter: str) -> int:
        """How much ``counter`` (a dotted ``status --json`` path) grew on drone i."""
        return self.refused_since(before, i).get(counter, 0)

    def assert_replays_and_resigns_refused(
        self, before: list[dict[str, int]], i: int, each: int
    ) -> None:
        """``each`` replays of a member's last sniffed authenticator and ``each`` re-signed
        copies were refused by drone i. A replay is ``auth_replayed`` if drone i heard that
        datagram, ``auth_bad_tag`` if it was a directed reply to another drone (no receiver
        tag for drone i); a vouched member sends no renewal, so which one the attacker last
        sniffed varies. The re-signed ones are forgeries (``forged``)."""
        replayed = self.moved(before, i, SPDP + "auth_replayed")
        bad_signature = self.forged(before, i)
        assert replayed + bad_signature >= 2 * each, self.refused_since(before, i)
        assert bad_signature >= each, self.refused_since(before, i)

    def forged(self, before: list[dict[str, int]], i: int) -> int:
        """Forgeries drone i refused: on its receiver tag (``auth_bad_tag``, issue 18: before
        any budget) or, without a tag for it, on the signature."""
        return self.moved(before, i, SPDP + "auth_bad_tag") + self.moved(
            before, i, SPDP + "auth_bad_signature"
        )

    def epoch(self, i: int) -> int:
        """Drone i's boot epoch, read from its SPDP authenticator on the air."""
        self.attacker.wait_for(
            lambda: (self.attacker.member(self.swarm.names[i]) or _NO).freshness is not None,
            60.0,
        )
        learned = self.attacker.member(self.swarm.names[i])
        assert learned is not None and learned.freshness is not None, "no SPDP authenticator"
        return learned.freshness.epoch

    def captured(self, i: int) -> KeyRing:
        """Drone i's keys as an attacker holding the drone would: its flashed node.key."""
        secrets = NodeSecrets.load(self.swarm.lib(i) / "node.key")
        return KeyRing.from_bundle(self.swarm.bundle, self.swarm.names[i], secrets)

    def fresh(self, i: int) -> Freshness:
        """A freshness claiming drone i's current epoch, far ahead of its real sequence."""
        self._sn += 1
        return Freshness(self.epoch(i), 1_000_000 + self._sn)

    def forged_alive_rounds(
        self, i: int, learned: Learned, unicast: tuple[str, int], metatraffic: tuple[str, int]
    ) -> None:
        """Three rounds, 0.3 s apart, of drone i's DATA(p) as ``learned`` naming these
        locators on the multicast group: replayed under its own authenticator, then
        re-signed with a fresh counter and the attacker's key."""
        for _ in range(3):
            for resign in (None, (self.fresh(i), ATTACKER_KEY)):
                forged = forge.forged_alive(
                    learned.participant, self.sn(), unicast=unicast, metatraffic=metatraffic,
                    resign=resign,
                )  # fmt: skip
                self.attacker.multicast(forged)
            time.sleep(0.3)

    def vehicle_commands(self) -> list[int]:
        """MAVLink commands each vehicle simulator has received so far."""
        return [len(self.swarm.sim_events(i, "command")) for i in range(self.swarm.n)]

    def assert_commander_commands_all(self) -> None:
        body = self.swarm.commands_all("hold", HOLD_TIMEOUT_S)
        nodes = body.get("nodes", {})
        states = {n: s.get("state") for n, s in nodes.items()}
        assert body["rc"] == 0 and states == dict.fromkeys(self.swarm.names, "completed"), body


_NO: Final = Learned(SpdpParticipant(GuidPrefix(bytes(12))), 0, "")
ATTACKER_KEY: Final = Ed25519PrivateKey.generate()  # the attacker's own: in no bundle
ATTACKER_PAIR_KEY: Final = bytes(random.Random(7).getrandbits(8) for _ in range(32))
DP: Final = "dataplane.counters."
SPDP: Final = "counters.dropped."


def settle(cond: Callable[[], bool], seconds: float = SETTLE_S) -> bool:
    """Poll ``cond`` for at most ``seconds``; True as soon as it holds."""
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        try:
            if cond():
                return True
        except (KeyError, TypeError):
            pass
        time.sleep(0.1)
    return False


@contextmanager
def attacked_swarm(prefix: str) -> Iterator[tuple[FlashedSwarm, Attacker]]:
    """A flashed swarm on a LAN of namespaces named ``prefix``-..., with an attacker host on
    it that listened from the swarm's start; the swarm, the attacker, the namespaces and the
    work folder are torn down on every exit path, and a leaked namespace fails the test.
    Shared by these attack modules and ``tests/test_attacks_spoof_netns.py``."""
    from tests.attacker.swarm import flashed_swarm

    root = Path(f"/tmp/{prefix}-{os.getpid()}")
    root.mkdir(parents=True, exist_ok=True)
    lan = Lan(4, prefix=run_prefix(prefix)).__enter__()
    try:
        with flashed_swarm(lan, root) as swarm:
            attacker = Attacker(swarm.attacker_ns, swarm.spdp_group).start()
            # the attacker listens from power-on, as one on the swarm's Wi-Fi can: vouched
            # members send no SPDP renewals (docs/discovery.md, "Vouching"), so one that
            # started listening later would learn a member only when it restarts
            swarm.reset()
            try:
                yield swarm, attacker
            finally:
                attacker.close()
    finally:
        lan.close()
        import shutil

        shutil.rmtree(root, ignore_errors=True)
        leaked = [n for n in list_namespaces() if n.startswith(lan.prefix + "-")]
        assert not leaked, f"network namespaces leaked: {leaked}"


@pytest.fixture(scope="module", name="lab_module")
def lab_module_fixture() -> Iterator[Lab]:
    with attacked_swarm("atk") as (swarm, attacker):
        yield Lab(swarm, attacker)


@pytest.fixture(name="lab")
def lab_fixture(lab_module: Lab, request: pytest.FixtureRequest) -> Iterator[Lab]:
    lab_module.dirty = False
    record = os.environ.get("SWARMD_ATTACK_RECORD")  # a JSON file: refusals moved per test
    before = lab_module.refusals() if record else []
    yield lab_module
    if record:
        path = Path(record)
        seen = json.loads(path.read_text()) if path.exists() else {}
        seen[request.node.name] = {
            lab_module.swarm.names[i]: lab_module.refused_since(before, i)
            for i in range(lab_module.swarm.n)
        }
        path.write_text(json.dumps(seen, indent=2, sort_keys=True) + "\n")
    report = getattr(request.node, "rep_call", None)
    if report is None:
        # no report: Ctrl-C cut the test short (pytest makes none for an interrupted call)
        # and the module's teardown removes the swarm next; restarting it here (daemons
        # started, convergence awaited) only kept the developer waiting (tests/interrupt.py)
        return
    passed = report.passed and not hasattr(report, "wasxfail")
    if lab_module.dirty or not passed:
        lab_module.swarm.reset()
