"""The mission's ROS 2 graph (issue 19): checked with one-line errors, carried and signed in
the bundle with derived identities, and turned into Fast DDS profiles by ``swarmctl ros2
profile``. The real-process test is tests/test_ros2_netns.py."""

from __future__ import annotations

import json
import re
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from swarmd.bundle.build import build_dev_bundle
from swarmd.bundle.encoding import canonical_json, seal
from swarmd.bundle.errors import BundleError, MissionError
from swarmd.bundle.keys import dev_signing_key
from swarmd.bundle.loader import read_bundle
from swarmd.bundle.mission import parse_mission
from swarmd.bundle.ros2 import (
    GRAPH_TOPIC,
    MAX_NODE_ENDPOINTS,
    MAX_USER_ID,
    Ros2EndpointKind,
    Ros2Graph,
    Ros2Node,
    bundle_ros2_participants,
    node_endpoints,
)
from swarmd.cli.swarmctl import main as swarmctl
from swarmd.ros2.graph import MAX_DATAGRAM, encode_entities_info, entities_info, graph_reader_port
from swarmd.ros2.profile import ProfileError, drone_profiles
from swarmd.ros2.relay import Ros2Relay
from swarmd.rtps.spdp import encode_spdp

REPO = Path(__file__).resolve().parent.parent
MISSION = (REPO / "firmware_bundle" / "missions" / "swarm3-ros2.yaml").read_text()
PLAIN = (REPO / "firmware_bundle" / "missions" / "swarm3.yaml").read_text()
NS = "{http://www.eprosima.com}"


def _replace(old: str, new: str) -> str:
    assert old in MISSION
    return MISSION.replace(old, new)


def test_graph_round_trips_through_the_signed_bundle() -> None:
    built = build_dev_bundle(parse_mission(MISSION))
    loaded = read_bundle(built.data, allow_dev=True, require_anchor=False)
    assert loaded.ros2 == built.bundle.ros2
    assert loaded.ros2 is not None
    assert [n.drones for n in loaded.ros2.nodes] == [("drone-1", "drone-2"), ("lead",)]
    participants = bundle_ros2_participants(loaded)
    assert [(p.drone, p.node.name) for p in participants] == [
        ("lead", "listener"),
        ("drone-1", "talker"),
        ("drone-2", "talker"),
    ]
    # prefixes are unique and carry the drone index in Fast DDS's "host id" bytes
    assert len({p.guid_prefix for p in participants}) == 3
    assert [p.guid_prefix[2:4] for p in participants] == [b"\0\0", b"\0\1", b"\0\2"]
    # ROS 2 participant ids start above every swarmd index: no port swarmd uses on a drone
    swarm_ports = {loaded.metatraffic_port(p) for p in loaded.participants}
    swarm_ports |= {loaded.user_port(p) for p in loaded.participants}
    assert not swarm_ports & {p.metatraffic_port for p in participants}
    assert not swarm_ports & {p.user_port for p in participants}


def test_a_mission_without_ros2_keeps_its_bytes() -> None:
    body = json.loads(build_dev_bundle(parse_mission(PLAIN)).data[76:-64])
    assert "ros2" not in body


def test_forged_ros2_identities_are_refused_even_when_signed() -> None:
    """A signed body whose ROS 2 prefix is not the derived one (a buggy or hostile builder)
    fails the load, like a swarmd participant with a foreign prefix."""
    mission = parse_mission(MISSION)
    body = json.loads(build_dev_bundle(mission).data[76:-64])
    body["ros2"]["participants"][1]["guid_prefix"] = "010f00ffdeadbeef00000000"
    data = seal(canonical_json(body), dev_signing_key(mission.swarm), dev=True)
    with pytest.raises(BundleError, match="ros2"):
        read_bundle(data, allow_dev=True, require_anchor=False)


