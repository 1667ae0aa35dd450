"""The nftables table that lets only the configured users send to swarmd's loopback ports,
generated from the daemon's config (``swarmd local-firewall``; docs/security.md, "The local
user", residual (6)).

Why a firewall. swarmd tells local users apart by reading the owner of the sender's socket
out of the kernel's socket table after the datagram arrived (swarmd.senderuid). A user who
binds a node's port at another address, sends with ``IP_PKTINFO``/``IPV6_PKTINFO`` naming the
node's address as source, and closes the socket at once is gone from the table by then: the
datagram is credited to the node (bench/sender_uid_pktinfo_race.py: 199/200 by IPv4, 200/200
by IPv6). Only the kernel at send time still knows the sending socket: nftables' output hook
reads its owner as ``meta skuid`` (nft(8), "META EXPRESSIONS"). So rules on that hook let each
of a guarded port's users return, then drop and count every other UDP datagram to that port;
a forged datagram then never reaches swarmd, whatever the socket does afterwards.

Which ports (read from the code that binds them):

- the ROS 2 relay's ``[::1]:ros2.relay_port`` (swarmd.ros2app; the relay's other socket, on
  127.0.0.1 at a port the kernel picks, only sends: what it receives is counted and dropped
  unread), users ``ros2.node_users``;
- the XRCE agent's ``px4.connection`` (``px4.backend: xrce-agent``, ``udp:HOST:PORT``), users
  ``px4.loopback_user``. The agent tells users apart for loopback senders only, so its rule
  matches what leaves on ``lo``: with the default 127.0.0.1 that is every datagram to it. On a
  wildcard (``px4.allow_network``) it matches every datagram this host sends to one of its
  own addresses, a broadcast or a multicast group: those reach the agent too.

Who may send: exactly the users the daemon itself takes on that port, so the two layers
agree (a datagram the firewall passes is one the lookup would also take). Root is not added:
swarmd drops root's datagrams there too unless root is listed, and a root process can delete
this table anyway, so allowing it would guard nothing.

A port whose users are not configured gets no rule (the daemon takes every local user there
too, and logs ``*_local_users_not_told_apart``): ``notes`` says so, one line each, and the
table is still written (empty), so the same systemd unit serves every drone.

Two forms of the same rules. The nftables table is the first choice. The drone's kernel may
not have it: L4T R32.x's ``tegra_defconfig`` (Linux 4.9, the Jetson Nano) builds no
``CONFIG_NF_TABLES`` at all, and the wildcard rule's ``fib`` needs nft_fib, merged in Linux
4.10 (docs/deploy.md, "The local firewall on the Nano"). What that kernel has is iptables:
``xt_owner`` (``-m owner --uid-owner``), ``xt_addrtype`` and ``xt_comment``. So the same
rules are also written as a chain ``swarmd_local`` of the filter table for
``iptables-restore``/``ip6tables-restore``, jumped to first from ``OUTPUT``: per port one
``RETURN`` for each user (a uid set is not one match there), then a counted ``DROP``.
``RETURN``, not ``ACCEPT``: the rest of ``OUTPUT`` still applies to what this chain passes.

Both forms have that one shape: one rule per user that returns, then the counted drop. For
nft it is also the oldest syntax: rule comments, ``meta skuid``, ``return`` and ``counter``
are in every nft since 0.2 (2014), where a negated set (``meta skuid != { 0, 1000 }``) needs
nft 0.7 and the kernel's inverted set lookup (docs/deploy.md, "The local firewall on the
Nano", has what was read for nft 0.8.2, Ubuntu 18.04's). ``return`` in a base chain ends
this chain with its policy, ``accept``: other tables' output chains still apply.

This module is pure (config in, text out); ``swarmd.cli.firewall_cmd`` runs ``nft`` or
``iptables-restore`` and picks the one the kernel takes.
"""

from __future__ import annotations

import ipaddress
import re
from dataclasses import dataclass
from typing import Final

from swarmd.config import DaemonConfig
from swarmd.loopback import plain_address

