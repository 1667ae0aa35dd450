"""``swarmctl bundle ...``: build, keygen, verify, show and flash firmware bundles."""

from __future__ import annotations

import argparse
from typing import Any


def register(sub: Any) -> None:
    parser: argparse.ArgumentParser = sub.add_parser(
        "bundle", help="build, sign, verify, show and flash firmware bundles"
    )
    parser.set_defaults(func=lambda _args: (parser.print_help(), 2)[1])
