"""``swarmctl px4 key | setup-signing``: the drone's MAVLink 2 signing key, and giving it to PX4.

The key is the one the daemon derives (``swarmd.px4.provision``, HKDF from the node key):
on the ground from the keygen directory (``--keys DIR --swarm NAME --node NAME``), on the
drone from its own config (``--config /etc/swarmd/swarmd.yaml``). ``--out FILE`` writes
PX4's 40-byte ``/mavlink/mavlink-signing-key.bin`` (key + u64 LE timestamp, mode 0600) for
the SD card, or the simulator's ``--signing-key``; without ``--out`` the 64 hex digits go to
stdout. ``setup-signing --connection udpout:...|serial:...`` sends it to the autopilot as
``SETUP_SIGNING`` and waits for a HEARTBEAT signed with it (exit 0), or says why not (exit 1).
docs/px4.md, "Message signing".

Exit codes: 0 ok; 1 the autopilot did not confirm the key; 65 a key, keygen directory or
``--connection`` that is not valid input; 71 the connection could not be opened; 73
``--out`` cannot be written; 78 a bad config (swarmd.exitcodes; docs/operations.md).
"""

from __future__ import annotations

import argparse
import asyncio
import hashlib
import sys
import time
from pathlib import Path
from typing import Any

from swarmd.bundle.errors import BundleError
from swarmd.bundle.keys import PRIVATE_MODE, node_key_path, write_file_atomic
from swarmd.config import ConfigError, load_config
from swarmd.exitcodes import EX_CANTCREAT, EX_CONFIG, EX_DATAERR, EX_FAILED, EX_OSERR
from swarmd.px4.provision import (
    SigningKeyError,
    ed25519_seed,
    node_secret,
    setup_signing,
    signing_key_for,
)
from swarmd.px4.signing import derive_key, parse_key_file, px4_key_file, timestamp_from_unix
from swarmd.px4.transport import parse_connection


def register(sub: Any) -> None:
    px4: argparse.ArgumentParser = sub.add_parser(
        "px4", help="PX4 link tools (the MAVLink signing key)"
    )
    psub = px4.add_subparsers(dest="px4_command", metavar="SUBCOMMAND")

    def usage(_args: argparse.Namespace) -> int:
        px4.print_help(sys.stderr)
        return 2

    px4.set_defaults(func=usage)
    p = psub.add_parser("key", help="derive a drone's MAVLink signing key (hex, or PX4's file)")
    _key_source(p)
    p.add_argument("--out", metavar="FILE", help="write PX4's 40-byte key file (mode 0600)")
    p.set_defaults(func=cmd_key)
    p = psub.add_parser(
        "setup-signing", help="send the key to PX4 (SETUP_SIGNING) on a bench link and confirm"
    )
    _key_source(p)
    p.add_argument(
        "--connection", required=True, metavar="CONN",
        help="udpout:HOST:PORT (SITL: udpout:127.0.0.1:14580) or serial:DEV:BAUD (PX4's USB)",
    )  # fmt: skip
    p.add_argument("--sysid", type=int, default=1, help="the autopilot's MAV_SYS_ID")
    p.add_argument(
        "--current-key", metavar="FILE",
        help="the key PX4 holds now (to rotate: PX4 takes a new key only signed with it)",
    )  # fmt: skip
    p.add_argument("--timeout", type=float, default=5.0, metavar="S", help="give up after S s")
    p.set_defaults(func=cmd_setup_signing)


def _key_source(p: argparse.ArgumentParser) -> None:
    p.add_argument("--config", metavar="FILE", help="on the drone: derive as the daemon does")
    p.add_argument("--keys", metavar="DIR", help="on the ground: the keygen directory")
    p.add_argument("--swarm", metavar="NAME", help="with --keys: the bundle's swarm name")
    p.add_argument("--node", metavar="NAME", help="with --keys: the drone's name")


def _fail(message: str, code: int) -> int:
    print(f"swarmctl px4: {message}", file=sys.stderr)
    return code