FAMILY: Final = "inet"
TABLE: Final = "swarmd_local"
CHAIN: Final = "output"
# nft prints a rule's counter with its values; the generated text has a bare "counter"
_COUNTER_VALUES: Final = re.compile(r"\bcounter packets (\d+) bytes \d+")
_COMMENT: Final = re.compile(r'comment "([^"]*)"')
# nft before 0.9.1 prints ``meta skuid`` as a bare ``skuid`` (nftables 6dd84833, "src: meta:
# always prefix 'meta' for almost all tokens"; Ubuntu 18.04 has 0.8.2)
_BARE_SKUID: Final = re.compile(r"(?<!meta )\bskuid\b")
# ``nft -nnn`` (numeric uids, which 0.8 needs) makes nft 0.9.1+ print route types as numbers:
# the kernel's RTN_* values (include/uapi/linux/rtnetlink.h), named as nft names them
_FIB_TYPE: Final = re.compile(r"(fib daddr type )(\{[^}]*\}|\d+)")
_RTN_NAMES: Final = {
    "0": "unspec", "1": "unicast", "2": "local", "3": "broadcast", "4": "anycast",
    "5": "multicast", "6": "blackhole", "7": "unreachable", "8": "prohibit",
}  # fmt: skip

# the iptables form: a chain of the filter table, in each IP version's own tables
XT_CHAIN: Final = "swarmd_local"
XT_VERSIONS: Final = (4, 6)
XT_JUMP: Final = f"-A OUTPUT -j {XT_CHAIN}"  # the hook, as iptables-save prints it
# route types a wildcard agent also receives (xt_addrtype; IPv6 has no broadcast, and
# ip6tables refuses BROADCAST)
_XT_WILDCARD: Final = {4: "LOCAL,BROADCAST,MULTICAST", 6: "LOCAL,MULTICAST"}
# one rule of ``iptables-save -c``: "[packets:bytes] -A chain ..." (the counters optional)
_XT_RULE: Final = re.compile(r"^(?:\[(\d+):\d+\] )?(-A (\S+) .*?)\s*$")
_XT_COMMENT: Final = re.compile(r'--comment "?([^"]*?)"? -j DROP$')


@dataclass(frozen=True, slots=True)
class GuardedPort:
    """One loopback port of swarmd that only ``uids`` may send to."""

    field: str  # the config field that names the port (the rule's comment)
    users_field: str  # the config field that names its users
    address: str | None  # the port's local address; None: any address (a wildcard bind)
    port: int
    uids: frozenset[int]

    def rules(self) -> list[str]:
        """The rules as ``nft list`` prints them (but the counter's values): each user
        returns, then the rest are counted and dropped under the comment."""
        if self.address is not None:
            ip = ipaddress.ip_address(self.address)
            match = f'oifname "lo" {"ip6" if ip.version == 6 else "ip"} daddr {ip.compressed}'
        else:
            # a wildcard also takes this host's broadcasts and its own multicast copies, which
            # leave by the Wi-Fi, not ``lo`` (a local user's ``SO_BROADCAST`` to the subnet, or
            # 224.0.0.1 with ``IP_MULTICAST_LOOP``: tests/test_local_firewall_netns.py); the
            # route's type names all three, unicast to any local address included (nft 0.7+,
            # the kernel's nft_fib_inet; only wildcard configs need it)
            match = "fib daddr type { local, broadcast, multicast }"
        match += f" udp dport {self.port}"
        users = [f"{match} meta skuid {uid} return" for uid in sorted(self.uids)]
        return [*users, f'{match} counter drop comment "{self.comment}"']

    def xt_rules(self, version: int) -> list[str]:
        """The rules for IP ``version``'s iptables, as ``iptables-save`` prints them (but
        the counters); none when the port is of the other version. Each user returns to
        ``OUTPUT``, then the rest are dropped and counted under the comment."""
        if self.address is not None:
            ip = ipaddress.ip_address(self.address)
            if ip.version != version:
                return []
            match = f"-d {ip.compressed}/{ip.max_prefixlen} -o lo -p udp -m udp --dport {self.port}"
        else:
            # the fib rule's route types, by xt_addrtype (a wildcard agent: both versions)
            types = _XT_WILDCARD[version]
            match = f"-p udp -m udp --dport {self.port} -m addrtype --dst-type {types}"
        users = [
            f"-A {XT_CHAIN} {match} -m owner --uid-owner {uid} -j RETURN"
            for uid in sorted(self.uids)
        ]
        return [*users, f'-A {XT_CHAIN} {match} -m comment --comment "{self.comment}" -j DROP']

    @property
    def comment(self) -> str:
        return f"{self.field}: {self.users_field} only"


