"""Daemon config: the documented default loads; every bad field is one line with its line."""

from __future__ import annotations

from pathlib import Path

import pytest
from swarmd_lab.configs import MINIMAL_CONFIG

from swarmd.config import ConfigError, load_config, parse_config

REPO = Path(__file__).resolve().parent.parent

MINIMAL = MINIMAL_CONFIG


def test_documented_default_config_loads() -> None:
    cfg = load_config(REPO / "config" / "swarmd.yaml")
    assert cfg.node == "uav1"
    assert cfg.interface == "wlan0"
    assert cfg.bundle.path == "/var/lib/swarmd/bundle.swb"
    assert cfg.bundle.trusted_key == "/var/lib/swarmd/swarm.pub"
    assert cfg.control_socket == "/run/swarmd/swarmd.sock"
    assert cfg.control_socket_mode == 0o660
    assert cfg.link.sources == ("nl80211", "wext", "static")
    assert (cfg.engine_mode, cfg.log_format) == ("adaptive", "auto")


def test_documented_default_enables_px4_and_the_data_plane() -> None:
    cfg = load_config(REPO / "config" / "swarmd.yaml")
    assert cfg.px4.enabled and cfg.px4.connection == "udpin:127.0.0.1:540"  # swarmd-px4.socket
    assert cfg.px4.signing and not cfg.px4.allow_network and cfg.px4.autopilot is None
    assert cfg.px4.sysid is None  # from the bundle participant's mavlink_sysid
    assert cfg.dataplane.enabled and cfg.dataplane.readiness_period_s == 1.0
    assert cfg.dataplane.state_dir == "/var/lib/swarmd"


def test_swarm_sections_absent_mean_off_present_mean_on() -> None:
    off = parse_config(MINIMAL, "c.yaml")
    assert not off.px4.enabled and not off.dataplane.enabled
    on = parse_config(
        MINIMAL + "px4:\n  sysid: 7\ndataplane:\n  readiness_period_s: 2\n  state_dir: st\n",
        "/etc/swarmd/c.yaml",
        base=Path("/etc/swarmd"),
    )
    assert on.px4.enabled and on.px4.sysid == 7
    assert on.dataplane.enabled and on.dataplane.stale_after_s == 6.0  # 3 periods
    assert on.dataplane.state_dir == "/etc/swarmd/st"
    assert not parse_config(MINIMAL + "dataplane:\n  enabled: false\n").dataplane.enabled


def test_minimal_config_resolves_relative_paths_and_defaults() -> None:
    cfg = parse_config(MINIMAL, "/etc/swarmd/swarmd.yaml", base=Path("/etc/swarmd"))
    assert cfg.bundle.path == "/etc/swarmd/bundle.swb"
    assert cfg.bundle.trusted_key == "/etc/swarmd/keys/swarm-signing.pub"
    assert cfg.ipv4 is None
    assert cfg.link.static_q == 0.5
    assert cfg.lines["network.interface"] == 6
    assert cfg.error("network.interface", "p", "f").line == 6


@pytest.mark.parametrize(
    ("extra", "line", "field", "problem"),
    [
        ("nodee: x\n", 7, "nodee", "unknown field 'nodee'"),
        ("link:\n  poll_interval_s: 0\n", 8, "link.poll_interval_s", "0 is outside"),
        ("link:\n  sources: [nl80211, radar]\n", 8, "link.sources", "unknown value 'radar'"),
        ("link:\n  sources: [file, file]\n", 8, "link.sources", "listed twice"),
        ("link:\n  static_q: high\n", 8, "link.static_q", "expected a number"),
        ("control:\n  mode: 999\n", 8, "control.mode", "is not a file mode"),
        # session 10 review: any "other" bit lets every local user reach the socket (the
        # write bit is connect(2)), i.e. take off the swarm
        ("control:\n  mode: '0666'\n", 8, "control.mode", "every local user"),
        ("control:\n  mode: '0662'\n", 8, "control.mode", "every local user"),
        ("control:\n  mode: '0604'\n", 8, "control.mode", "every local user"),
        ("discovery:\n  mode: fast\n", 8, "discovery.mode", "unknown value 'fast'"),
        ("logging:\n  level: loud\n", 8, "logging.level", "unknown value 'loud'"),
        ("discovery:\n  overrides:\n    lease: 3\n", 9, "discovery.overrides.lease", "unknown"),
        ("px4:\n  connection: tcp:1.2.3.4:5\n", 8, "px4.connection", "no known scheme"),
        ("px4:\n  connection: serial:/dev/ttyTHS1:12345\n", 8, "px4.connection", "baud"),
        ("px4:\n  sysid: 300\n", 8, "px4.sysid", "300 is outside 1..255"),
        ("px4:\n  sysid: 1.5\n", 8, "px4.sysid", "not a whole number"),
        ("px4:\n  takeoff_alt_m: 500\n", 8, "px4.takeoff_alt_m", "outside"),
        ("px4:\n  enabled: yes please\n", 8, "px4.enabled", "expected true or false"),
        ("px4:\n  rtl: true\n", 8, "px4.rtl", "unknown field 'rtl'"),
        ("dataplane:\n  readiness_period_s: 0\n", 8, "dataplane.readiness_period_s", "0 is"),
        (
            "dataplane:\n  readiness_period_s: 2\n  stale_after_s: 1\n",
            9,
            "dataplane.stale_after_s",
            "does not exceed readiness_period_s",
        ),
    ],
)
def test_bad_field_is_one_line_with_file_line_field_and_fix(
    extra: str, line: int, field: str, problem: str
) -> None:
    with pytest.raises(ConfigError) as info:
        parse_config(MINIMAL + extra, "swarmd.yaml", engine_fields=frozenset({"lease_s"}))
    text = str(info.value)
    assert "\n" not in text
    assert text.startswith(f"swarmd.yaml:{line}: field {field}: ")
    assert problem in text
    assert "; fix: " in text