def _key(args: argparse.Namespace) -> bytes:
    if args.config is not None:
        from swarmd.bundle.loader import load_bundle

        config = load_config(args.config)
        bundle = load_bundle(
            config.bundle.path,
            config.bundle.trusted_key,
            expected_sha256=config.bundle.expected_sha256,
            allow_dev=config.bundle.allow_dev,
        )
        from swarmd.daemon_setup import NodeSecretsError, load_node_secrets

        seed = b""
        if config.px4.signing_key is None:  # derived, as the daemon does
            try:
                seed = ed25519_seed(load_node_secrets(config, bundle).ed25519)
            except NodeSecretsError as exc:
                raise SigningKeyError(str(exc)) from None
        return signing_key_for(
            swarm=bundle.swarm, node=config.node, key_file=config.px4.signing_key, seed=seed
        )
    if args.keys is None or args.swarm is None or args.node is None:
        raise SigningKeyError(
            "give --config FILE (on the drone) or --keys DIR --swarm NAME --node NAME; "
            "fix: see 'swarmctl px4 key --help'"
        )
    return derive_key(node_secret(node_key_path(args.keys, args.node)), args.swarm, args.node)


def _checked_key(args: argparse.Namespace) -> bytes | int:
    """The key, or the exit code after one line on stderr."""
    try:
        return _key(args)
    except ConfigError as exc:
        return _fail(f"config rejected: {exc}", EX_CONFIG)
    except (BundleError, SigningKeyError, ValueError) as exc:
        return _fail(str(exc), EX_DATAERR)


def _label(key: bytes) -> str:
    return "SHA256:" + hashlib.sha256(key).digest()[:8].hex()  # to compare keys, not the key


def cmd_key(args: argparse.Namespace) -> int:
    key = _checked_key(args)
    if isinstance(key, int):
        return key
    label = _label(key)
    if args.out is None:
        print(key.hex())
        print(f"key {label}", file=sys.stderr)
        return 0
    try:
        data = px4_key_file(key, timestamp_from_unix(time.time()))
        write_file_atomic(Path(args.out), data, PRIVATE_MODE)
    except OSError as exc:
        return _fail(f"{args.out}: {exc.strerror}", EX_CANTCREAT)
    print(f"wrote {args.out} (PX4 /mavlink/mavlink-signing-key.bin, key {label})")
    return 0


def cmd_setup_signing(args: argparse.Namespace) -> int:
    try:
        endpoint = parse_connection(args.connection, "--connection")
    except ValueError as exc:
        return _fail(str(exc), EX_DATAERR)
    if endpoint.kind == "udpin":
        return _fail(
            f"--connection {endpoint}: setup-signing speaks first; fix: udpout:HOST:PORT "
            "(PX4 SITL: udpout:127.0.0.1:14580) or serial:/dev/ttyACM0:115200 (PX4's USB)",
            EX_DATAERR,
        )
    key = _checked_key(args)
    if isinstance(key, int):
        return key
    try:
        current = None
        if args.current_key is not None:
            current = parse_key_file(Path(args.current_key).read_bytes(), args.current_key)
        ok = asyncio.run(
            setup_signing(endpoint, args.sysid, key, current_key=current, timeout_s=args.timeout)
        )
    except OSError as exc:
        return _fail(f"{args.connection}: {exc.strerror or exc}", EX_OSERR)
    except ValueError as exc:
        return _fail(str(exc), EX_DATAERR)
    if not ok:
        return _fail(
            f"no HEARTBEAT from system {args.sysid} signed with key {_label(key)} within "
            f"{args.timeout:g} s; fix: PX4 >= v1.17 (v1.17's first version takes SETUP_SIGNING "
            "on USB only), disarmed, and --current-key if PX4 already holds a key",
            EX_FAILED,
        )
    print(f"PX4 system {args.sysid} signs with key {_label(key)} ({args.connection})")
    return 0
