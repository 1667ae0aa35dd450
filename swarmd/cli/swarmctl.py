"""``swarmctl``: the operator's tool, on the ground laptop and over SSH on each drone.

Each command group lives in its own module with a ``register(subparsers)`` function that adds
its parser and sets ``func`` (returning the exit code). Exit codes follow sysexits where one
fits: 0 ok, 1 a check failed, 2 a bad command line (argparse) or daemon not reachable, 3
``takeoff --require-all`` with a drone not ready, 64 a command's targets used incorrectly,
65 bad input data, 69/71/73 a service, a system call or an output file refused, 78 bad
configuration, 130 interrupted (swarmd.exitcodes; docs/operations.md, "Exit codes").
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from typing import Final

from swarmd import __version__
from swarmd.cli import bundle_cmd, outcomes_cmd, px4_cmd, ros2_cmd, status_cmd, takeoff_cmd
from swarmd.cli.pipes import reader_may_close_stdout

# The exit codes in one place an operator finds them (session 17: only each command's own
# --help and docs/operations.md had them); tests/test_cmd_operator.py checks it against the
# swarmctl column of operations.md's "Exit codes" table.
EPILOG: Final = (
    "Exit codes (each command's --help has its own; docs/operations.md, 'Exit codes'): 0 ok; "
    "1 a check failed (takeoff/land/hold/abort: a drone did not confirm the command; "
    "outcomes: a drone did not execute one); 2 a bad command line, or the daemon is not "
    "reachable (nothing sent); 3 takeoff --require-all: not every drone became ready "
    "(nothing sent); 64 a command used wrongly; 65 bad input data; 71 a connection cannot be "
    "opened; 73 an output cannot be written; 78 bad configuration or a bundle that fails "
    "verification; 130 interrupted (a command already sent keeps running: swarmctl names "
    "it); 141 the reader closed stdout early."
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="swarmctl",
        description="Operate swarmd: build and flash firmware bundles, inspect discovery, "
        "command the swarm.",
        epilog=EPILOG,
    )
    parser.add_argument("--version", action="version", version=f"swarmctl {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for module in (bundle_cmd, status_cmd, takeoff_cmd, outcomes_cmd, px4_cmd, ros2_cmd):
        module.register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    with reader_may_close_stdout():
        args = parser.parse_args(argv)
        func = getattr(args, "func", None)
        if func is None:
            parser.print_help(sys.stderr)
            return 2
        code: int = func(args)
    return code


if __name__ == "__main__":
    sys.exit(main())
