"""Mission files: the examples load; every kind of bad input is one line naming file, line,
field and fix (issue 3, "Bad input"), and nothing is written."""

from __future__ import annotations

from pathlib import Path

import pytest

from swarmd.bundle.errors import MissionError
from swarmd.bundle.mission import load_mission, parse_mission
from swarmd.bundle.model import Durability, Reliability, Role
from swarmd.cli.swarmctl import main as swarmctl
from swarmd.exitcodes import EX_DATAERR
from swarmd.rtps.ports import max_participant_index

REPO = Path(__file__).resolve().parent.parent
MISSIONS = REPO / "firmware_bundle" / "missions"

GOOD = """\
swarm: t3
domain_id: 0
participants:
  - {name: lead, index: 0, role: commander, mavlink_sysid: 1}
  - {name: d1, index: 1, role: member, mavlink_sysid: 2, ipv4: 10.0.0.2}
  - {name: d2, index: 2, role: member, mavlink_sysid: 3}
topics:
  - name: swarm/ready
    type: swarmd::Readiness
    writers: member
    readers: commander
  - name: swarm/command
    type: swarmd::Command
    reliability: reliable
    history_depth: 8
    writers: commander
    readers: member
"""


def test_good_mission_parses_with_defaults_and_resolved_selectors() -> None:
    m = parse_mission(GOOD, "good.yaml")
    assert m.swarm == "t3"
    assert [p.name for p in m.participants] == ["lead", "d1", "d2"]
    assert m.participants[0].role is Role.COMMANDER
    assert m.participants[1].ipv4 == "10.0.0.2"
    assert m.participants[2].ipv4 is None
    ready, command = m.topics
    assert ready.writers == ("d1", "d2") and ready.readers == ("lead",)
    assert ready.qos.reliability is Reliability.BEST_EFFORT
    assert ready.qos.durability is Durability.VOLATILE and ready.qos.history_depth == 1
    assert command.qos.reliability is Reliability.RELIABLE and command.qos.history_depth == 8
    assert command.writers == ("lead",) and command.readers == ("d1", "d2")
    assert (m.discovery.t_min_s, m.discovery.t_max_s, m.discovery.lease_s) == (8.0, 20.0, 20.0)


@pytest.mark.parametrize(("name", "size"), [("swarm3", 3), ("swarm10", 10), ("swarm50", 50)])
def test_example_missions_load(name: str, size: int) -> None:
    m = load_mission(MISSIONS / f"{name}.yaml")
    assert len(m.participants) == size
    topics = {t.name: t for t in m.topics}
    # the two topics the product uses (design: member -> commander, commander -> members)
    ready, command = topics["swarm/ready"], topics["swarm/command"]
    assert ready.type_name == "swarmd::Readiness"
    assert ready.qos.reliability is Reliability.BEST_EFFORT and ready.qos.history_depth == 1
    assert command.type_name == "swarmd::Command"
    assert command.qos.reliability is Reliability.RELIABLE
    roles = {p.name: p.role for p in m.participants}
    assert all(roles[n] is Role.MEMBER for n in ready.writers)
    assert all(roles[n] is Role.COMMANDER for n in ready.readers)
    assert all(roles[n] is Role.COMMANDER for n in command.writers)


def _replace(old: str, new: str) -> str:
    assert old in GOOD, old
    return GOOD.replace(old, new, 1)


TOP = max_participant_index(0)