@pytest.mark.parametrize(
    ("old", "new", "field"),
    [
        ("type: std_msgs/msg/String", "type: std_msgs::String", "ros2.topics[0].type"),
        ("- name: /chatter", "- name: chatter", "ros2.topics[0].name"),
        ("- name: /chatter", "- name: /rosout", "ros2.topics[0].name"),
        ("publishes: [/chatter]", "publishes: [/chater]", "ros2.nodes[0].publishes"),
        ("serves: [/trigger]", "serves: [/chatter]", "ros2.nodes[0].serves"),
        ("drones: member", "drones: nobody", "ros2.nodes[0].drones"),
        ("- name: listener", "- name: talker", "ros2.nodes[1].name"),
        ("type: std_srvs/srv/Trigger", "type: std_srvs/msg/Trigger", "ros2.services[0].type"),
        ("  domain_id: 0\n  topics:", "  domain_id: 999\n  topics:", "ros2.domain_id"),
        ("      durability: volatile", "      durablity: volatile", "ros2.topics[0].durablity"),
    ],
)
def test_a_bad_graph_is_one_line_naming_the_field(old: str, new: str, field: str) -> None:
    with pytest.raises(MissionError) as info:
        parse_mission(_replace(old, new), "m.yaml")
    line = str(info.value)
    assert "\n" not in line
    assert "m.yaml:" in line and field in line and "fix:" in line


def big_mission(drones: int, publishes: int) -> str:
    """``drones`` drones (d0, d1, ...), each with one ROS 2 node ``n`` publishing
    ``publishes`` topics: its endpoints are these and ROS 2's own (``_BUILTIN``)."""
    participants = "\n".join(
        f"  - {{name: d{i}, index: {i}, role: member, mavlink_sysid: {i % 250 + 1}}}"
        for i in range(drones)
    )
    topics = "\n".join(
        f"    - {{name: /t{i}, type: std_msgs/msg/String}}" for i in range(publishes)
    )
    pubs = ", ".join(f"/t{i}" for i in range(publishes))
    return (
        f"swarm: big\ndomain_id: 0\nparticipants:\n{participants}\ntopics:\n"
        "  - {name: a, type: x::Y, writers: all, readers: all}\n"
        f"ros2:\n  topics:\n{topics}\n  nodes:\n"
        f"    - {{name: n, drones: all, publishes: [{pubs}]}}\n"
    )


def test_more_endpoints_than_static_ids_is_refused() -> None:
    with pytest.raises(MissionError, match=str(MAX_USER_ID)):
        parse_mission(big_mission(300, 120), "big.yaml")


def test_a_node_whose_announcement_would_not_fit_one_datagram_is_refused() -> None:
    """Review 18b: every datagram swarmd sends a node must fit Fast DDS's receive limit
    (``MAX_DATAGRAM``, 65,500 octets; no DATA_FRAG here). The largest per node is the
    relay's DATA(p) for it, 60 octets per endpoint: a node of ``MAX_NODE_ENDPOINTS`` at the
    highest user ids a bundle allows fits, one more endpoint is refused at build with one
    line naming the node."""
    builtin = len(node_endpoints(Ros2Graph(0, (), (), ()), Ros2Node("n", 0, (), (), (), (), ())))
    drones = MAX_USER_ID // MAX_NODE_ENDPOINTS  # the last drone's ids are above 31,000
    bundle = build_dev_bundle(
        parse_mission(big_mission(drones, MAX_NODE_ENDPOINTS - builtin))
    ).bundle
    participants = bundle_ros2_participants(bundle)
    last = participants[-1]
    assert len(last.endpoints) == MAX_NODE_ENDPOINTS and last.first_user_id > 31_000
    relay = Ros2Relay(participants, "d0", domain_id=0, lease_s=20.0)
    spdp = encode_spdp(relay.synthesized(last, "10.0.0.1"), sequence_number=1 << 40, timestamp=None)
    assert len(spdp) <= MAX_DATAGRAM
    assert len(encode_entities_info(entities_info(last))) < MAX_DATAGRAM // 4
    with pytest.raises(MissionError) as info:
        parse_mission(big_mission(3, MAX_NODE_ENDPOINTS - builtin + 1), "big.yaml")
    message = str(info.value)
    assert "\n" not in message and "ros2.nodes[0]" in message and "split" in message


