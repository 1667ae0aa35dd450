"""``swarmd``: the daemon entry point (``swarmd run --config FILE``).

Exit codes (sysexits): 0 clean stop (SIGTERM/SIGINT), 2 usage, 69 the control socket is
held by another live swarmd, 71 a UDP socket cannot be bound or joined, 73 a state file
(boot epoch, bundle floor) cannot be written or its folder is unsafe, 78 bad config or a
rejected bundle, a rolled-back one included (systemd's ``RestartPreventExitStatus=78``
stops a restart loop on those).
Every failure before the loop runs is one line on stderr, never a traceback.
``swarmd local-firewall`` (swarmd.cli.firewall_cmd) has its own codes.

``main(argv, before_run=...)`` takes an optional hook called after the config and bundle
are loaded and before any socket is opened; a ``StartupError`` it raises ends the run with
that one line and its exit code. The daemon sets none; the testbed's fair start
(``swarmd_lab.start_barrier``, ``SWARMD_START_BARRIER``) is such a hook, outside this entry
point.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Sequence
from dataclasses import fields
from typing import TYPE_CHECKING

from swarmd import __version__
from swarmd.cli import firewall_cmd
from swarmd.config import ConfigError, load_config
from swarmd.exitcodes import EX_CONFIG, EX_USAGE, StartupError

if TYPE_CHECKING:
    from swarmd.cli.sandbox_check import Unit


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="swarmd",
        description="swarmd: discovery and command daemon of a PX4 drone swarm "
        "(docs/operations.md)",
    )
    parser.add_argument("--version", action="version", version=f"swarmd {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    run = sub.add_parser("run", help="run the daemon in the foreground (systemd Type=notify)")
    run.add_argument("--config", required=True, metavar="FILE", help="daemon config file (YAML)")
    check = sub.add_parser(
        "check-config",
        help="check a config file, its bundle and the state folders, then exit",
        # the same codes as run's: both call the same check functions (docs/operations.md)
        description="Run every start-up check of 'swarmd run' that neither binds, sends nor "
        "writes: the config, the bundle it names, the state folders (as the unit's user, "
        "under the unit's sandbox), the PX4 link's endpoint. Exit 0 ok; else run's one "
        "line and run's code: 78 config or bundle, 73 a state folder, 71 an endpoint, "
        "69 the control socket's folder.",
    )
    check.add_argument("--config", required=True, metavar="FILE", help="daemon config file (YAML)")
    check.add_argument(
        "--user",
        metavar="NAME",
        help="judge the state folders for this user, overriding the unit's (default: the "
        "unit's User=, Group=, SupplementaryGroups= and DynamicUser=; no unit found: as "
        "root, swarmd when it exists, else the user running the check)",
    )
    check.add_argument(
        "--unit",
        metavar="PATH",
        help="judge the folders the daemon writes under this unit file's sandbox "
        "(default: the installed unit, systemctl cat swarmd; none found: not judged)",
    )
    firewall_cmd.register(sub)
    return parser


def _fail(message: str, code: int) -> int:
    print(f"swarmd: {message}", file=sys.stderr)
    return code


def main(argv: Sequence[str] | None = None, *, before_run: Callable[[], None] | None = None) -> int:
    """``swarmd`` itself; ``before_run`` runs between loading and binding (see above)."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command == "local-firewall":
        return firewall_cmd.run(args)
    if args.command not in ("run", "check-config"):
        parser.print_help(sys.stderr)
        return EX_USAGE
    # imported here so `swarmd --help` stays fast and works without the engine's deps
    from swarmd import logs
    from swarmd.bundle.errors import BundleError
    from swarmd.bundle.loader import load_bundle
    from swarmd.bundle.statedir import DaemonUser
    from swarmd.daemon import Daemon, run
    from swarmd.daemon_setup import NodeSecretsError, enforce_bundle_floor, load_node_secrets
    from swarmd.discovery.config import EngineConfig
    from swarmd.rawclock import run_on_raw_clock

    engine_fields = frozenset(f.name for f in fields(EngineConfig)) - {"mode"}
    try:
        config = load_config(args.config, engine_fields=engine_fields)
    except ConfigError as exc:
        return _fail(f"config rejected: {exc}", EX_CONFIG)
    user: DaemonUser | None = None  # check-config's: whose view it judges from
    unit: Unit | None = None
    if args.command == "check-config":
        # check-config's own (the unit file, its user): `run` does not import them
        from swarmd.cli.sandbox_check import load_unit, sandbox_note
        from swarmd.cli.unit_user import judged_user

        try:
            # the unit run will run under: its sandbox and whom it runs the daemon as
            unit = load_unit(args.unit)
            user = judged_user(args.user, unit)
        except StartupError as exc:
            return _fail(str(exc), exc.exit_code)
    try:
        # before the bundle or its key is believed; files of the daemon's user are its own
        config.check_trusted_files(user.own_uid if user else frozenset())
    except ConfigError as exc:
        return _fail(f"config rejected: {exc}", EX_CONFIG)
    logs.configure(config.log_level, config.log_format)
    log = logs.get_logger(node=config.node)
    try:
        bundle = load_bundle(
            config.bundle.path,
            config.bundle.trusted_key,
            expected_sha256=config.bundle.expected_sha256,
            allow_dev=config.bundle.allow_dev,
            # read through the folders just judged (safeopen: swapped since: refused)
            trusted_owners=user.own_uid if user else frozenset(),
        )
    except BundleError as exc:
        return _fail(f"bundle rejected: {exc}", EX_CONFIG)
    try:
        config.member_of(bundle)
    except ConfigError as exc:
        return _fail(f"config rejected: {exc}", EX_CONFIG)
    try:
        secrets = load_node_secrets(config, bundle, user.own_uid if user else frozenset())
    except NodeSecretsError as exc:
        return _fail(f"node key rejected: {exc}", EX_CONFIG)
    # the anti-rollback floor (docs/security.md, "Bundle rollback"), read only: a refusal
    # here is one line before anything runs; Daemon.start checks again and raises the floor
    # (`check-config` never does: a bundle checked but not run must not lock out the
    # bundle the drone runs now)
    try:
        enforce_bundle_floor(config, bundle, commit=False, user=user)
    except StartupError as exc:
        return _fail(str(exc), exc.exit_code)
    if user is not None:  # check-config
        try:
            # every check of `run`'s start that neither binds, sends nor writes, so this
            # refuses what `run` refuses, with its line (docs/operations.md, "Exit codes")
            daemon = Daemon(config, bundle, log=log, node_secrets=secrets)
            notes = daemon.check_state(daemon.check_start(), user)
        except ConfigError as exc:
            return _fail(f"config rejected: {exc}", EX_CONFIG)
        except StartupError as exc:
            return _fail(str(exc), exc.exit_code)
        try:
            # run's writes under the unit's ProtectSystem= and friends (check-config runs
            # outside that sandbox, so the folder checks above cannot see it)
            sandbox = sandbox_note(config, unit)
        except StartupError as exc:
            return _fail(str(exc), exc.exit_code)
        for note in notes:  # `run` logs these as warnings and starts
            print(f"swarmd: warning: {note}", file=sys.stderr)
        print(
            f"swarmd: {args.config}: ok (node {config.node}, swarm {bundle.swarm}), "
            f"state folders judged as {user.name} ({user.source}); {sandbox}"
        )
        return 0
    if before_run is not None:
        try:
            before_run()
        except StartupError as exc:
            return _fail(str(exc), exc.exit_code)
    try:
        # the loop's clock is the crystal's, never NTP's slew: every validity rests on it
        return run_on_raw_clock(run(config, bundle, log=log, node_secrets=secrets))
    except ConfigError as exc:
        return _fail(f"config rejected: {exc}", EX_CONFIG)
    except StartupError as exc:
        return _fail(str(exc), exc.exit_code)


if __name__ == "__main__":
    sys.exit(main())