BAD = [
    pytest.param("swarm: [unclosed\n", 2, "<yaml>", "malformed YAML", id="malformed-yaml"),
    pytest.param(
        _replace("  - {name: d2,", "  - {name: d1,"),
        6,
        "participants[2].name",
        "duplicate participant name 'd1'",
        id="duplicate-name",
    ),
    pytest.param(
        _replace("d2, index: 2", "d2, index: 1"),
        6,
        "participants[2].index",
        "duplicate participant index 1",
        id="duplicate-index",
    ),
    pytest.param(
        _replace("d2, index: 2, role: member", "d2, index: 2, role: pilot"),
        6,
        "participants[2].role",
        "unknown value 'pilot'",
        id="unknown-role",
    ),
    pytest.param(
        _replace("    readers: commander\n", "    readers: d9\n"),
        11,
        "topics[0].readers",
        "'d9' is neither a role nor a participant name",
        id="unknown-reader",
    ),
    pytest.param(
        _replace(
            "  - {name: lead, index: 0, role: commander,",
            "  - {name: lead, index: 0, role: member,",
        ),
        11,
        "topics[0].readers",
        "read by nobody",
        id="topic-read-by-nobody",
    ),
    pytest.param(
        _replace("    writers: commander\n", "    writers: []\n"),
        16,
        "topics[1].writers",
        "written by nobody",
        id="topic-written-by-nobody",
    ),
    pytest.param(
        _replace("d2, index: 2", f"d2, index: {TOP + 1}"),
        6,
        "participants[2].index",
        "overflows the port range of domain 0",
        id="index-overflows-ports",
    ),
    pytest.param(
        _replace("domain_id: 0", "domain_id: 232").replace("d2, index: 2", "d2, index: 63"),
        6,
        "participants[2].index",
        "overflows the port range of domain 232 (its user unicast port would be 65537",
        id="index-overflows-ports-high-domain",
    ),
    pytest.param(
        _replace("type: swarmd::Readiness", "type: swarmd::Read-iness"),
        9,
        "topics[0].type",
        "not a valid DDS type name",
        id="bad-type-name",
    ),
    pytest.param(
        _replace("type: swarmd::Readiness", "type: 9swarmd::Readiness"),
        9,
        "topics[0].type",
        "not a valid DDS type name",
        id="type-name-leading-digit",
    ),
    pytest.param(
        _replace("  - name: swarm/ready", "  - name: swarm//ready"),
        8,
        "topics[0].name",
        "not a valid DDS topic name",
        id="bad-topic-name",
    ),
    pytest.param(
        _replace("  - name: swarm/command", "  - name: swarm/ready"),
        12,
        "topics[1].name",
        "duplicate topic",
        id="duplicate-topic",
    ),
    pytest.param(
        _replace("domain_id: 0", "domain_id: 500"),
        2,
        "domain_id",
        "outside 0..232",
        id="domain-out-of-range",
    ),
    pytest.param(
        _replace("mavlink_sysid: 3}", "mavlink_sysid: 2}"),
        6,
        "participants[2].mavlink_sysid",
        "duplicate MAVLink system id 2",
        id="duplicate-sysid",
    ),
    pytest.param(
        _replace("ipv4: 10.0.0.2", "ipv4: 10.0.0.300"),
        5,
        "participants[1].ipv4",
        "not an IPv4 address",
        id="bad-ipv4",
    ),
    pytest.param(
        _replace("    history_depth: 8\n", "    history_depth: 0\n"),
        15,
        "topics[1].history_depth",
        "0 is outside",
        id="history-depth-zero",
    ),
    pytest.param(
        _replace("    history_depth: 8\n", "    histroy_depth: 8\n"),
        15,
        "topics[1].histroy_depth",
        "unknown field 'histroy_depth'",
        id="misspelt-field",
    ),
    pytest.param(
        _replace("swarm: t3\n", "swarm: t3\nswarm: t4\n"),
        2,
        "swarm",
        "duplicate key",
        id="duplicate-yaml-key",
    ),
    pytest.param(
        _replace("domain_id: 0\n", "domain_id: 0\ndiscovery: {t_min_s: 30, t_max_s: 10}\n"),
        3,
        "discovery.t_max_s",
        "Tmax 10.0 s is below Tmin 30.0 s",
        id="tmax-below-tmin",
    ),
    pytest.param(
        _replace("mavlink_sysid: 1}", "mavlink_sysid: true}"),
        4,
        "participants[0].mavlink_sysid",
        "expected an integer, got True",
        id="bool-is-not-int",
    ),
    pytest.param(
        _replace("{name: d2,", "{name: all,"),
        6,
        "participants[2].name",
        "reserved",
        id="reserved-name",
    ),
    pytest.param(
        _replace("swarm: t3\n", ""),
        1,
        "swarm",
        "missing required field",
        id="missing-swarm",
    ),
    pytest.param("", 1, "<document>", "empty", id="empty-file"),
    pytest.param("- a\n- b\n", 1, "<top>", "expected a mapping", id="top-is-a-list"),
]


@pytest.mark.parametrize(("text", "line", "field", "problem"), BAD)
def test_bad_mission_is_one_line_with_file_line_field_and_fix(
    text: str, line: int, field: str, problem: str
) -> None:
    with pytest.raises(MissionError) as info:
        parse_mission(text, "m.yaml")
    err = info.value
    message = str(err)
    assert "\n" not in message
    assert message.startswith(f"m.yaml:{line}: field {field}: "), message
    assert problem in message
    assert "; fix: " in message and err.fix


def test_cli_rejects_bad_mission_with_exit_65_before_writing(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    mission = tmp_path / "bad.yaml"
    mission.write_text(_replace("d2, index: 2", "d2, index: 1"))
    out = tmp_path / "out.swb"
    code = swarmctl(["bundle", "build", str(mission), "-o", str(out), "--unsigned-dev"])
    assert code == EX_DATAERR
    err = capsys.readouterr().err.strip()
    assert err == (
        f"swarmctl: {mission}:6: field participants[2].index: duplicate participant index 1 "
        "(also 'd1'); fix: give every participant a unique index"
    )
    assert list(tmp_path.iterdir()) == [mission]


def test_missing_mission_file_is_one_line(capsys: pytest.CaptureFixture[str]) -> None:
    code = swarmctl(
        ["bundle", "build", "/nonexistent/m.yaml", "-o", "/tmp/x.swb", "--unsigned-dev"]
    )
    assert code == EX_DATAERR
    assert (
        capsys.readouterr()
        .err.strip()
        .startswith("swarmctl: /nonexistent/m.yaml: field -: file not found")
    )
