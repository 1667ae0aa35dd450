"""``swarmctl ros2 profile``: the Fast DDS profiles of the swarm's stock ROS 2 nodes.

Writes, for each drone that runs a node of the bundle's ROS 2 graph, ``<out>/<drone>/``:
``<node>.xml`` (the participant with the bundle's GUID prefix and ports, unicast-only
discovery, static EDP), ``<node>.env`` (the environment to start the node with) and
``static-edp.xml`` (every endpoint of the swarm). docs/ros2.md says how an operator uses them.

``swarmctl ros2 check BUNDLE --profiles DIR`` (preflight, docs/preflight.md) regenerates the
same files from the flashed bundle and refuses any installed file that differs.

Exit codes as ``swarmctl bundle``: 0 ok, 2 usage, 65 the bundle has no ROS 2 graph, a drone
has no address, or (check) an installed profile differs, 73 an output could not be written,
78 a bundle that fails verification.
"""

from __future__ import annotations

import argparse
import ipaddress
import json
import os
from pathlib import Path
from typing import Any

from swarmd.bundle.ros2 import bundle_ros2_participants
from swarmd.cli.bundle_cmd import _err, _guard, _load, _trust_args
from swarmd.exitcodes import EX_BAD_ARGS, EX_CANTCREAT, EX_DATAERR, EX_OK
from swarmd.ros2.profile import ProfileError, ProfileFile, drone_profiles
from swarmd.ros2.relay import DEFAULT_RELAY_PORT


def register(sub: Any) -> None:
    ros2 = sub.add_parser("ros2", help="stock ROS 2 nodes on the swarm (docs/ros2.md)")
    ros2_sub = ros2.add_subparsers(dest="ros2_command", metavar="SUBCOMMAND")

    def usage(_args: argparse.Namespace) -> int:
        ros2.print_help()
        return EX_BAD_ARGS

    ros2.set_defaults(func=usage)
    p = ros2_sub.add_parser(
        "profile", help="write each drone's Fast DDS XML and environment files from a bundle"
    )
    p.add_argument("bundle", metavar="BUNDLE")
    p.add_argument("--out", required=True, metavar="DIR", help="writes DIR/<drone>/...")
    _generation_args(p)
    p.add_argument("--json", action="store_true", help="print the files written as JSON")
    _trust_args(p)
    p.set_defaults(func=cmd_profile)
    c = ros2_sub.add_parser(
        "check",
        help="preflight: refuse installed profiles that differ from what BUNDLE gives",
    )
    c.add_argument("bundle", metavar="BUNDLE", help="the flashed bundle")
    c.add_argument(
        "--profiles",
        required=True,
        metavar="DIR",
        help="the installed files: DIR/<drone>/... as 'ros2 profile --out DIR' wrote them, or "
        "with one --drone the drone's own folder (e.g. /etc/swarmd/ros2)",
    )
    _generation_args(c)
    c.add_argument("--json", action="store_true", help="print the verdict as JSON")
    _trust_args(c)
    c.set_defaults(func=cmd_check)


def _generation_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--drone", action="append", metavar="NAME", help="only this drone (repeat)")
    p.add_argument(
        "--install-dir",
        metavar="DIR",
        help="where the files will live on each drone ({drone} is replaced; default: the "
        "absolute path of DIR/<drone>)",
    )
    p.add_argument(
        "--address",
        action="append",
        default=[],
        metavar="NAME=A.B.C.D",
        help="a drone's address when the mission has no ipv4 for it (repeat)",
    )
    p.add_argument(
        "--via-swarmd",
        action="store_true",
        help="discovery through the drone's swarmd on loopback: no ROS 2 discovery frame on "
        "the air (needs ros2.relay in swarmd's config; docs/ros2.md)",
    )
    p.add_argument(
        "--relay-port",
        type=int,
        default=DEFAULT_RELAY_PORT,
        metavar="PORT",
        help=f"swarmd's relay port on [::1] (default {DEFAULT_RELAY_PORT}, as ros2.relay_port)",
    )


