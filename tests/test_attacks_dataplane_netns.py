"""Issue 10's attacks on the data plane and commands (docs/security.md, "Attack tests",
attacks 1, 2, the readiness row of 3, and 5), each from a host on the swarm's LAN that is not
in the bundle: forged commands, forged reliable-protocol state, a forged readiness sample,
and a captured TAKEOFF replayed after a member lost its state file.

The swarm, the attacker, the three things every test asserts and the rules they share are
``tests/attacker/lab.py``'s. Seen failing against main before the defences (f0f3378) for the
attack's own reason: a forged TAKEOFF executed, a member's reader locked out, a readiness
row pinned at report_stale, a replayed TAKEOFF run.
"""

from __future__ import annotations

import subprocess
import time
from collections.abc import Callable, Mapping, Sequence

import pytest

from swarmd.bundle.model import EndpointKind
from swarmd.dataplane.types import CommandKind, Readiness
from tests.attacker import forge
from tests.attacker.lab import (
    ATTACKER_PAIR_KEY,
    COMMAND,
    DP,
    LEAD,
    M1,
    M2,
    READY,
    Lab,
    settle,
)
from tests.attacker.swarm import BIN, FlashedSwarm, until

pytestmark = [pytest.mark.netns]


# -- 1. commands as the commander ---------------------------------------------------------


def test_forged_commands_as_commander_refused(lab: Lab) -> None:
    """TAKEOFF, HOLD, LAND, ABORT as the commander to a member, each twice: without an
    authenticator, and with one under the attacker's own key whose epochs (public, from
    SPDP) and sequence pass every cheap check, so only the tag refuses it."""
    sw, atk = lab.swarm, lab.attacker
    lead, member = lab.prefix(LEAD), lab.prefix(M1)
    writer = sw.endpoint(COMMAND, EndpointKind.WRITER)
    reader = sw.endpoint(COMMAND, EndpointKind.READER)
    before, vehicle = lab.refusals(), lab.vehicle_commands()
    executed_before = sw.status(M1)["executor"]["counters"]
    kinds = [CommandKind.TAKEOFF, CommandKind.HOLD, CommandKind.LAND, CommandKind.ABORT]
    for k, kind in enumerate(kinds):
        sample = forge.command(kind, k, targets=[sw.names[M1]])
        bare = forge.forged_command(
            lead, member, writer=writer, reader=reader, sn=forge.JUMP_SN + k, sample=sample
        )
        atk.send(bare, sw.user_addr(M1))
        mac = forge.mac(
            bare,
            pair_key=ATTACKER_PAIR_KEY,
            freshness=lab.fresh(LEAD),
            receiver=member,
            receiver_epoch=lab.epoch(M1),
        )
        atk.send(mac, sw.user_addr(M1))
        time.sleep(0.3)

    def effect() -> bool:
        return bool(sw.status(M1)["executor"]["counters"] != executed_before)

    settle(lambda: effect() or lab.moved(before, M1, DP + "dropped_auth_failed") >= len(kinds))
    assert not effect(), f"{sw.names[M1]} executed forged commands: {sw.status(M1)['executor']}"
    assert lab.moved(before, M1, DP + "dropped_auth_missing") >= len(kinds), lab.refused_since(
        before, M1
    )
    assert lab.moved(before, M1, DP + "dropped_auth_failed") >= len(kinds), lab.refused_since(
        before, M1
    )
    assert lab.vehicle_commands() == vehicle
    lab.assert_commander_commands_all()