def _profiles(drone: str, relay_port: int | None = None, mission: str = MISSION) -> dict[str, str]:
    bundle = build_dev_bundle(parse_mission(mission)).bundle
    assert bundle.ros2 is not None
    participants = bundle_ros2_participants(bundle)
    addresses = {p.name: p.ipv4 for p in bundle.participants if p.ipv4 is not None}
    files = drone_profiles(
        bundle.ros2, participants, addresses, drone, f"/etc/ros2/{drone}", relay_port=relay_port
    )
    return {f.path: f.text for f in files}


def test_via_swarmd_profile_keeps_discovery_on_ipv6_loopback() -> None:
    # two nodes on drone-1: they find each other on ::1, and the relay finds both
    two = _replace(
        "    - name: listener\n", "    - {name: helper, drones: [drone-1]}\n    - name: listener\n"
    )
    bundle = build_dev_bundle(parse_mission(two)).bundle
    mine = [p for p in bundle_ros2_participants(bundle) if p.drone == "drone-1"]
    assert [p.node.name for p in mine] == ["talker", "helper"]
    files = _profiles("drone-1", relay_port=7399, mission=two)
    root = ET.fromstring(files["drone-1/talker.xml"])  # noqa: S314 - our own generated text
    meta = next(root.iter(f"{NS}metatrafficUnicastLocatorList"))
    assert [e.text for e in meta.iter(f"{NS}address")] == ["::1"]
    assert next(meta.iter(f"{NS}udpv6")) is not None
    peers = next(root.iter(f"{NS}initialPeersList"))
    assert [
        (a.text, int(p.text or ""))
        for a, p in zip(peers.iter(f"{NS}address"), peers.iter(f"{NS}port"), strict=True)
    ] == [("::1", 7399), ("::1", mine[1].metatraffic_port)]
    # the UDPv6 transport is allowed on ::1 only: Fast DDS binds the discovery port there
    lo6 = [t for t in root.iter(f"{NS}transport_descriptor") if t.findtext(f"{NS}type") == "UDPv6"]
    assert [a.text for a in lo6[0].iter(f"{NS}address")] == ["::1"]
    # user data stays UDPv4 on the drone's address
    user = next(root.iter(f"{NS}defaultUnicastLocatorList"))
    assert [e.text for e in user.iter(f"{NS}address")] == ["10.42.0.11"]
    # every endpoint's entity id is its static id: the relay announces it from the bundle
    for endpoint in root.iter():
        if endpoint.tag in (f"{NS}data_writer", f"{NS}data_reader"):
            assert endpoint.findtext(f"{NS}entityID") == endpoint.findtext(f"{NS}userDefinedID")
    plain = _profiles("drone-1")["drone-1/talker.xml"]
    assert "::1" not in plain and "UDPv6" not in plain


def test_nodes_of_one_drone_are_one_host_and_separate_processes_to_fast_dds() -> None:
    """Fast DDS takes participants whose GUID prefixes share octets 0-7 for one process and
    delivers between them in memory, which two node processes cannot: no message would
    flow (tests/test_ros2_local_netns.py). Octets 0-3 (vendor, "host id") stay the drone's."""
    two = _replace(
        "    - name: listener\n", "    - {name: helper, drones: [drone-1]}\n    - name: listener\n"
    )
    participants = bundle_ros2_participants(build_dev_bundle(parse_mission(two)).bundle)
    mine = [p.guid_prefix for p in participants if p.drone == "drone-1"]
    assert len(mine) == 2
    assert mine[0][:4] == mine[1][:4]
    assert mine[0][:8] != mine[1][:8]
    assert len({p.guid_prefix[:8] for p in participants}) == len(participants)


def test_graph_readers_are_listed_at_their_unique_flow_port_on_the_relay_route() -> None:
    """rmw's graph reader listens on its own port (``graph_reader_port``, set by the relay
    profile's portBase), not the user port: the static file points there on the relay route,
    so the nodes of one drone get each other's graph samples."""
    two = _replace(
        "    - name: listener\n", "    - {name: helper, drones: [drone-1]}\n    - name: listener\n"
    )
    participants = bundle_ros2_participants(build_dev_bundle(parse_mission(two)).bundle)

    def reader_ports(text: str) -> dict[int, int]:
        root = ET.fromstring(text)  # noqa: S314 - our own generated text
        out = {}
        for r in root.iter("reader"):
            locator = r.find("unicastLocator")
            if r.findtext("topicName") == GRAPH_TOPIC and locator is not None:
                out[int(r.findtext("userId") or "")] = int(locator.get("port") or "")
        return out

    relay = reader_ports(
        _profiles("drone-1", relay_port=7399, mission=two)["drone-1/static-edp.xml"]
    )
    plain = reader_ports(_profiles("drone-1", mission=two)["drone-1/static-edp.xml"])
    for p in participants:
        uid = next(
            p.first_user_id + i
            for i, e in enumerate(p.endpoints)
            if e.dds_topic == GRAPH_TOPIC and e.kind == Ros2EndpointKind.READER
        )
        assert relay[uid] == graph_reader_port(p, participants)
        assert plain[uid] == p.user_port
    assert sorted({relay[u] for u in relay}) == [6998, 6999]


