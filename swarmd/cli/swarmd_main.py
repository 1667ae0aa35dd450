"""``swarmd``: the daemon entry point (``swarmd run --config FILE``)."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from swarmd import __version__


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="swarmd", description="swarmd discovery daemon")
    parser.add_argument("--version", action="version", version=f"swarmd {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    run = sub.add_parser("run", help="run the daemon in the foreground (systemd Type=notify)")
    run.add_argument("--config", required=True, help="daemon config file (YAML)")
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command != "run":
        parser.print_help(sys.stderr)
        return 2
    print("swarmd: the daemon is not built yet", file=sys.stderr)
    return 69


if __name__ == "__main__":
    sys.exit(main())