@dataclass(frozen=True, slots=True)
class LocalFirewall:
    """The table for one config: its rules, and a note for each port left to every user."""

    file: str
    ports: tuple[GuardedPort, ...]
    notes: tuple[str, ...]

    def table(self) -> str:
        """The table as ``nft list table inet swarmd_local`` prints it (counters bare, the
        chain's priority as a number)."""
        rules = "".join(f"\t\t{rule}\n" for port in self.ports for rule in port.rules())
        return (
            f"table {FAMILY} {TABLE} {{\n"
            f"\tchain {CHAIN} {{\n"
            # "priority 0", not its name "filter": nft 0.8 (Ubuntu 18.04, docs/deploy.md)
            # has no priority names; nft 1.0 lists 0 as "filter" (``normalized``)
            "\t\ttype filter hook output priority 0; policy accept;\n"
            f"{rules}"
            "\t}\n"
            "}\n"
        )

    def script(self) -> str:
        """Input for ``nft -f``: replaces any older table in one transaction (declaring it
        first makes the delete succeed when there is none)."""
        return (
            f"# swarmd local-firewall --config {self.file} (docs/security.md, residual (6))\n"
            f"table {FAMILY} {TABLE}\n"
            f"delete table {FAMILY} {TABLE}\n"
            f"{self.table()}"
        )

    def xt_rules(self, version: int) -> list[str]:
        """The chain's rules for IP ``version``, in order."""
        return [rule for port in self.ports for rule in port.xt_rules(version)]

    def xt_script(self, version: int, live: XtLive) -> str:
        """Input for ``iptables-restore --noflush`` (``ip6tables-restore`` for 6): declaring
        the chain creates it or empties an older one, the rules follow, and the jump from
        ``OUTPUT`` is made the first rule, once; one commit, so no moment without the
        rules. ``live`` is the table as it is now (``xt_live``)."""
        hook: list[str] = []
        if not live.hooked_once_first:
            hook = [f"-D OUTPUT -j {XT_CHAIN}"] * live.jumps + [f"-I OUTPUT 1 -j {XT_CHAIN}"]
        lines = [f":{XT_CHAIN} - [0:0]", *self.xt_rules(version), *hook]
        return _xt_commit(f"--config {self.file}", lines)

    def xt_differences(self, version: int, live: XtLive) -> list[str]:
        """What IP ``version``'s live chain and hook lack or have more than wanted, as
        ``differences``; [] when they match."""
        want = self.xt_rules(version)
        have = list(live.rules or ())
        diff = [f"- {line}" for line in want if line not in have]
        diff += [f"+ {line}" for line in have if line not in want]
        if not diff and have != want:
            diff = ["the same rules in another order"]
        if live.rules is None:
            diff.insert(0, f"- :{XT_CHAIN} (no such chain)")
        elif not live.hooked_once_first:
            diff.append(
                f"- {XT_JUMP} as OUTPUT's only jump to it, first "
                f"(live: {live.jumps} jumps, first: {live.first_is_jump})"
            )
        return diff


@dataclass(frozen=True, slots=True)
class XtLive:
    """One IP version's filter table as ``iptables-save -c -t filter`` printed it: swarmd's
    chain (None: there is none) and how ``OUTPUT`` jumps to it."""

    rules: tuple[str, ...] | None  # the chain's rules without their counters
    dropped: dict[str, int]  # a DROP rule's comment -> the datagrams it dropped
    jumps: int  # OUTPUT's rules that jump to the chain
    first_is_jump: bool  # OUTPUT's first rule is one of them

    @property
    def hooked_once_first(self) -> bool:
        return self.jumps == 1 and self.first_is_jump

    @property
    def loaded(self) -> bool:
        return self.rules is not None or self.jumps > 0


def xt_live(saved: str) -> XtLive:
    """``iptables-save -c -t filter`` output (with or without counters) as an ``XtLive``."""
    rules: list[str] = []
    dropped: dict[str, int] = {}
    output: list[str] = []
    declared = False
    for line in saved.splitlines():
        if line.startswith(f":{XT_CHAIN} "):
            declared = True
        found = _XT_RULE.match(line)
        if found is None:
            continue
        count, rule, chain = found.groups()
        if chain == "OUTPUT":
            output.append(rule)
        elif chain == XT_CHAIN:
            rules.append(rule)
            comment = _XT_COMMENT.search(rule)
            if comment is not None and count is not None:
                dropped[comment.group(1)] = int(count)
    jumps = output.count(XT_JUMP)
    return XtLive(
        tuple(rules) if declared or rules else None,
        dropped,
        jumps,
        bool(output) and output[0] == XT_JUMP,
    )


def xt_removal(live: XtLive) -> str | None:
    """Input for ``iptables-restore --noflush`` that deletes the chain and every jump to
    it; None when there is neither."""
    if not live.loaded:
        return None
    lines = [f"-D OUTPUT -j {XT_CHAIN}"] * live.jumps
    if live.rules is not None:
        lines += [f"-F {XT_CHAIN}", f"-X {XT_CHAIN}"]
    return _xt_commit("--remove", lines)


