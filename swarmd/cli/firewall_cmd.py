"""``swarmd local-firewall``: the nftables table that lets only the configured users send to
swarmd's loopback ports (swarmd.localfirewall; docs/security.md, "The local user",
residual (6); docs/operations.md, "The local firewall").

- ``--config FILE``: print it, as ``nft -f`` input that replaces an older table at once;
- ``--config FILE --apply``: load it (the unit's ``ExecStartPre=+``, as root);
- ``--config FILE --check``: compare it with the live table and print each rule's drops;
- ``--remove``: delete the table, if there is one (the unit's ``ExecStopPost=+``).

Exit codes: 0 ok; 1 ``--check`` found the table missing or different; 69 ``nft`` is missing
or refused (``--apply``: systemd then fails the start); 78 the config is rejected. A port
whose users are not configured is a note on stderr, not a failure. This is the thin tier:
every ``nft`` call is here, the text comes from swarmd.localfirewall.
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys

from swarmd.config import ConfigError, load_config
from swarmd.exitcodes import EX_CONFIG, EX_FAILED, EX_OK, EX_UNAVAILABLE
from swarmd.localfirewall import FAMILY, TABLE, LocalFirewall, differences, dropped, local_firewall

NFT_TIMEOUT_S = 10.0


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser(
        "local-firewall",
        help="the nftables table that lets only the configured users send to swarmd's "
        "loopback ports (print, --apply, --check, --remove)",
    )
    p.add_argument("--config", help="daemon config file (YAML); all but --remove need it")
    mode = p.add_mutually_exclusive_group()
    mode.add_argument("--apply", action="store_true", help="load it now (root)")
    mode.add_argument(
        "--check", action="store_true", help="exit 1 when the live table is missing or differs"
    )
    mode.add_argument("--remove", action="store_true", help="delete the table (root)")


class NftError(Exception):
    """``nft`` is missing or failed: one line."""


def _nft(args: list[str], script: str | None = None) -> subprocess.CompletedProcess[str]:
    nft = shutil.which("nft")
    if nft is None:
        raise NftError("nft not found; fix: install nftables (Debian: apt-get install nftables)")
    try:
        return subprocess.run(  # noqa: S603 - fixed argv, no shell
            [nft, *args],
            input=script,
            capture_output=True,
            text=True,
            timeout=NFT_TIMEOUT_S,
            check=False,
        )
    except subprocess.TimeoutExpired:
        raise NftError(f"nft {' '.join(args)}: no answer in {NFT_TIMEOUT_S:g} s") from None


def _failed(what: str, done: subprocess.CompletedProcess[str]) -> NftError:
    reason = " ".join(done.stderr.split())[:300] or f"exit {done.returncode}"
    return NftError(f"{what}: {reason}; fix: run as root, with nf_tables in the kernel")


def _live() -> str | None:
    """The live table as ``nft list`` prints it; None when there is none."""
    done = _nft(["list", "table", FAMILY, TABLE])
    if done.returncode == 0:
        return done.stdout
    if "No such file or directory" in done.stderr:
        return None
    raise _failed(f"nft list table {FAMILY} {TABLE}", done)


def _check(wanted: LocalFirewall) -> int:
    live = _live()
    if live is None:
        print(f"swarmd: local-firewall: table {FAMILY} {TABLE} is not loaded", file=sys.stderr)
        return EX_FAILED
    diff = differences(live, wanted)
    if diff:
        print(
            f"swarmd: local-firewall: table {FAMILY} {TABLE} differs from {wanted.file} "
            "(- wanted, + live); fix: swarmd local-firewall --apply, or restart swarmd",
            file=sys.stderr,
        )
        for line in diff:
            print(f"  {line}", file=sys.stderr)
        return EX_FAILED
    counts = dropped(live)
    print(f"swarmd: local-firewall: table {FAMILY} {TABLE} matches {wanted.file}")
    for port in wanted.ports:
        print(f"  {port.comment}: dropped {counts.get(port.comment, 0)} datagrams of other users")
    return EX_OK


def run(args: argparse.Namespace) -> int:
    """``swarmd local-firewall``; one line on stderr for every failure."""
    try:
        if args.remove:
            done = _nft(["delete", "table", FAMILY, TABLE])
            if done.returncode != 0 and "No such file or directory" not in done.stderr:
                raise _failed(f"nft delete table {FAMILY} {TABLE}", done)
            return EX_OK
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
            return _check(wanted)
        if args.apply:
            done = _nft(["-f", "-"], wanted.script())
            if done.returncode != 0:
                raise _failed("nft -f", done)
            return EX_OK
        print(wanted.script(), end="")
        return EX_OK
    except NftError as exc:
        print(f"swarmd: local-firewall: {exc}", file=sys.stderr)
        return EX_UNAVAILABLE
