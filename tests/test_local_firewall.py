"""``swarmd local-firewall``'s table, generated from the config (swarmd.localfirewall): which
ports, which users, the notes for a port left to everyone, and the comparison ``--check``
makes with nft's own listing. The kernel's side is tests/test_local_firewall_netns.py."""

from __future__ import annotations

from pathlib import Path

import pytest

from swarmd.cli.swarmd_main import main
from swarmd.config import ConfigError, parse_config
from swarmd.localfirewall import differences, dropped, local_firewall, normalized
from tests.test_daemon_config import MINIMAL

RELAY = "ros2:\n  relay_port: 7411\n  node_users: [1000, 0, 1001]\n"
XRCE = "px4:\n  backend: xrce-agent\n  loopback_user: 1002\n"

# what nft 1.0.6 prints for the table of MINIMAL + RELAY + XRCE (`nft -nnn list table inet
# swarmd_local`, as --check runs it, in a namespace; the relay's counter then set to 3 by
# hand; tests/test_local_firewall_netns.py checks the live listing the same way)
LISTED = """\
table inet swarmd_local {
	chain output {
		type filter hook output priority 0; policy accept;
		oifname "lo" ip6 daddr ::1 udp dport 7411 meta skuid 0 return
		oifname "lo" ip6 daddr ::1 udp dport 7411 meta skuid 1000 return
		oifname "lo" ip6 daddr ::1 udp dport 7411 meta skuid 1001 return
		oifname "lo" ip6 daddr ::1 udp dport 7411 counter packets 3 bytes 120 drop comment "ros2.relay_port: ros2.node_users only"
		oifname "lo" ip daddr 127.0.0.1 udp dport 888 meta skuid 1002 return
		oifname "lo" ip daddr 127.0.0.1 udp dport 888 counter packets 0 bytes 0 drop comment "px4.connection: px4.loopback_user only"
	}
}
"""  # noqa: E501 - nft's own lines
# the same table as nft 0.8.2 (Ubuntu 18.04) prints it at -nnn: written from its source, not
# captured (no 0.8.2 here): meta keys bare (src/meta.c, meta_expr_print: ``skuid``, until
# nftables 6dd84833 in 0.9.1), uids and ports numeric at three -n (src/meta.c, uid_type_print)
LISTED_0_8 = LISTED.replace("meta skuid", "skuid")
# nft 1.0.6, `nft -nnn list`, a wildcard agent: -nnn prints the route types as numbers too
LISTED_WILDCARD = """\
table inet swarmd_local {
	chain output {
		type filter hook output priority 0; policy accept;
		fib daddr type { 2, 3, 5 } udp dport 888 meta skuid 1002 return
		fib daddr type { 2, 3, 5 } udp dport 888 counter packets 0 bytes 0 drop comment "px4.connection: px4.loopback_user only"
	}
}
"""  # noqa: E501 - nft's own lines
WILDCARD = MINIMAL + XRCE + "  connection: udp:0.0.0.0:888\n  allow_network: true\n"


def test_the_relay_port_and_a_loopback_agent_take_only_their_users() -> None:
    wall = local_firewall(parse_config(MINIMAL + RELAY + XRCE, "c.yaml"))
    assert [(p.address, p.port, p.uids) for p in wall.ports] == [
        ("::1", 7411, frozenset({0, 1000, 1001})),
        ("127.0.0.1", 888, frozenset({1002})),
    ]
    assert wall.notes == ()
    assert normalized(LISTED) == normalized(wall.table())
    assert differences(LISTED, wall) == []
    assert dropped(LISTED) == {
        "ros2.relay_port: ros2.node_users only": 3,
        "px4.connection: px4.loopback_user only": 0,
    }


def test_root_is_not_added_to_the_users() -> None:
    """The firewall takes whom the daemon takes: root only when listed."""
    wall = local_firewall(parse_config(MINIMAL + "ros2:\n  node_users: 1000\n", "c.yaml"))
    (port,) = wall.ports
    assert [rule.split(" udp dport 7399 ")[1] for rule in port.rules()] == [
        "meta skuid 1000 return",
        'counter drop comment "ros2.relay_port: ros2.node_users only"',
    ]


def test_the_rules_need_nothing_newer_than_the_oldest_nft() -> None:
    """Each user returns, then one counted drop, as in the iptables form: no negated set
    (``!= { ... }``, nft 0.7+ and the kernel's inverted lookup), nothing but rule comments,
    ``meta skuid``, ``return`` and ``counter`` (docs/deploy.md, "The local firewall on the
    Nano")."""
    table = local_firewall(parse_config(MINIMAL + RELAY + XRCE, "c.yaml")).table()
    assert "!=" not in table and "{ " not in table.split("policy accept;")[1]
    assert table.count(" return\n") == 4 and table.count(" counter drop ") == 2