def test_captured_member_cannot_impersonate_commander_or_member(lab: Lab) -> None:
    """The attacker holds drone-1's flashed node.key (a captured drone). With it: a TAKEOFF
    to drone-2 claiming the commander (MAC'd with drone-1's real key with drone-2), the same
    claiming drone-1 itself (authentic, but drone-1 commands nobody), and a dispose of
    drone-2 signed with drone-1's real Ed25519 key. All refused."""
    sw, atk = lab.swarm, lab.attacker
    captured = lab.captured(M1)
    victim = lab.prefix(M2)
    pair_key = captured.pair_key(victim)
    assert pair_key is not None
    writer = sw.endpoint(COMMAND, EndpointKind.WRITER)
    reader = sw.endpoint(COMMAND, EndpointKind.READER)
    before, vehicle = lab.refusals(), lab.vehicle_commands()
    executed_before = sw.status(M2)["executor"]["counters"]
    sample = forge.command(CommandKind.TAKEOFF, 100, targets=[sw.names[M2]])
    for claimed, index in ((lab.prefix(LEAD), LEAD), (lab.prefix(M1), M1)):
        bare = forge.forged_command(
            claimed, victim, writer=writer, reader=reader, sn=forge.JUMP_SN, sample=sample
        )
        atk.send(
            forge.mac(
                bare,
                pair_key=pair_key,
                freshness=lab.fresh(index),
                receiver=victim,
                receiver_epoch=lab.epoch(M2),
            ),
            sw.user_addr(M2),
        )
    dispose = forge.signed_dispose(victim, lab.sn(), lab.fresh(M2), captured)
    atk.multicast(dispose)
    lost_before = len(sw.log_events(LEAD, "peer_lost"))

    def effect() -> bool:
        return bool(sw.status(M2)["executor"]["counters"] != executed_before)

    settle(lambda: effect() or lab.forged(before, LEAD) >= 1)
    assert not effect(), sw.status(M2)["executor"]
    assert lab.moved(before, M2, DP + "dropped_auth_failed") >= 1, lab.refused_since(before, M2)
    assert sum(lab.refused_since(before, M2).values()) >= 2, lab.refused_since(before, M2)
    assert lab.forged(before, LEAD) >= 1, lab.refused_since(before, LEAD)
    assert sw.log_events(LEAD, "peer_lost")[lost_before:] == []
    assert lab.vehicle_commands() == vehicle
    lab.assert_commander_commands_all()


# -- 2. reliable-protocol state: HEARTBEAT jump, GAP, ACKNACK -------------------------------


def _command_reader_forgery_refused(
    lab: Lab, member: int, forger: Callable[..., bytes], rounds: Sequence[Mapping[str, int]]
) -> None:
    """One forged submessage per round, ``forger(commander, member, writer=, reader=,
    **round)`` on the command topic, sent to ``member``: each is dropped unauthenticated and
    the reader has not moved (the real commander's commands still arrive)."""
    sw = lab.swarm
    writer = sw.endpoint(COMMAND, EndpointKind.WRITER)
    reader = sw.endpoint(COMMAND, EndpointKind.READER)
    before = lab.refusals()
    for fields in rounds:
        datagram = forger(
            lab.prefix(LEAD), lab.prefix(member), writer=writer, reader=reader, **fields
        )
        lab.attacker.send(datagram, sw.user_addr(member))
    n = len(rounds)
    settle(lambda: lab.moved(before, member, DP + "dropped_auth_missing") >= n)
    lab.assert_commander_commands_all()
    moved = lab.moved(before, member, DP + "dropped_auth_missing")
    assert moved >= n, lab.refused_since(before, member)


def test_forged_heartbeat_jump_refused(lab: Lab) -> None:
    """A HEARTBEAT moving the reader's position far ahead: refused, nothing skipped."""
    jump = {"first": forge.JUMP_SN, "last": forge.JUMP_SN}
    rounds = [{**jump, "count": 1_000_000 + k} for k in range(3)]
    _command_reader_forgery_refused(lab, M1, forge.forged_heartbeat, rounds)


def test_forged_gap_refused(lab: Lab) -> None:
    """A GAP marking every SN below the jump irrelevant: refused, nothing marked."""
    rounds = [{"start": 1, "end": forge.JUMP_SN}] * 3
    _command_reader_forgery_refused(lab, M2, forge.forged_gap, rounds)


def _block_user_data(sw: FlashedSwarm, i: int, source: str) -> None:
    """nftables in drone i: drop user data from ``source`` (the path a repair must cross)."""
    port = sw.user_addr(i)[1]
    ruleset = f"""\
table inet atk_block {{
  chain input {{
    type filter hook input priority 0; policy accept;
    ip saddr {source} udp dport {port} counter drop
  }}
}}
"""
    subprocess.run(  # noqa: S603 - fixed argv, ruleset on stdin
        sw.lan[i].command(["nft", "-f", "-"]), input=ruleset, text=True, check=True, timeout=10
    )


def _unblock(sw: FlashedSwarm, i: int) -> None:
    sw.lan[i].run(["nft", "delete", "table", "inet", "atk_block"], check=False)


