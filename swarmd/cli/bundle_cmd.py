"""``swarmctl bundle ...``: keygen, build, verify, show, flash, check and roll back bundles.

Exit codes: 0 ok; 1 a fleet check found a drone that differs; 2 usage; 65 (EX_DATAERR) a bad
mission or key file, nothing written; 73 (EX_CANTCREAT) an output or flash target could not be
written; 78 (EX_CONFIG) a bundle that fails verification. Every failure is one line on stderr.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

from swarmd.bundle.build import build_from_files, check_serial
from swarmd.bundle.encoding import EnvelopeError, split
from swarmd.bundle.errors import (
    BundleError,
    FlashError,
    KeyFileError,
    MissionError,
    SerialRefused,
)
from swarmd.bundle.flash import (
    DEFAULT_TARGET_DIR,
    FlashPayload,
    Ssh,
    check_target,
    flash,
    parse_target,
    rollback,
)
from swarmd.bundle.keys import (
    PUBLIC_MODE,
    dev_node_keys,
    fingerprint,
    generate_keys,
    load_node_keys,
    load_public_key,
    node_key_path,
    write_file_atomic,
)
from swarmd.bundle.loader import read_bundle
from swarmd.bundle.mission import load_mission
from swarmd.bundle.model import SERIAL_MAX, Bundle, Participant
from swarmd.bundle.summary import human, serial_text, summary
from swarmd.exitcodes import EX_BAD_ARGS, EX_CANTCREAT, EX_CONFIG, EX_DATAERR, EX_FAILED, EX_OK

PROG = "swarmctl"
DEFAULT_ALL_TARGET = f"root@{{ipv4}}:{DEFAULT_TARGET_DIR}"


def _err(message: str) -> None:
    print(f"{PROG}: {message}", file=sys.stderr)


def _print_json(value: Any) -> None:
    print(json.dumps(value, indent=2, sort_keys=True))


def register(sub: Any) -> None:
    parser: argparse.ArgumentParser = sub.add_parser(
        "bundle",
        help="build, sign, verify, show and flash firmware bundles",
        description="The pre-flight firmware bundle (paper section 4.2): every participant and "
        "endpoint of the mission, signed, flashed to every drone. See docs/preflight.md.",
    )

    def usage(_args: argparse.Namespace) -> int:
        parser.print_help(sys.stderr)
        return EX_BAD_ARGS

    parser.set_defaults(func=usage)
    bsub = parser.add_subparsers(dest="bundle_command", metavar="ACTION")

    p = bsub.add_parser("keygen", help="make the swarm signing key and per-node announcement keys")
    p.add_argument("--out", required=True, metavar="DIR", help="keys directory")
    p.add_argument("--mission", metavar="MISSION", help="also make a key for every participant")
    p.add_argument("--force", action="store_true", help="replace existing keys (rotation)")
    p.set_defaults(func=cmd_keygen)

    p = bsub.add_parser("build", help="build and sign a bundle from a mission file")
    p.add_argument("mission", metavar="MISSION.yaml")
    p.add_argument("-o", "--output", required=True, metavar="OUT.swb")
    p.add_argument("--sign-key", metavar="KEY", help="swarm signing key (PEM) from keygen")
    p.add_argument(
        "--keys", metavar="DIR", help="keys directory with nodes/<name>.pub (default: KEY's dir)"
    )
    p.add_argument(
        "--unsigned-dev",
        action="store_true",
        help="lab only: sign with the public dev key; drones refuse it unless bundle.allow_dev",
    )
    p.add_argument(
        "--serial",
        metavar="N",
        help="the anti-rollback serial, 1..4294967295 (default: one more than the bundle it "
        "replaces: --replaces, else the bundle already at -o, else 1); drones refuse a "
        "serial below the highest they accepted, and another bundle with that same serial",
    )
    p.add_argument(
        "--replaces",
        metavar="OLD.swb",
        help="the bundle this one replaces: the serial becomes its serial + 1",
    )
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    p.set_defaults(func=cmd_build)

    p = bsub.add_parser("verify", help="verify a bundle as the daemon would (exit 78 if bad)")
    p.add_argument("bundle", metavar="BUNDLE")
    _trust_args(p)
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=cmd_verify)

    p = bsub.add_parser("show", help="summarise a bundle: swarm, hash, participants, topics")
    p.add_argument("bundle", metavar="BUNDLE")
    _trust_args(p)
    p.add_argument("--json", action="store_true", help="machine-readable, with endpoint matches")
    p.add_argument("--node", metavar="NAME", help="endpoint matches for this node only")
    p.add_argument("--no-matches", action="store_true", help="leave out the per-node matches")
    p.set_defaults(func=cmd_show)

    p = bsub.add_parser("flash", help="write a bundle and a node key to a drone (or directory)")
    p.add_argument("bundle", metavar="BUNDLE")
    who = p.add_mutually_exclusive_group(required=True)
    who.add_argument("--node", metavar="NAME", help="the participant this drone is")
    who.add_argument("--all", action="store_true", help="every participant with an ipv4")
    p.add_argument(
        "--target",
        metavar="DIR|[user@]host:DIR",
        help="where to write; may use {name}, {ipv4}, {index} "
        f"(--all default: {DEFAULT_ALL_TARGET})",
    )
    p.add_argument("--keys", metavar="DIR", help="keys directory with nodes/<name>.key")
    p.add_argument(
        "--replace-trust-key",
        action="store_true",
        help="overwrite the drone's swarm.pub when it trusts another key (key rotation)",
    )
    p.add_argument(
        "--allow-lower-serial",
        action="store_true",
        help="write the bundle even when its serial is below the one the drone carries or "
        "its bundle floor (a bench reset); swarmd on the drone still refuses a serial below "
        "its floor at start (exit 78) until that floor file is deleted",
    )
    _trust_args(p)
    _ssh_args(p)
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=cmd_flash)

    p = bsub.add_parser(
        "check", help="read back what drones carry and compare with a bundle's hash"
    )
    p.add_argument("bundle", metavar="BUNDLE")
    who = p.add_mutually_exclusive_group(required=True)
    who.add_argument("--node", metavar="NAME")
    who.add_argument("--all", action="store_true")
    p.add_argument("--target", metavar="DIR|[user@]host:DIR")
    _trust_args(p)
    _ssh_args(p)
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=cmd_check)

    p = bsub.add_parser(
        "rollback",
        help="restore the previous bundle on a drone; refused (exit 78) when the drone's "
        "bundle floor says its swarmd would refuse it: then rebuild with a higher --serial",
    )
    p.add_argument("--target", required=True, metavar="DIR|[user@]host:DIR")
    _ssh_args(p)
    p.set_defaults(func=cmd_rollback)


def _trust_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--trusted-key", metavar="PUB", help="swarm signing public key to require")
    p.add_argument("--expect-sha256", metavar="HEX", help="pinned content hash to require")
    p.add_argument("--allow-dev", action="store_true", help="accept an --unsigned-dev bundle")


def _ssh_args(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--ssh-option",
        action="append",
        default=[],
        metavar="OPT",
        help="extra ssh/scp -o option, repeatable (e.g. Port=2222, IdentityFile=...)",
    )


# -- helpers ----------------------------------------------------------------------------------


class _Loaded:
    def __init__(self, bundle: Bundle, data: bytes, dev: bool, trust: str) -> None:
        self.bundle = bundle
        self.data = data
        self.dev = dev
        self.trust = trust


def _load(args: argparse.Namespace, *, inspect: bool) -> _Loaded:
    """Read and verify BUNDLE; ``inspect`` lets a dev bundle through without --allow-dev."""
    path = str(args.bundle)
    trusted: bytes | None = None
    if args.trusted_key is not None:
        try:
            trusted = load_public_key(args.trusted_key)
        except KeyFileError as exc:
            raise BundleError(exc.file, f"trusted key: {exc.problem}", exc.fix) from None
    expected: bytes | None = None
    if args.expect_sha256 is not None:
        try:
            expected = bytes.fromhex(args.expect_sha256)
        except ValueError:
            expected = b""
        if len(expected) != 32:
            raise BundleError(
                "--expect-sha256", "not 64 hex digits", "copy the hash from 'bundle show'"
            )
    try:
        data = Path(path).read_bytes()
    except OSError as exc:
        raise BundleError(path, f"cannot read: {exc.strerror}", "check the path") from None
    try:
        dev = split(data).dev
    except EnvelopeError:
        dev = False  # read_bundle reports the framing problem below
    bundle = read_bundle(
        data,
        source=path,
        trusted_key=trusted,
        expected_sha256=expected,
        allow_dev=args.allow_dev or (inspect and dev),
        require_anchor=False,
    )
    trust = "trusted-key" if trusted is not None else "pinned-hash" if expected else "embedded-key"
    return _Loaded(bundle, data, dev, trust)


def _guard(func: Callable[[argparse.Namespace], int]) -> Callable[[argparse.Namespace], int]:
    """Map the bundle errors to one stderr line and their exit codes."""

    def run(args: argparse.Namespace) -> int:
        try:
            return func(args)
        except (MissionError, KeyFileError) as exc:
            _err(str(exc))
            return EX_DATAERR
        except BundleError as exc:
            if getattr(args, "json", False):
                _print_json({"ok": False, "error": str(exc)})
            _err(f"bundle rejected: {exc}")
            return EX_CONFIG
        except SerialRefused as exc:  # what the drone's swarmd would refuse: its code
            _err(str(exc))
            return EX_CONFIG
        except FlashError as exc:
            _err(str(exc))
            return EX_CANTCREAT

    return run


# -- commands ---------------------------------------------------------------------------------


@_guard
def cmd_keygen(args: argparse.Namespace) -> int:
    names = [p.name for p in load_mission(args.mission).participants] if args.mission else []
    try:
        result = generate_keys(args.out, names, force=args.force)
    except OSError as exc:
        _err(f"{args.out}: cannot write keys: {exc.strerror}; fix: check the directory")
        return EX_CANTCREAT
    for path in result.created:
        print(f"created {path}")
    for path in result.kept:
        print(f"kept    {path} (exists; --force replaces it)")
    for path in result.upgraded:
        print(f"added   an X25519 key to {path} (its Ed25519 key is kept)")
    return EX_OK


@_guard
def cmd_build(args: argparse.Namespace) -> int:
    if args.sign_key is None and not args.unsigned_dev:
        _err("build needs --sign-key KEY (from 'bundle keygen'), or --unsigned-dev for a lab bench")
        return EX_BAD_ARGS
    if args.sign_key is not None and args.unsigned_dev:
        _err("--sign-key and --unsigned-dev exclude each other")
        return EX_BAD_ARGS
    if args.serial is not None and args.replaces is not None:
        _err("--serial and --replaces exclude each other")
        return EX_BAD_ARGS
    serial, replaced = _build_serial(args)
    if serial is None:
        return EX_BAD_ARGS
    mission = load_mission(args.mission)
    built = build_from_files(
        mission, args.sign_key, args.keys, dev=args.unsigned_dev, serial=serial
    )
    out = Path(args.output)
    try:
        write_file_atomic(out, built.data, PUBLIC_MODE)
    except OSError as exc:
        _err(f"{out}: cannot write: {exc.strerror}; fix: check the output directory")
        return EX_CANTCREAT
    b = built.bundle
    if built.dev:
        print(
            f"{PROG}: warning: {out} is an --unsigned-dev bundle signed with a public key; "
            "drones refuse it unless bundle.allow_dev is set",
            file=sys.stderr,
        )
    if args.json:
        _print_json(
            {
                "ok": True,
                "file": str(out),
                "size_bytes": len(built.data),
                "swarm": b.swarm,
                "participants": b.size,
                "topics": len(b.topics),
                "content_sha256": b.content_sha256.hex(),
                "signer": fingerprint(b.signing_public_key),
                "dev": built.dev,
                "serial": serial,
                "replaces": replaced,
            }
        )
    else:
        after = (
            ""
            if replaced is None
            else f" (replaces serial {replaced['serial']} of {replaced['file']})"
        )
        print(
            f"wrote {out}: swarm {b.swarm}, {b.size} participants, {len(b.topics)} topics, "
            f"{len(built.data)} bytes, sha256 {b.content_sha256.hex()}, "
            f"signer {fingerprint(b.signing_public_key)}, serial {serial}{after}"
        )
    return EX_OK


def _build_serial(args: argparse.Namespace) -> tuple[int | None, dict[str, Any] | None]:
    """The new bundle's serial and what it replaces: ``--serial``, else one more than
    ``--replaces`` (which must verify), else one more than the bundle already at ``-o``
    (a file there that is no bundle is overwritten, as before, with serial 1 and a
    warning), else 1. (None, None) after a one-line usage error."""
    if args.serial is not None:
        try:
            serial = int(args.serial)
            check_serial(serial)
        except ValueError:
            _err(f"--serial {args.serial}: not a whole number in 1..{SERIAL_MAX}")
            return None, None
        return serial, None
    previous = args.replaces if args.replaces is not None else args.output
    if args.replaces is None and not Path(previous).exists():
        return 1, None
    try:
        data = Path(previous).read_bytes()
        old = read_bundle(data, source=str(previous), allow_dev=True, require_anchor=False)
    except OSError as exc:
        if args.replaces is None:
            raise
        raise BundleError(
            str(previous), f"cannot read: {exc.strerror}", "check --replaces"
        ) from None
    except BundleError as exc:
        if args.replaces is not None:
            raise
        print(
            f"{PROG}: warning: {previous} is not a bundle ({exc.problem}); it is overwritten "
            "with serial 1",
            file=sys.stderr,
        )
        return 1, None
    base = 0 if old.serial is None else old.serial
    if base >= SERIAL_MAX:
        raise BundleError(
            str(previous),
            f"serial {base} is the last one",
            "rotate the swarm signing key and reset every drone's floor (docs/operations.md)",
        )
    return base + 1, {"file": str(previous), "serial": base}


@_guard
def cmd_verify(args: argparse.Namespace) -> int:
    loaded = _load(args, inspect=False)
    b = loaded.bundle
    if args.json:
        _print_json(
            {
                "ok": True,
                "file": str(args.bundle),
                "swarm": b.swarm,
                "content_sha256": b.content_sha256.hex(),
                "participants": b.size,
                "signer": fingerprint(b.signing_public_key),
                "trust": loaded.trust,
                "dev": loaded.dev,
                "serial": b.serial,
            }
        )
    else:
        print(
            f"OK {args.bundle}: swarm {b.swarm}, {b.size} participants, "
            f"sha256 {b.content_sha256.hex()}, signer {fingerprint(b.signing_public_key)} "
            f"({loaded.trust}{', DEV' if loaded.dev else ''}), serial {serial_text(b.serial)}"
        )
    return EX_OK


@_guard
def cmd_show(args: argparse.Namespace) -> int:
    loaded = _load(args, inspect=True)
    if args.node is not None:
        _participant(loaded.bundle, args.node)
    s = summary(
        loaded.bundle,
        file=str(args.bundle),
        size=len(loaded.data),
        dev=loaded.dev,
        trust=loaded.trust,
        matches_for=args.node,
        with_matches=not args.no_matches,
    )
    if args.json:
        _print_json(s)
    else:
        print(human(s))
    return EX_OK


def _participant(bundle: Bundle, name: str) -> Participant:
    try:
        return bundle.participant(name)
    except KeyError:
        names = ", ".join(p.name for p in bundle.participants[:10])
        raise KeyFileError(
            "--node", f"no participant {name!r} in swarm {bundle.swarm}", f"use one of: {names}"
        ) from None


def _targets(args: argparse.Namespace, bundle: Bundle) -> list[tuple[Participant, str]]:
    """(participant, target text) pairs from --node/--all and the --target template."""
    if args.all:
        template = args.target or DEFAULT_ALL_TARGET
        chosen = [p for p in bundle.participants if p.ipv4 is not None]
    else:
        if args.target is None:
            raise KeyFileError(
                "--target", "flash --node needs a target", "add --target DIR or user@host:DIR"
            )
        template = args.target
        chosen = [_participant(bundle, args.node)]
    out = []
    for p in chosen:
        try:
            text = template.format(name=p.name, ipv4=p.ipv4 or "", index=p.index)
        except (KeyError, IndexError, ValueError):
            raise KeyFileError(
                "--target", f"bad template {template!r}", "use only {name}, {ipv4}, {index}"
            ) from None
        out.append((p, text))
    return out


def _node_key_pem(args: argparse.Namespace, loaded: _Loaded, p: Participant) -> bytes:
    if args.keys is not None:
        keys = load_node_keys(node_key_path(args.keys, p.name))
        source = str(node_key_path(args.keys, p.name))
    elif loaded.dev:
        keys = dev_node_keys(loaded.bundle.swarm, p.name)
        source = "dev key"
    else:
        raise KeyFileError(
            "--keys", f"no key source for node {p.name!r}", "pass --keys DIR (from keygen)"
        )
    if keys.public != (p.announce_public_key, p.x25519_public_key):
        raise KeyFileError(
            source,
            f"these keys are not {p.name!r}'s keys in the bundle",
            "use the keys directory the bundle was built from",
        )
    return keys.pem()


@_guard
def cmd_flash(args: argparse.Namespace) -> int:
    loaded = _load(args, inspect=True)
    plan = _targets(args, loaded.bundle)
    # every key is checked before the first drone is touched
    payloads = [
        (
            FlashPayload(
                p.name, loaded.data, loaded.bundle, _node_key_pem(args, loaded, p), loaded.dev
            ),
            parse_target(text),
        )
        for p, text in plan
    ]
    if not payloads:
        _err("no participant has an ipv4 address; fix: flash each with --node NAME --target ...")
        return EX_BAD_ARGS
    ssh = Ssh(tuple(args.ssh_option))
    results: list[dict[str, Any]] = []
    failed = refused = 0
    for payload, target in payloads:
        try:
            r = flash(
                payload,
                target,
                ssh=ssh,
                replace_trust=args.replace_trust_key,
                allow_lower_serial=args.allow_lower_serial,
            )
        except FlashError as exc:
            failed += 1
            refused += isinstance(exc, SerialRefused)
            _err(f"{payload.node}: {exc}")
            results.append(
                {"node": payload.node, "target": str(target), "ok": False, "error": str(exc)}
            )
            continue
        results.append(
            {
                "node": r.node,
                "target": r.target,
                "ok": True,
                "content_sha256": r.content_sha256,
                "previous_kept": r.replaced_previous,
                "trust_written": r.trust_written,
            }
        )
        if not args.json:
            notes = []
            if r.replaced_previous:
                notes.append("previous kept as bundle.swb.prev")
            if r.trust_written:
                notes.append(
                    f"trust anchor {fingerprint(loaded.bundle.signing_public_key)} written"
                )
            extra = f" ({'; '.join(notes)})" if notes else ""
            print(f"flashed {r.node} -> {r.target}: sha256 {r.content_sha256} verified{extra}")
    if args.json:
        _print_json({"ok": failed == 0, "results": results})
    if failed and failed == refused:  # only serial refusals: the daemon's own code for them
        return EX_CONFIG
    return EX_CANTCREAT if failed else EX_OK


@_guard
def cmd_check(args: argparse.Namespace) -> int:
    loaded = _load(args, inspect=True)
    expected = loaded.bundle.content_sha256.hex()
    ssh = Ssh(tuple(args.ssh_option))
    rows: list[dict[str, Any]] = []
    for p, text in _targets(args, loaded.bundle):
        target = parse_target(text)
        try:
            state = check_target(target, expected_node=p.name, allow_dev=loaded.dev, ssh=ssh)
        except FlashError as exc:
            rows.append({"node": p.name, "target": str(target), "ok": False, "error": str(exc)})
            continue
        same = state.content_sha256 == expected
        row: dict[str, Any] = {
            "node": p.name,
            "target": str(target),
            "ok": same,
            "content_sha256": state.content_sha256,
        }
        if not same:
            row["error"] = f"carries {state.content_sha256}, expected {expected}"
        rows.append(row)
    ok = all(r["ok"] for r in rows)
    if args.json:
        _print_json({"ok": ok, "expected_sha256": expected, "nodes": rows})
    else:
        print(f"expected sha256 {expected}")
        for r in rows:
            status = "OK  " if r["ok"] else "FAIL"
            print(f"{status} {r['node']:<16} {r['target']:<40} {r.get('error', '')}".rstrip())
        print(f"{sum(r['ok'] for r in rows)}/{len(rows)} drones carry the same bundle")
    return EX_OK if ok else EX_FAILED


@_guard
def cmd_rollback(args: argparse.Namespace) -> int:
    target = parse_target(args.target)
    rollback(target, ssh=Ssh(tuple(args.ssh_option)))
    print(f"rolled back {target} to its previous bundle")
    return EX_OK