def _expected(args: argparse.Namespace, out: Path) -> list[ProfileFile] | int:
    """The files BUNDLE gives for the selected drones, or an exit code (error printed)."""
    bundle = _load(args, inspect=False).bundle
    if bundle.ros2 is None:
        _err(
            f"{args.bundle}: the bundle declares no ROS 2 graph; fix: add a 'ros2:' section to "
            "the mission (docs/ros2.md) and rebuild with 'swarmctl bundle build'"
        )
        return EX_DATAERR
    addresses = {p.name: p.ipv4 for p in bundle.participants if p.ipv4 is not None}
    for item in args.address:
        name, _, address = item.partition("=")
        try:
            ipaddress.IPv4Address(address)
        except ValueError:
            _err(f"--address {item!r}: not NAME=A.B.C.D; fix: e.g. --address drone-2=10.42.0.12")
            return EX_BAD_ARGS
        addresses[name] = address
    if not 1 <= args.relay_port <= 65535:
        _err(f"--relay-port {args.relay_port}: not a UDP port; fix: 1..65535 (default 7399)")
        return EX_BAD_ARGS
    participants = bundle_ros2_participants(bundle)
    drones = sorted({p.drone for p in participants}, key=lambda d: bundle.member(d).index)
    for name in args.drone or []:
        if name not in drones:
            _err(
                f"--drone {name!r}: runs no ROS 2 node of this bundle; fix: use one of "
                f"{', '.join(drones)}"
            )
            return EX_BAD_ARGS
    files: list[ProfileFile] = []
    for drone in args.drone or drones:
        if args.install_dir is not None:
            install = str(args.install_dir).replace("{drone}", drone)
        else:
            install = str((out / drone).absolute())
        try:
            files += drone_profiles(
                bundle.ros2,
                participants,
                addresses,
                drone,
                install,
                relay_port=args.relay_port if args.via_swarmd else None,
            )
        except ProfileError as exc:
            _err(f"{args.bundle}: {exc}")
            return EX_DATAERR
    return files


@_guard
def cmd_profile(args: argparse.Namespace) -> int:
    out = Path(args.out)
    files = _expected(args, out)
    if isinstance(files, int):
        return files
    written: list[str] = []
    try:
        for f in files:
            path = out / f.path
            path.parent.mkdir(parents=True, exist_ok=True)
            tmp = path.with_name(path.name + ".tmp")
            tmp.write_text(f.text)
            os.replace(tmp, path)
            written.append(str(path))
    except OSError as exc:
        _err(f"{out}: cannot write ({exc.strerror}); fix: choose a writable --out")
        return EX_CANTCREAT
    if args.json:
        print(json.dumps({"ok": True, "files": written}, indent=2))
    else:
        for path_text in written:
            print(path_text)
    return EX_OK


@_guard
def cmd_check(args: argparse.Namespace) -> int:
    """Every file the bundle gives must be installed with exactly that text: a profile from
    another bundle (other ids, prefixes, ports or peers) matches nothing, silently, in Fast
    DDS (docs/ros2.md), so preflight refuses it here instead."""
    root = Path(args.profiles)
    files = _expected(args, root)
    if isinstance(files, int):
        return files
    # on a drone the files sit in one folder (DIR/<file>), as installed: one --drone whose
    # DIR/<drone>/ does not exist is read from there
    flat = args.drone is not None and len(args.drone) == 1 and not (root / args.drone[0]).is_dir()
    problems: list[str] = []
    for f in files:
        path = root / Path(f.path).name if flat else root / f.path
        try:
            installed = path.read_text()
        except OSError as exc:
            problems.append(f"{path}: cannot read ({exc.strerror})")
            continue
        if installed != f.text:
            problems.append(f"{path}: {_first_difference(installed, f.text)}")
    if args.json:
        print(json.dumps({"ok": not problems, "checked": len(files), "problems": problems}))
    elif problems:
        for problem in problems:
            _err(
                f"{problem}; fix: regenerate with 'swarmctl ros2 profile' from the flashed "
                "bundle (same flags) and reinstall"
            )
    else:
        print(f"OK {len(files)} ROS 2 profile files match {args.bundle}")
    return EX_DATAERR if problems else EX_OK


def _first_difference(installed: str, expected: str) -> str:
    have, want = installed.splitlines(), expected.splitlines()
    for number, (a, b) in enumerate(zip(have, want, strict=False), start=1):
        if a != b:
            return f"line {number} differs from the bundle's: {a.strip()[:80]!r}"
    return f"has {len(have)} lines, the bundle gives {len(want)}"