def _xt_commit(how: str, lines: list[str]) -> str:
    body = "".join(f"{line}\n" for line in lines)
    return (
        f"# swarmd local-firewall {how} (docs/security.md, residual (6))\n*filter\n{body}COMMIT\n"
    )


def local_firewall(config: DaemonConfig) -> LocalFirewall:
    """The table ``config`` needs; ``ConfigError`` (one line) when a port cannot be written
    as a rule."""
    ports: list[GuardedPort] = []
    notes: list[str] = []
    ros2 = config.ros2
    if ros2.relay:
        # only relay configs pay for the relay's import: `swarmd run` imports this module
        # (its parser's `local-firewall`) before its engine starts
        from swarmd.ros2.relay import LOOPBACK

        if ros2.node_users is None:
            notes.append(_unguarded(config, "ros2.node_users", f"[{LOOPBACK}]:{ros2.relay_port}"))
        else:
            ports.append(
                GuardedPort(
                    "ros2.relay_port", "ros2.node_users", LOOPBACK, ros2.relay_port, ros2.node_users
                )
            )
    px4 = config.px4
    if px4.enabled and px4.backend == "xrce-agent":
        # only XRCE configs pay for the backend's import (asyncio), as in swarmd.config
        from swarmd.px4.xrce_backend import parse_xrce_connection

        endpoint = parse_xrce_connection(px4.connection)
        if endpoint.kind == "udpin":
            address = _address(config, endpoint.host)
            if px4.loopback_user is None:
                if address is None or ipaddress.ip_address(address).is_loopback:
                    notes.append(_unguarded(config, "px4.loopback_user", px4.connection))
            else:
                ports.append(
                    GuardedPort(
                        "px4.connection",
                        "px4.loopback_user",
                        address,
                        endpoint.port,
                        frozenset({px4.loopback_user}),
                    )
                )
    return LocalFirewall(config.file, tuple(ports), tuple(notes))


def _address(config: DaemonConfig, host: str) -> str | None:
    """``host`` as an address for a rule; None for a wildcard (every local address). A
    v4-mapped address is its IPv4 form (swarmd.loopback): an IPv6 socket bound to
    ``::ffff:127.0.0.1`` receives IPv4 datagrams to 127.0.0.1, which an ``ip6`` rule never
    sees (review 14: ``nobody``'s datagrams reached such an agent past the loaded table)."""
    ip = plain_address(host.strip("[]"))
    if ip is None:
        raise config.error(
            "px4.connection",
            f"{host!r} is no IP address: the firewall rule needs the agent's address",
            "write it as an address, e.g. udp:127.0.0.1:888",
        )
    return None if ip.is_unspecified else ip.compressed


def _unguarded(config: DaemonConfig, users_field: str, where: str) -> str:
    """A note (one line, as a config error reads) for a port every local user may send to."""
    return str(
        config.error(
            users_field,
            f"not set: {where} takes every local user, the firewall guards nothing there",
            f"set {users_field} (docs/operations.md) to guard it",
        )
    )


def normalized(listing: str) -> list[str]:
    """``nft -nnn list table`` output (or ``LocalFirewall.table()``) as comparable lines: each
    stripped, blank lines dropped, counters without their values, the priority a number,
    ``skuid`` as ``meta skuid`` and route types by name, as every nft from 0.8 prints them."""
    lines = (_one_form(line).strip() for line in listing.splitlines())
    return [line for line in lines if line]


def _one_form(line: str) -> str:
    line = _COUNTER_VALUES.sub("counter", line).replace("priority filter;", "priority 0;")
    line = _BARE_SKUID.sub("meta skuid", line)
    return _FIB_TYPE.sub(_route_types_named, line)


def _route_types_named(found: re.Match[str]) -> str:
    clause, types = found.groups()
    return clause + re.sub(r"\d+", lambda n: _RTN_NAMES.get(n.group(0), n.group(0)), types)


def differences(live: str, wanted: LocalFirewall) -> list[str]:
    """What the live table lacks or has more than ``wanted`` ("-" wanted, "+" live), in
    order; [] when they match."""
    have, want = normalized(live), normalized(wanted.table())
    if have == want:
        return []
    return [f"- {line}" for line in want if line not in have] + [
        f"+ {line}" for line in have if line not in want
    ] or ["the same lines in another order"]


def dropped(listing: str) -> dict[str, int]:
    """Each rule's comment -> the datagrams it dropped, from ``nft list table`` output."""
    out: dict[str, int] = {}
    for line in listing.splitlines():
        count, comment = _COUNTER_VALUES.search(line), _COMMENT.search(line)
        if count is not None and comment is not None:
            out[comment.group(1)] = int(count.group(1))
    return out
