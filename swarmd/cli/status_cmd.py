"""``swarmctl status | peers | watch``: ask the local daemon over its control socket."""

from __future__ import annotations

import argparse
from typing import Any


def register(sub: Any) -> None:
    parser: argparse.ArgumentParser = sub.add_parser("status", help="show this drone's discovery state")
    parser.set_defaults(func=lambda _args: (parser.print_help(), 2)[1])