def test_static_edp_ids_are_unique_and_every_profile_id_is_listed() -> None:
    static = ET.fromstring(_profiles("lead")["lead/static-edp.xml"])  # noqa: S314 - ours
    ids = [int(e.text or "") for e in static.iter("userId")]
    assert len(ids) == len(set(ids)) and min(ids) >= 1 and max(ids) <= MAX_USER_ID
    for drone, node in (("lead", "listener"), ("drone-1", "talker"), ("drone-2", "talker")):
        profile = ET.fromstring(_profiles(drone)[f"{drone}/{node}.xml"])  # noqa: S314
        own = [int(e.text or "") for e in profile.iter(f"{NS}userDefinedID")]
        assert own and set(own) <= set(ids)
        # ROS 2's own endpoints have ids too: without one static EDP never matches them
        names = {e.get("profile_name") for e in profile.iter() if e.get("profile_name")}
        assert {"ros_discovery_info", "/parameter_events", "/rosout"} <= names


def test_participant_profile_is_unicast_only_with_the_bundle_prefix() -> None:
    bundle = build_dev_bundle(parse_mission(MISSION)).bundle
    me = next(p for p in bundle_ros2_participants(bundle) if p.drone == "drone-1")
    text = _profiles("drone-1")["drone-1/talker.xml"]
    root = ET.fromstring(text)  # noqa: S314 - our own generated text
    prefix = next(root.iter(f"{NS}prefix")).text or ""
    assert bytes.fromhex(prefix.replace(".", "")) == me.guid_prefix
    assert next(root.iter(f"{NS}EDP")).text == "STATIC"
    assert next(root.iter(f"{NS}useBuiltinTransports")).text == "false"
    assert "239.255" not in text and "SHM" not in text
    peers = next(root.iter(f"{NS}initialPeersList"))
    ports = [int(e.text or "") for e in peers.iter(f"{NS}port")]
    hosts = [e.text for e in peers.iter(f"{NS}address")]
    # the two other ROS 2 participants, each with its explicit port (no port probing)
    assert len(ports) == 2 and "10.42.0.11" not in hosts
    env = _profiles("drone-1")["drone-1/talker.env"]
    assert "ROS_AUTOMATIC_DISCOVERY_RANGE=SYSTEM_DEFAULT" in env
    assert "RMW_IMPLEMENTATION=rmw_fastrtps_cpp" in env
    assert "FASTDDS_DEFAULT_PROFILES_FILE=/etc/ros2/drone-1/talker.xml" in env


def test_a_drone_without_address_is_named() -> None:
    bundle = build_dev_bundle(parse_mission(MISSION)).bundle
    assert bundle.ros2 is not None
    with pytest.raises(ProfileError, match="drone-2"):
        drone_profiles(
            bundle.ros2,
            bundle_ros2_participants(bundle),
            {"lead": "10.0.0.1", "drone-1": "10.0.0.2"},
            "lead",
            "/x",
        )


