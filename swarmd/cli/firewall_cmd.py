"""``swarmd local-firewall``: the rules that let only the configured users send to swarmd's
loopback ports (swarmd.localfirewall; docs/security.md, "The local user", residual (6);
docs/operations.md, "The local firewall"). Two backends load the same rules: ``nft`` (the
table ``inet swarmd_local``) and ``iptables`` (the chain ``swarmd_local`` of iptables' and
ip6tables' filter table, jumped to first from ``OUTPUT``), for kernels without nf_tables such
as the Jetson Nano's (docs/deploy.md, "The local firewall on the Nano").

- ``--config FILE``: print it, as ``nft -f`` input (``--backend iptables``: the
  ``iptables-restore`` and ``ip6tables-restore`` input);
- ``--config FILE --apply``: load it (the unit's ``ExecStartPre=+``, as root). With
  ``--backend auto`` (the default) nft first; when nft is missing or refused (a kernel
  without nf_tables, or without a feature the table needs) iptables. Probed, not guessed:
  what loads is what the kernel took. The other backend's old rules are then removed, and
  one line on stdout names the backend;
- ``--config FILE --check``: compare it with what is loaded (``auto``: whichever backend
  holds rules) and print each rule's drops;
- ``--remove``: delete the table and the chain, if there are any (``auto``: both).

Exit codes: 0 ok; 1 ``--check`` found the rules missing or different; 69 no backend could
load them (``--apply``: systemd then fails the start) or answer: one line with each
backend's reason and the fix; 78 the config is rejected. A config that guards no port
needs no backend: ``--apply`` and ``--check`` where none answers (or, for ``--check``,
none holds rules) exit 0 with a line that nothing is loaded and why. A port whose users are not
configured is a note on stderr, not a failure. This is the thin tier: every process is
started here, the text comes from swarmd.localfirewall.
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
from dataclasses import dataclass
from typing import Final

from swarmd.config import ConfigError, load_config
from swarmd.exitcodes import EX_CONFIG, EX_FAILED, EX_OK, EX_UNAVAILABLE
from swarmd.localfirewall import (
    FAMILY,
    TABLE,
    XT_CHAIN,
    XT_VERSIONS,
    LocalFirewall,
    XtLive,
    differences,
    dropped,
    local_firewall,
    xt_live,
    xt_removal,
)

TOOL_TIMEOUT_S: Final = 10.0
# how long iptables-restore waits for the xtables lock (``--wait``) that another program
# (Docker, firewalld) may hold; below TOOL_TIMEOUT_S, so the tool's own error is what is shown
XT_LOCK_WAIT_S: Final = 5
BACKENDS: Final = ("auto", "nft", "iptables")
# the one-line fix when no backend loads (docs/deploy.md, "The local firewall on the Nano")
FIX: Final = (
    "fix: run as root, with nft and a kernel with nf_tables (CONFIG_NF_TABLES_INET, "
    "CONFIG_NFT_META; CONFIG_NFT_FIB_INET for an agent on a wildcard), or iptables and a "
    "kernel with CONFIG_IP_NF_FILTER, CONFIG_IP6_NF_FILTER and CONFIG_NETFILTER_XT_MATCH_"
    "OWNER, _ADDRTYPE, _COMMENT (Debian: apt-get install nftables, or iptables)"
)


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser(
        "local-firewall",
        help="the nftables table (or iptables chain) that lets only the configured users "
        "send to swarmd's loopback ports (print, --apply, --check, --remove)",
    )
    p.add_argument("--config", help="daemon config file (YAML); all but --remove need it")
    p.add_argument(
        "--backend",
        choices=BACKENDS,
        default="auto",
        help="auto (default): nft, and iptables when nft is missing or the kernel refuses "
        "the table; nft or iptables: that one only",
    )
    mode = p.add_mutually_exclusive_group()
    mode.add_argument("--apply", action="store_true", help="load it now (root)")
    mode.add_argument(
        "--check", action="store_true", help="exit 1 when the live rules are missing or differ"
    )
    mode.add_argument("--remove", action="store_true", help="delete the rules (root)")


class ToolError(Exception):
    """A firewall tool is missing, hung or refused: one line."""


def _tool(argv: list[str], script: str | None = None) -> subprocess.CompletedProcess[str]:
    """Runs ``argv`` (``nft``, ``iptables-save``, ...; found on PATH) with ``script`` on
    stdin. The only place a process starts (the tests give a fake one)."""
    path = shutil.which(argv[0])
    if path is None:
        raise ToolError(f"{argv[0]} not found")
    try:
        return subprocess.run(  # noqa: S603 - fixed argv, no shell
            [path, *argv[1:]],
            input=script,
            capture_output=True,
            text=True,
            timeout=TOOL_TIMEOUT_S,
            check=False,
        )
    except subprocess.TimeoutExpired:
        raise ToolError(f"{' '.join(argv)}: no answer in {TOOL_TIMEOUT_S:g} s") from None


def _refused(what: str, done: subprocess.CompletedProcess[str]) -> ToolError:
    reason = " ".join(done.stderr.split())[:300] or f"exit {done.returncode}"
    return ToolError(f"{what}: {reason}")


@dataclass(frozen=True, slots=True)
class _Live:
    """What ``--check`` found loaded by one backend."""

    diff: list[str]  # ``differences``: [] when it matches
    dropped: dict[str, int]  # a port's comment -> the datagrams its rule dropped


class _Nft:
    name: Final = "nft"
    where: Final = f"table {FAMILY} {TABLE}"

    def apply(self, wanted: LocalFirewall) -> None:
        done = _tool(["nft", "-f", "-"], wanted.script())
        if done.returncode != 0:
            raise _refused("nft -f", done)

    def inspect(self, wanted: LocalFirewall) -> _Live | None:
        # -nnn: uids and ports as numbers; nft 0.8 (Ubuntu 18.04) prints user and service
        # names at fewer -n ("Specify three times ...", its --help), 0.9.1+ takes any count
        done = _tool(["nft", "-nnn", "list", "table", FAMILY, TABLE])
        if done.returncode == 0:
            return _Live(differences(done.stdout, wanted), dropped(done.stdout))
        if _no_table(done):
            return None
        raise _refused(f"nft list table {FAMILY} {TABLE}", done)

    def remove(self) -> None:
        done = _tool(["nft", "delete", "table", FAMILY, TABLE])
        if done.returncode != 0 and not _no_table(done):
            raise _refused(f"nft delete table {FAMILY} {TABLE}", done)


def _no_table(done: subprocess.CompletedProcess[str]) -> bool:
    return "No such file or directory" in done.stderr  # ENOENT: the table is not there


class _Xtables:
    name: Final = "iptables"
    where: Final = f"chain {XT_CHAIN} of iptables and ip6tables"

    def apply(self, wanted: LocalFirewall) -> None:
        for version in XT_VERSIONS:
            self._restore(version, wanted.xt_script(version, self._live(version)))

    def inspect(self, wanted: LocalFirewall) -> _Live | None:
        lives = {version: self._live(version) for version in XT_VERSIONS}
        if not any(live.loaded for live in lives.values()):
            return None
        diff: list[str] = []
        counts: dict[str, int] = {}
        for version, live in lives.items():
            diff += [f"IPv{version}: {line}" for line in wanted.xt_differences(version, live)]
            for comment, count in live.dropped.items():
                counts[comment] = counts.get(comment, 0) + count
        return _Live(diff, counts)

    def remove(self) -> None:
        for version in XT_VERSIONS:
            script = xt_removal(self._live(version))
            if script is not None:
                self._restore(version, script)

    @staticmethod
    def _live(version: int) -> XtLive:
        save = [_xt_tool(version, "save"), "-c", "-t", "filter"]
        done = _tool(save)
        if done.returncode != 0:
            raise _refused(" ".join(save), done)
        return xt_live(done.stdout)

    @staticmethod
    def _restore(version: int, script: str) -> None:
        # --noflush: only swarmd's chain and its jump change, every other rule stays
        tool = _xt_tool(version, "restore")
        restore = [tool, *_lock_wait(tool), "--noflush"]
        done = _tool(restore, script)
        if done.returncode != 0:
            raise _refused(" ".join(restore), done)


def _lock_wait(tool: str) -> list[str]:
    """``--wait=N`` when ``tool`` takes it, else nothing. iptables-restore 1.6.2+ takes the
    xtables lock and, without ``--wait``, fails at once while another program holds it
    (iptables 999eaa24, "iptables-restore: support acquiring the lock"); 1.6.1 (Ubuntu
    18.04, the Nano) takes no lock and refuses the option. So its ``--help`` is asked (stdin
    empty: an old one that goes on to read rules finds none), not its version guessed."""
    done = _tool([tool, "--help"], "")
    return [f"--wait={XT_LOCK_WAIT_S}"] if "--wait" in done.stdout + done.stderr else []


def _xt_tool(version: int, verb: str) -> str:
    return f"{'iptables' if version == 4 else 'ip6tables'}-{verb}"


_Backend = _Nft | _Xtables
ALL: Final[tuple[_Backend, ...]] = (_Nft(), _Xtables())


def _chosen(backend: str) -> tuple[_Backend, ...]:
    """The backends to try, in order: ``auto`` is nft, then iptables."""
    return tuple(b for b in ALL if backend in ("auto", b.name))


def _none_answered(reasons: list[str]) -> ToolError:
    return ToolError(f"{'; '.join(reasons)}; {FIX}")


def _apply(wanted: LocalFirewall, backends: tuple[_Backend, ...]) -> int:
    reasons: list[str] = []
    for backend in backends:
        try:
            backend.apply(wanted)
        except ToolError as exc:
            reasons.append(f"{backend.name}: {exc}")
            continue
        # the other backend's rules of an older start (another config, another kernel):
        # removed where its tool answers; where it is missing or refused, nothing is loaded
        for other in ALL:
            if other is not backend:
                try:
                    other.remove()
                except ToolError:
                    pass
        for reason in reasons:
            print(f"swarmd: local-firewall: note: not loaded by {reason}", file=sys.stderr)
        print(f"swarmd: local-firewall: loaded by {backend.name}: {backend.where}")
        return EX_OK
    if not wanted.ports:
        return _nothing_to_guard(wanted, reasons)
    raise _none_answered(reasons)


def _nothing_to_guard(wanted: LocalFirewall, reasons: list[str]) -> int:
    """A config that guards no port has no rule to lose: a drone without nft or iptables
    still starts (the unit's ``ExecStartPre``), and says why nothing is loaded. Residual (6)
    is unchanged: it is about ports left to every user, which these notes name
    (docs/security.md; docs/deploy.md, "The local firewall")."""
    for reason in reasons:
        print(f"swarmd: local-firewall: note: not loaded by {reason}", file=sys.stderr)
    print(
        f"swarmd: local-firewall: nothing loaded: {wanted.file} guards no port (no "
        "ros2.node_users with ros2.relay, no px4.loopback_user with a loopback xrce-agent), "
        "so there is no rule to load"
    )
    return EX_OK


def _check(wanted: LocalFirewall, backends: tuple[_Backend, ...]) -> int:
    found: list[tuple[_Backend, _Live]] = []
    reasons: list[str] = []
    for backend in backends:
        try:
            live = backend.inspect(wanted)
        except ToolError as exc:
            reasons.append(f"{backend.name}: {exc}")
            continue
        if live is not None:
            found.append((backend, live))
    if not found:
        if not wanted.ports:  # no rule is wanted, so none is missing
            return _nothing_to_guard(wanted, reasons)
        if len(reasons) == len(backends):
            raise _none_answered(reasons)
        where = ", ".join(f"no {b.where}" for b in backends)
        print(f"swarmd: local-firewall: not loaded ({where})", file=sys.stderr)
        return EX_FAILED
    status = EX_OK
    for backend, live in found:
        if live.diff:
            print(
                f"swarmd: local-firewall: {backend.name}: {backend.where} differs from "
                f"{wanted.file} (- wanted, + live); fix: swarmd local-firewall --apply, or "
                "restart swarmd",
                file=sys.stderr,
            )
            for line in live.diff:
                print(f"  {line}", file=sys.stderr)
            status = EX_FAILED
            continue
        print(f"swarmd: local-firewall: {backend.name}: {backend.where} matches {wanted.file}")
        for port in wanted.ports:
            count = live.dropped.get(port.comment, 0)
            print(f"  {port.comment}: dropped {count} datagrams of other users")
    return status


def _remove(backends: tuple[_Backend, ...]) -> int:
    reasons: list[str] = []
    for backend in backends:
        try:
            backend.remove()
        except ToolError as exc:
            reasons.append(f"{backend.name}: {exc}")
    if len(reasons) == len(backends):
        raise _none_answered(reasons)
    return EX_OK


def _printed(wanted: LocalFirewall, backend: str) -> str:
    """What ``--apply`` would load on a host without swarmd's rules: the nft script, or
    (``iptables``) each IP version's ``-restore --noflush`` input."""
    if backend != "iptables":
        return wanted.script()
    empty = XtLive(None, {}, 0, False)
    return "".join(
        f"# {_xt_tool(version, 'restore')} --noflush\n{wanted.xt_script(version, empty)}"
        for version in XT_VERSIONS
    )


def run(args: argparse.Namespace) -> int:
    """``swarmd local-firewall``; one line on stderr for every failure."""
    backends = _chosen(args.backend)
    try:
        if args.remove:
            return _remove(backends)
        if args.config is None:
            print("swarmd: local-firewall: --config FILE is needed", file=sys.stderr)
            return EX_CONFIG
        try:
            wanted = local_firewall(load_config(args.config))
        except ConfigError as exc:
            print(f"swarmd: config rejected: {exc}", file=sys.stderr)
            return EX_CONFIG
        for note in wanted.notes:
            print(f"swarmd: local-firewall: note: {note}", file=sys.stderr)
        if args.check:
            return _check(wanted, backends)
        if args.apply:
            return _apply(wanted, backends)
        print(_printed(wanted, args.backend), end="")
        return EX_OK
    except ToolError as exc:
        print(f"swarmd: local-firewall: {exc}", file=sys.stderr)
        return EX_UNAVAILABLE
