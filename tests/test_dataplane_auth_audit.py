"""User data the issue implies but its first tests did not try (issue 10 audit): a genuine
datagram the commander sealed for one member, captured and replayed to another member."""

from __future__ import annotations

from swarmd.dataplane import CommandReceived
from swarmd.rtps import Data, Heartbeat
from tests.test_dataplane_auth import (
    CMD_R,
    CMD_W,
    assert_refused,
    deliver,
    flying_swarm,
    next_sn,
    sealed,
    still_commands,
    takeoff_payload,
)
from tests.test_dataplane_swarm import Swarm


def _replay() -> tuple[Swarm, bytes]:
    """A flying swarm and the commander's next TAKEOFF to m01, sealed as lead seals it."""
    swarm = flying_swarm()
    lead = swarm.bundle.participant("lead")
    # both members expect the same next SN: the replay is otherwise exactly what m02 wants
    sn = next_sn(swarm, "m01")
    assert next_sn(swarm, "m02") == sn
    subs = (
        Data(CMD_R, CMD_W, sn, None, takeoff_payload(swarm)),
        Heartbeat(CMD_R, CMD_W, sn, sn, 1000),
    )
    return swarm, sealed(swarm, "lead", lead, "m01", *subs, seq=10_000)


def test_a_takeoff_sealed_for_one_member_is_refused_by_another() -> None:
    swarm, for_m01 = _replay()
    # the pair key and the receiver's prefix are in the tag: m02 cannot accept it
    assert_refused(swarm, "m02", for_m01, "auth_failed")
    still_commands(swarm)


def test_control_the_same_datagram_is_executed_by_the_member_it_was_sealed_for() -> None:
    swarm, for_m01 = _replay()
    events = deliver(swarm, "m01", for_m01)
    assert any(isinstance(e, CommandReceived) for e in events), events
