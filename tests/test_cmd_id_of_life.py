"""A commander sends only its own life's command ids (docs/security.md, "A re-dated id";
docs/dataplane.md, "A life runs only its own commands").

A restarted commander has no record of its earlier lives' ids. Code in its process that
calls ``DataPlane.send_command`` with an old ``Command`` and a fresh echo of the member's
new life would pass both member rules (``another_life``: the echo names the member's
current epoch; ``issued_in_life``: the fresh echo dates the issue after the member's start),
and a member that lost its executed-id record would run it a second time. No ``swarmctl``
path does this (every request makes a new id), but the plane is the last place that knows
which ids are its own: it refuses to send an id that is not of its own life
(``epoch << 32 | counter`` with a counter it gave out) unless its own ``dated`` record
holds it. The refusal is an exception (``ForeignCommandId``, a ``ValueError``) before
anything moves: the caller is code in this process, a sending bug, and gets no SN it
could mistake for a command in flight; nothing goes on the air.

The attack: the restarted plane sends the earlier life's id with a fresh echo. The guards:
this life's ids are sent, and resent with their first dating, as before.
"""

from __future__ import annotations

import pytest

from swarmd.dataplane import TOPIC_COMMAND, Command, CommandKind, DataPlane
from swarmd.dataplane.types import TimeEcho
from tests.test_cmd_copies import _bundle
from tests.test_dataplane_swarm import make_plane

MEMBERS = ["m01", "m02"]


def _commander(epoch: int) -> DataPlane:
    lead = make_plane(_bundle(MEMBERS), "lead", epoch=epoch, incarnation=epoch - 1)
    for i, name in enumerate(MEMBERS):
        lead.peer_up(name, (f"10.1.0.{i + 1}", 7411), 0.0, epoch=3)
    return lead


def _fresh(targets: list[str]) -> list[TimeEcho]:
    """Echoes of the members' current life (epoch 3), as ``time_echoes`` would give."""
    return [TimeEcho(name, 1_000 + i, 100, 3) for i, name in enumerate(targets)]


def _last_sn(plane: DataPlane) -> int:
    sn: int = plane.status(0.0)["writers"][TOPIC_COMMAND]["last_sn"]
    return sn


def test_a_restarted_commander_refuses_to_send_an_earlier_lifes_id() -> None:
    earlier = _commander(epoch=1)
    old = earlier.make_command(
        CommandKind.TAKEOFF, altitude_m=5.0, targets=["m01"], valid_ms=30_000
    )
    assert old.command_id >> 32 == 1
    lead = _commander(epoch=2)  # the same node, restarted: no record of epoch 1's ids
    redated = Command(old.command_id, old.kind, 5.0, ["m01"], 30_000, _fresh(["m01"]))
    sn_before = _last_sn(lead)
    with pytest.raises(ValueError, match=str(old.command_id)):
        lead.send_command(redated, 1.0)
    assert lead.datagrams_to_send() == []  # nothing on the air
    assert _last_sn(lead) == sn_before  # no SN spent
    assert lead.counters["command_id_not_ours"] == 1
    # and a later honest command still goes out, with its own dating
    new = lead.make_command(
        CommandKind.LAND, targets=["m01"], valid_ms=5_000, echoes=_fresh(["m01"])
    )
    lead.send_command(new, 2.0)
    assert lead.datagrams_to_send()


def test_an_id_of_this_life_not_yet_made_is_refused() -> None:
    """An id ahead of the counter would be dated now, and the command ``make_command`` later
    gives that id would go out with this dating (and be a duplicate at every member)."""
    lead = _commander(epoch=2)
    ahead = Command(2 << 32 | 5, CommandKind.HOLD, 0.0, ["m02"], 5_000, _fresh(["m02"]))
    with pytest.raises(ValueError, match=str(ahead.command_id)):
        lead.send_command(ahead, 1.0)
    assert lead.datagrams_to_send() == []


def test_this_lifes_ids_are_sent_and_resent_with_their_first_dating() -> None:
    lead = _commander(epoch=2)
    first = lead.make_command(
        CommandKind.TAKEOFF,
        altitude_m=5.0,
        targets=MEMBERS,
        valid_ms=10_000,
        echoes=_fresh(MEMBERS),
    )
    lead.send_command(first, 1.0)
    assert lead.datagrams_to_send()
    later = Command(first.command_id, first.kind, 5.0, MEMBERS, 60_000, [])
    assert lead.dated(later).valid_ms == 10_000
    lead.send_command(later, 2.0)
    assert lead.datagrams_to_send()
    assert lead.counters["command_id_not_ours"] == 0