def test_check_reads_what_nft_0_8_and_nft_1_0_print() -> None:
    """``--check`` compares with ``nft -nnn list``: 0.8 prints ``skuid`` without ``meta``,
    1.0 prints a wildcard's route types as numbers; both are the wanted table."""
    wall = local_firewall(parse_config(MINIMAL + RELAY + XRCE, "c.yaml"))
    assert differences(LISTED_0_8, wall) == []
    assert dropped(LISTED_0_8)["ros2.relay_port: ros2.node_users only"] == 3
    assert differences(LISTED_WILDCARD, local_firewall(parse_config(WILDCARD, "c.yaml"))) == []
    assert differences(LISTED_0_8.replace("skuid 1002", "skuid 1003"), wall) != []


def test_the_script_replaces_an_older_table_in_one_transaction() -> None:
    wall = local_firewall(parse_config(MINIMAL + RELAY, "c.yaml"))
    lines = wall.script().splitlines()
    body = [line for line in lines if not line.startswith("#")]
    assert body[:2] == ["table inet swarmd_local", "delete table inet swarmd_local"]
    assert "\n".join(body[2:]) + "\n" == wall.table()


@pytest.mark.parametrize(
    ("extra", "field"),
    [
        ("ros2:\n  relay: true\n", "ros2.node_users"),
        ("px4:\n  backend: xrce-agent\n", "px4.loopback_user"),
    ],
)
def test_a_port_without_its_users_gets_no_rule_and_a_note(extra: str, field: str) -> None:
    wall = local_firewall(parse_config(MINIMAL + extra, "c.yaml"))
    assert wall.ports == ()
    (note,) = wall.notes
    assert note.startswith("c.yaml") and f"field {field}:" in note and "fix:" in note
    assert "\n" not in note


def test_nothing_to_guard_is_an_empty_table_not_a_failure() -> None:
    """The same unit serves every drone: a MAVLink drone without the relay loads an empty
    chain."""
    for extra in ("", "px4:\n  connection: udpin:127.0.0.1:540\n"):
        wall = local_firewall(parse_config(MINIMAL + extra, "c.yaml"))
        assert wall.ports == () and wall.notes == ()
        assert "udp dport" not in wall.table()


def test_an_agent_on_a_wildcard_is_guarded_on_every_local_address() -> None:
    (port,) = local_firewall(parse_config(WILDCARD, "c.yaml")).ports
    assert port.address is None
    # not only ``oifname "lo"``: broadcasts and multicast copies leave by another interface
    assert port.rules()[0] == (
        "fib daddr type { local, broadcast, multicast } udp dport 888 meta skuid 1002 return"
    )


def test_an_agent_named_by_host_name_is_one_line_naming_the_field() -> None:
    cfg = parse_config(
        MINIMAL + XRCE + "  connection: udp:localhost:888\n  allow_network: true\n", "c.yaml"
    )
    with pytest.raises(ConfigError) as info:
        local_firewall(cfg)
    assert info.value.field == "px4.connection"
    assert "udp:127.0.0.1:888" in info.value.fix


def test_a_changed_or_extra_rule_is_a_difference() -> None:
    wall = local_firewall(parse_config(MINIMAL + RELAY + XRCE, "c.yaml"))
    other = LISTED.replace("skuid 1002", "skuid 1003")
    diff = differences(other, wall)
    assert [line[0] for line in diff] == ["-", "+"]
    assert "1002" in diff[0] and "1003" in diff[1]
    assert differences("table inet swarmd_local {\n}\n", wall) != []


def test_the_command_rejects_a_bad_config_in_one_line(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["local-firewall"]) == 78
    assert "--config" in capsys.readouterr().err
    assert main(["local-firewall", "--config", "/nonexistent/swarmd.yaml"]) == 78
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "swarmd: config rejected:" in err


def test_the_command_prints_what_nft_loads(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    config = tmp_path / "swarmd.yaml"
    config.write_text(MINIMAL + "ros2:\n  relay: true\n")
    assert main(["local-firewall", "--config", str(config)]) == 0
    out, err = capsys.readouterr()
    assert out == local_firewall(parse_config(config.read_text(), str(config))).script()
    assert "ros2.node_users" in err and err.count("\n") == 1


@pytest.mark.parametrize(
    ("host", "address"), [("::ffff:127.0.0.1", "127.0.0.1"), ("::ffff:0.0.0.0", None)]
)
def test_a_v4_mapped_agent_address_gets_the_ipv4_rule(host: str, address: str | None) -> None:
    """An agent bound to ``::ffff:127.0.0.1`` (an IPv6 socket) receives IPv4 datagrams to
    127.0.0.1; one bound to ``::ffff:0.0.0.0`` every IPv4 one. The table had an ``ip6``
    rule for them, which no IPv4 datagram meets (review 14; the kernel's side:
    tests/test_local_firewall_netns.py). Now the rule is the IPv4 address's, or the
    wildcard's."""
    config = MINIMAL + XRCE + f"  connection: udp:{host}:888\n  allow_network: true\n"
    wall = local_firewall(parse_config(config, "c.yaml"))
    assert [(p.address, p.port) for p in wall.ports] == [(address, 888)]
    assert wall.xt_rules(4) != []