@pytest.mark.parametrize(
    ("text", "field"),
    [
        ("bundle: {trusted_key: k}\nnetwork: {interface: eth0}\n", "node"),
        ("node: a\nnetwork: {interface: eth0}\n", "bundle"),
        ("node: a\nbundle: {path: b}\nnetwork: {interface: eth0}\n", "bundle.trusted_key"),
        ("node: a\nbundle: {trusted_key: k}\n", "network"),
        ("node: a\nbundle: {trusted_key: k}\nnetwork: {ipv4: 10.0.0.1}\n", "network.interface"),
        (
            "node: a\nbundle: {trusted_key: k}\nnetwork: {interface: e, ipv4: 10.0.0}\n",
            "network.ipv4",
        ),
        ("node: [a]\n", "node"),
        ("node: a\n  bad: indent\n", "<yaml>"),
        ("", "<document>"),
    ],
)
def test_missing_and_malformed(text: str, field: str) -> None:
    with pytest.raises(ConfigError, match=f"field {field}: ") as info:
        parse_config(text, "c.yaml")
    assert "; fix: " in str(info.value)


def test_expected_sha256_is_a_trust_anchor_and_checked() -> None:
    good = "node: a\nbundle: {expected_sha256: '" + "ab" * 32 + "'}\nnetwork: {interface: e}\n"
    assert parse_config(good).bundle.expected_sha256 == bytes.fromhex("ab" * 32)
    with pytest.raises(ConfigError, match="not a SHA-256"):
        parse_config(good.replace("ab" * 32, "xyz"))


def test_missing_file(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="config file not found"):
        load_config(tmp_path / "nope.yaml")


def test_vouch_switch_override_is_0_or_1() -> None:
    from swarmd.daemon_setup import engine_config

    off = parse_config(MINIMAL + "discovery:\n  overrides:\n    vouch: 0\n", "x.yaml")
    assert engine_config(off).vouch is False
    assert engine_config(parse_config(MINIMAL, "x.yaml")).vouch is True
    bad = parse_config(MINIMAL + "discovery:\n  overrides:\n    vouch: 2\n", "x.yaml")
    with pytest.raises(ConfigError, match="vouch"):
        engine_config(bad)


def test_ros2_relay_section_absent_means_off_present_means_on() -> None:
    assert not parse_config(MINIMAL, "c.yaml").ros2.relay
    on = parse_config(MINIMAL + "ros2:\n  relay_port: 7500\n  lease_s: 6\n", "c.yaml")
    assert on.ros2.relay and on.ros2.relay_port == 7500 and on.ros2.lease_s == 6.0
    assert not parse_config(MINIMAL + "ros2:\n  relay: false\n", "c.yaml").ros2.relay


@pytest.mark.parametrize(
    ("extra", "field"),
    [
        ("ros2:\n  relay_port: 70000\n", "ros2.relay_port"),
        ("ros2:\n  relay_port: 7399.5\n", "ros2.relay_port"),
        ("ros2:\n  lease_s: 0.1\n", "ros2.lease_s"),
        ("ros2:\n  relay: yes please\n", "ros2.relay"),
        ("ros2:\n  relai: true\n", "ros2.relai"),
    ],
)
def test_bad_ros2_field_is_one_line(extra: str, field: str) -> None:
    with pytest.raises(ConfigError, match=f"field {field}: ") as info:
        parse_config(MINIMAL + extra, "c.yaml")
    assert "\n" not in str(info.value) and "; fix: " in str(info.value)


def test_local_users_by_name_or_uid_and_absent_means_not_told_apart() -> None:
    """``ros2.node_users`` and ``px4.loopback_user`` (docs/operations.md): names resolve
    here, uids are taken as written; absent, None (every local sender is taken)."""
    assert parse_config(MINIMAL, "c.yaml").ros2.node_users is None
    assert parse_config(MINIMAL, "c.yaml").px4.loopback_user is None
    cfg = parse_config(MINIMAL + "ros2:\n  node_users: [root, 1234]\n", "c.yaml")
    assert cfg.ros2.node_users == frozenset({0, 1234})
    one = parse_config(MINIMAL + "ros2:\n  node_users: nobody\n", "c.yaml")
    assert one.ros2.node_users == frozenset({65534})
    px4 = "px4:\n  backend: xrce-agent\n  connection: udp:127.0.0.1:8888\n  loopback_user: nobody\n"
    assert parse_config(MINIMAL + px4, "c.yaml").px4.loopback_user == 65534


@pytest.mark.parametrize(
    ("extra", "field"),
    [
        ("ros2:\n  node_users: [no-such-user-here]\n", "ros2.node_users"),
        ("ros2:\n  node_users: []\n", "ros2.node_users"),
        ("ros2:\n  node_users: -1\n", "ros2.node_users"),
        ("ros2:\n  node_users: {a: 1}\n", "ros2.node_users"),
        ("px4:\n  loopback_user: root\n", "px4.loopback_user"),  # the mavlink backend
        (
            "px4:\n  backend: xrce-agent\n  connection: udp:127.0.0.1:8888\n"
            "  loopback_user: no-such-user-here\n",
            "px4.loopback_user",
        ),
    ],
)
def test_bad_local_user_field_is_one_line(extra: str, field: str) -> None:
    with pytest.raises(ConfigError, match=f"field {field}: ") as info:
        parse_config(MINIMAL + extra, "c.yaml")
    assert "\n" not in str(info.value) and "; fix: " in str(info.value)