def test_cli_writes_every_drone_and_refuses_a_bundle_without_graph(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    mission = tmp_path / "m.yaml"
    mission.write_text(MISSION)
    bundle = tmp_path / "s.swb"
    assert swarmctl(["bundle", "build", str(mission), "-o", str(bundle), "--unsigned-dev"]) == 0
    out = tmp_path / "out"
    assert swarmctl(["ros2", "profile", str(bundle), "--allow-dev", "--out", str(out)]) == 0
    written = sorted(str(p.relative_to(out)) for p in out.rglob("*") if p.is_file())
    assert written == sorted(
        [
            "drone-1/static-edp.xml",
            "drone-1/talker.env",
            "drone-1/talker.xml",
            "drone-2/static-edp.xml",
            "drone-2/talker.env",
            "drone-2/talker.xml",
            "lead/listener.env",
            "lead/listener.xml",
            "lead/static-edp.xml",
        ]
    )
    via = tmp_path / "via"
    args = ["ros2", "profile", str(bundle), "--allow-dev", "--out", str(via), "--via-swarmd"]
    assert swarmctl([*args, "--relay-port", "7500"]) == 0
    assert "<port>7500</port>" in (via / "lead" / "listener.xml").read_text()
    capsys.readouterr()
    assert swarmctl([*args, "--relay-port", "0"]) == 2
    assert "--relay-port 0" in capsys.readouterr().err
    # a DEV bundle is refused without --allow-dev, like every other bundle command
    assert swarmctl(["ros2", "profile", str(bundle), "--out", str(out)]) == 78
    plain = tmp_path / "p.yaml"
    plain.write_text(PLAIN)
    assert swarmctl(["bundle", "build", str(plain), "-o", str(bundle), "--unsigned-dev"]) == 0
    capsys.readouterr()
    assert swarmctl(["ros2", "profile", str(bundle), "--allow-dev", "--out", str(out)]) == 65
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and re.search(r"no ROS 2 graph; fix: add a 'ros2:'", err)


def test_preflight_check_refuses_profiles_that_do_not_match_the_flashed_bundle(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    mission = tmp_path / "m.yaml"
    mission.write_text(MISSION)
    bundle = tmp_path / "s.swb"
    assert swarmctl(["bundle", "build", str(mission), "-o", str(bundle), "--unsigned-dev"]) == 0
    installed = tmp_path / "etc"
    common = ["--allow-dev", "--via-swarmd"]
    assert swarmctl(["ros2", "profile", str(bundle), "--out", str(installed), *common]) == 0
    check = ["ros2", "check", str(bundle), "--profiles", str(installed)]
    capsys.readouterr()
    assert swarmctl([*check, *common]) == 0
    assert capsys.readouterr().out.startswith("OK 9 ROS 2 profile files match")
    assert swarmctl([*check, *common, "--drone", "lead"]) == 0
    # on the drone: one folder, as installed
    onboard = tmp_path / "onboard"
    onboard.mkdir()
    for f in (installed / "lead").iterdir():
        (onboard / f.name).write_text(f.read_text())
    onboard_check = ["ros2", "check", str(bundle), "--profiles", str(onboard), "--drone", "lead"]
    install = ["--install-dir", str((installed / "lead").absolute())]
    assert swarmctl([*onboard_check, *common, *install]) == 0
    # the plain route's files are not these: refused
    assert swarmctl([*check, "--allow-dev"]) == 65
    capsys.readouterr()
    # a new bundle (the listener now also publishes) against the old installed files
    changed = MISSION.replace(
        "subscribes: [/chatter]", "subscribes: [/chatter]\n      publishes: [/chatter]"
    )
    assert changed != MISSION
    mission.write_text(changed)
    assert swarmctl(["bundle", "build", str(mission), "-o", str(bundle), "--unsigned-dev"]) == 0
    capsys.readouterr()
    assert swarmctl([*check, *common, "--drone", "lead"]) == 65
    err = capsys.readouterr().err.strip().splitlines()
    assert err and all("; fix: regenerate with 'swarmctl ros2 profile'" in e for e in err)
    assert any(e.startswith(f"swarmctl: {installed}/lead/listener.xml: line ") for e in err)
    capsys.readouterr()
    assert swarmctl([*onboard_check, *common, *install]) == 65  # the old bundle's files
    assert f"{onboard}/listener.xml: line " in capsys.readouterr().err
    (installed / "lead" / "listener.env").unlink()
    capsys.readouterr()
    assert swarmctl([*check, *common, "--drone", "lead", "--json"]) == 65
    verdict = json.loads(capsys.readouterr().out)
    assert not verdict["ok"] and any("cannot read" in p for p in verdict["problems"])