def test_forged_acknack_refused(lab: Lab) -> None:
    """A command is lost on its way to a member; a forged ACKNACK "from" that member says
    it arrived. Refused, the commander keeps repairing and the member gets it."""
    sw, atk = lab.swarm, lab.attacker
    before = lab.refusals()
    _block_user_data(sw, M1, sw.lan[LEAD].address)
    try:
        hold = subprocess.Popen(  # noqa: S603 - our own console script
            sw.lan[LEAD].command(
                [
                    str(BIN / "swarmctl"),
                    "hold",
                    "--only",
                    sw.names[M1],
                    "--timeout",
                    "20",
                    "--json",
                    "--socket",
                    sw.sock(LEAD),
                ]  # fmt: skip
            ),
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        until(lambda: bool(sw.status(LEAD)["commands"]), lambda: sw.status(LEAD)["commands"], 20)
        last_sn = sw.status(LEAD)["dataplane"]["writers"][COMMAND]["last_sn"]
        for count in range(5):
            atk.send(
                forge.forged_acknack(
                    lab.prefix(M1),
                    lab.prefix(LEAD),
                    writer=sw.endpoint(COMMAND, EndpointKind.WRITER),
                    reader=sw.endpoint(COMMAND, EndpointKind.READER),
                    base=last_sn + 1,
                    count=1_000_000 + count,
                ),
                sw.user_addr(LEAD),
            )
            time.sleep(0.2)
    finally:
        _unblock(sw, M1)
    out, err = hold.communicate(timeout=60)
    assert hold.returncode == 0, out + err
    assert lab.moved(before, LEAD, DP + "dropped_auth_missing") >= 5, lab.refused_since(
        before, LEAD
    )
    lab.assert_commander_commands_all()


# -- 3. readiness at a high SN -------------------------------------------------------------


def test_forged_readiness_high_sn_refused(lab: Lab) -> None:
    sw, atk = lab.swarm, lab.attacker
    before = lab.refusals()
    name = sw.names[M1]
    sample = Readiness(name, 1, True, "", False, 1, 3, 12, 90, 800)
    atk.send(
        forge.forged_readiness(
            lab.prefix(M1),
            lab.prefix(LEAD),
            writer=sw.endpoint(READY, EndpointKind.WRITER),
            reader=sw.endpoint(READY, EndpointKind.READER),
            sn=forge.JUMP_SN,
            sample=sample,
        ),
        sw.user_addr(LEAD),
    )

    def pinned() -> bool:
        return bool(sw.status(LEAD)["readiness"][name]["reason"] == "report_stale")

    # stale_after_s is 3 s in the shipped config: a pinned row shows it within 3-4 s
    settle(pinned, 6.0)
    row = sw.status(LEAD)["readiness"][name]
    assert row["ready"] and row["reason"] is None, row
    assert lab.moved(before, LEAD, DP + "dropped_auth_missing") >= 1, lab.refused_since(
        before, LEAD
    )
    lab.assert_commander_commands_all()


# -- 5. replay of a captured TAKEOFF after a member restarts without its state file --------


def test_replayed_takeoff_after_state_loss_refused(lab: Lab) -> None:
    sw, atk = lab.swarm, lab.attacker
    lab.dirty = True  # a drone flies, then restarts
    target = sw.user_addr(M2)
    t0 = time.monotonic()
    real = sw.swarmctl(LEAD, "takeoff", "--only", sw.names[M2], "--alt", "5", "--json")
    assert real.returncode == 0, real.stdout + real.stderr
    captured = atk.capture(t0, lambda c: c.dst == target and c.src[0] == sw.lan[LEAD].address)
    assert captured, "the attacker captured none of the take-off's datagrams"
    # the member loses its state file (new SD card) and its vehicle is on the ground again
    sw.stop(M2)
    sw.wipe_state(M2)
    sw.start(M2)
    until(
        lambda: (
            bool(sw.status(LEAD)["readiness"][sw.names[M2]]["ready"])
            and sw.status(LEAD)["readiness"][sw.names[M2]]["landed_state"] == "ON_GROUND"
        ),
        lambda: sw.status(LEAD)["readiness"],
    )
    before = lab.refusals()
    vehicle = lab.vehicle_commands()
    for c in captured:
        atk.send(c.payload, target)
        time.sleep(0.05)

    def executed() -> bool:
        return bool(sw.status(M2)["executor"]["counters"].get("received_takeoff", 0))

    # made for drone-2's previous life: refused on the receiver epoch, state file or not
    refusal = DP + "dropped_auth_receiver_epoch"
    settle(lambda: executed() or lab.moved(before, M2, refusal) >= len(captured))
    assert not executed(), sw.status(M2)["executor"]
    assert lab.vehicle_commands()[M2] == vehicle[M2]
    assert lab.moved(before, M2, refusal) >= len(captured), lab.refused_since(before, M2)
    lab.assert_commander_commands_all()
