"""Authentication costs (issue 10): CPU per signed and verified SPDP datagram, what a forged
datagram costs the engine, SPDP bytes with and without the authenticator, and frames and
bytes of an authenticated in-memory swarm. Prints markdown (``--json`` for machines).

    .venv/bin/python bench/auth.py [--repeat 7] [--calls 400]

Timings: ``--repeat`` runs of ``--calls`` calls each, microseconds per call; the median of
the runs and their spread (min..max). Unit tests never assert on timing; this script only
reports. The Jetson Nano column is an estimate, its basis is printed with it.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from swarmd_lab.testing import (  # noqa: E402
    auth_for,
    build_swarm,
    engine_for,
    make_bundle,
    peer_datagram,
)

from bench.bundle import machine  # noqa: E402
from swarmd.auth.freshness import Freshness  # noqa: E402
from swarmd.auth.keys import KeyRing, NodeSecrets  # noqa: E402
from swarmd.auth.spdp import (  # noqa: E402
    AUTHENTICATOR_OVERHEAD,
    PLACEHOLDER,
    SpdpAuth,
    SpdpVerifier,
    open_tail,
    seal,
)
from swarmd.auth.tags import TAG_BYTES  # noqa: E402
from swarmd.rtps.spdp import encode_spdp_dispose  # noqa: E402

# Basis of the Jetson Nano estimate: OpenSSL's Ed25519/X25519 code on aarch64 is portable
# 64-bit C (no assembly for curve25519 arithmetic), so its cycle counts are assumed to be
# 2x-3x those of x86-64 (no MULX/ADX, lower IPC on the in-order-ish A57 pipeline), and the
# Nano's Cortex-A57 runs at 1.43 GHz against this machine's ~2.6 GHz (BogoMIPS 5192 / 2):
# a factor of 2.6 / 1.43 x (2..3) = 3.6x..5.5x. Python-level work (slicing, dicts) is
# assumed to scale by the clock and IPC alike (the same range). Not measured on a Nano.
NANO_FACTOR = (3.6, 5.5)


def timed(fn: Callable[[], object], calls: int, repeat: int) -> tuple[float, float, float]:
    """(median, min, max) microseconds per call over ``repeat`` runs of ``calls`` calls."""
    runs = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        for _ in range(calls):
            fn()
        runs.append((time.perf_counter() - t0) / calls * 1e6)
    return statistics.median(runs), min(runs), max(runs)


def crypto_rows(calls: int, repeat: int) -> list[tuple[str, tuple[float, float, float]]]:
    bundle = make_bundle(10)
    a1, a0 = auth_for(bundle, 1, epoch=7), auth_for(bundle, 0)
    ring1, ring0 = a1.keyring, a0.keyring
    prefix = bundle.participants[1].guid_prefix.value
    # a multicast DATA(p) as uav1 sends it: the template, and one sealed copy to verify
    template = peer_datagram(bundle, 1, auth=_Template(ring1, 7, 0.0), heard=tuple(range(10)))
    one = a1.seal(template)
    opened = open_tail(one)
    assert opened is not None
    _, sig, signed = opened
    seqs = iter(range(1, 10**9))
    a0.verifier.restore({prefix: Freshness(6, 1)})  # ``one`` (epoch 7) stays fresh: no accept
    a0.verifier._tagged = _NoBudget()  # type: ignore[assignment] # the tag alone is timed
    sealed = iter([a1.seal(template) for _ in range(calls * repeat)])
    verifier = SpdpVerifier(ring0, 0.0)
    seconds = iter(float(i) for i in range(10**9))  # one second apart: budgets never bind
    src = ("10.0.0.2", 7412)
    peer = bundle.participants[2].guid_prefix
    secrets = NodeSecrets.dev(bundle.swarm, bundle.participants[0].name)
    return [
        (
            "Ed25519 sign of one DATA(p) (KeyRing.sign)",
            timed(lambda: ring1.sign(signed), calls, repeat),
        ),
        (
            "Ed25519 verify of one DATA(p) (KeyRing.verify)",
            timed(lambda: ring0.verify(prefix, signed, sig), calls, repeat),
        ),
        (
            "seal a DATA(p) template (freshness + 9 receiver tags + sign + splice)",
            timed(lambda: seal(template, Freshness(7, next(seqs)), ring1, a1.tags), calls, repeat),
        ),
        (
            "check one receiver tag (ReceiverTags.holds: keyed BLAKE2b over the DATA(p))",
            timed(lambda: a0.check(prefix, one, src, 0.0), calls, repeat),
        ),
        (
            "accept a DATA(p) (SpdpVerifier.check: all checks + verify)",
            timed(lambda: verifier.check(prefix, next(sealed), src, next(seconds)), calls, repeat),
        ),
        (
            "pairwise key, first use (KeyRing + X25519 + HKDF)",
            timed(
                lambda: KeyRing.from_bundle(bundle, "uav0", secrets).pair_key(peer),
                max(1, calls // 4),
                repeat,
            ),
        ),
    ]


class _Template(SpdpAuth):
    """Leaves the placeholder in: the template a daemon seals each time."""

    def seal(self, template: bytes) -> bytes:
        return template


class _NoBudget:
    def take(self, key: object, now: float) -> bool:
        return False


def refusal_rows(calls: int, repeat: int) -> list[tuple[str, tuple[float, float, float]]]:
    """What one forged datagram costs ``DiscoveryEngine.receive_datagram`` (uav0, N = 10)."""
    bundle = make_bundle(10)
    stranger = make_bundle(10, swarm="forger")
    a1 = auth_for(bundle, 1, epoch=7)
    genuine = peer_datagram(bundle, 1, auth=a1)
    forger = auth_for(bundle, 2, epoch=1000)
    src = ("10.0.0.2", 7412)
    rows = []

    def engine() -> Any:
        e = engine_for(bundle, 0, auth=auth_for(bundle, 0))
        e.receive_datagram(genuine, src, 0.0)  # uav1 known at src
        return e

    e = engine()
    rows.append(
        (
            "replayed member DATA(p)",
            timed(lambda: e.receive_datagram(genuine, src, 0.0), calls, repeat),
        )
    )
    e = engine()
    forged = [peer_datagram(bundle, 1, auth=forger) for _ in range(calls * repeat)]
    it = iter(forged)
    rows.append(
        (
            "forged member DATA(p) from its exact address (refused on the receiver tag)",
            timed(lambda: e.receive_datagram(next(it), src, 0.0), calls, repeat),
        )
    )
    strangers = [
        peer_datagram(stranger, 1 + i % 9, sequence_number=1 + i) for i in range(calls * repeat)
    ]
    e = engine()
    it = iter(strangers)
    now = iter(float(i) for i in range(10**9))
    rows.append(
        (
            "invented participant, decoded (foreign budget left)",
            timed(
                lambda: e.receive_datagram(next(it), ("10.8.0.1", 7412), next(now)), calls, repeat
            ),
        )
    )
    e = engine()
    for d in strangers[:300]:
        e.receive_datagram(d, ("10.8.0.1", 7412), 0.0)
    it = iter(strangers)
    rows.append(
        (
            "invented participant, foreign budget spent",
            timed(lambda: e.receive_datagram(next(it), ("10.8.0.1", 7412), 0.0), calls, repeat),
        )
    )
    return rows


def bytes_rows() -> list[dict[str, Any]]:
    out = []
    for n in (10, 50, 1000):
        bundle = make_bundle(n)
        a = auth_for(bundle, 1)
        heard = tuple(range(n))
        dest = bundle.participants[0].guid_prefix
        prefix = bundle.participants[1].guid_prefix
        for kind, plain, signed in (
            (
                "DATA(p) multicast",
                peer_datagram(bundle, 1, heard=heard),
                peer_datagram(bundle, 1, heard=heard, auth=a),
            ),
            (
                "DATA(p) directed",
                peer_datagram(bundle, 1, heard=heard, destination=dest),
                peer_datagram(bundle, 1, heard=heard, destination=dest, auth=a),
            ),
        ):
            out.append(_bytes_row(n, kind, len(plain), len(signed)))
        plain_d = encode_spdp_dispose(prefix, sequence_number=2, timestamp=None)
        signed_d = a.seal(
            encode_spdp_dispose(
                prefix, sequence_number=2, timestamp=None, authenticator=PLACEHOLDER
            )
        )
        out.append(_bytes_row(n, "DATA(p[UD])", len(plain_d), len(signed_d)))
    return out


def _bytes_row(n: int, kind: str, plain: int, signed: int) -> dict[str, Any]:
    # UDP payload; on the air add IPv4 (20) + UDP (8) for the IP packet
    return {
        "n": n,
        "kind": kind,
        "plain_bytes": plain,
        "authenticated_bytes": signed,
        "added": signed - plain,
        "added_pct_payload": round(100 * (signed - plain) / plain, 1),
        "added_pct_ip": round(100 * (signed - plain) / (plain + 28), 1),
    }


def swarm_rows(seconds: float) -> list[dict[str, Any]]:
    out = []
    for n in (10, 50):
        row: dict[str, Any] = {"n": n, "virtual_s": seconds}
        for authenticated in (False, True):
            t0 = time.perf_counter()
            swarm = build_swarm(n, seed=11, authenticated=authenticated)
            swarm.run_until(seconds)
            tx = swarm.net.transmissions
            key = "auth" if authenticated else "plain"
            row[f"{key}_frames"] = len(tx)
            row[f"{key}_bytes"] = sum(t.size for t in tx)
            row[f"{key}_all_discovered"] = swarm.all_discovered()
            row[f"{key}_wall_s"] = round(time.perf_counter() - t0, 2)
        row["added_frames"] = row["auth_frames"] - row["plain_frames"]
        row["added_bytes_pct"] = round(100 * (row["auth_bytes"] / row["plain_bytes"] - 1), 1)
        out.append(row)
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=7)
    parser.add_argument("--calls", type=int, default=400)
    parser.add_argument("--swarm-seconds", type=float, default=60.0)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    crypto = crypto_rows(args.calls, args.repeat)
    refusals = refusal_rows(args.calls, args.repeat)
    sizes = bytes_rows()
    swarms = swarm_rows(args.swarm_seconds)
    result = {
        "overhead_bytes": f"{AUTHENTICATOR_OVERHEAD} + {TAG_BYTES} per receiver tag, padded to 4",
        "crypto_us": {k: v for k, v in crypto},
        "refusal_us": {k: v for k, v in refusals},
        "bytes": sizes,
        "swarm": swarms,
        "nano_factor": NANO_FACTOR,
    }
    if args.json:
        print(json.dumps(result, indent=2))
        return 0
    print(machine())
    print(f"\nrepeat {args.repeat} x {args.calls} calls; us per call: median (min..max)\n")
    print("| operation | here, µs | Jetson Nano estimate, µs |\n|---|---:|---:|")
    for name, (med, lo, hi) in crypto + refusals:
        print(
            f"| {name} | {med:.1f} ({lo:.1f}..{hi:.1f}) | "
            f"{med * NANO_FACTOR[0]:.0f}..{med * NANO_FACTOR[1]:.0f} |"
        )
    print("\n| N | datagram | plain B | authenticated B | + B | + % payload | + % IP packet |")
    print("|---:|---|---:|---:|---:|---:|---:|")
    for r in sizes:
        print(
            f"| {r['n']} | {r['kind']} | {r['plain_bytes']} | {r['authenticated_bytes']} | "
            f"{r['added']} | {r['added_pct_payload']} | {r['added_pct_ip']} |"
        )
    print("\n| N | frames plain | frames auth | + frames | bytes plain | bytes auth | + % |")
    print("|---:|---:|---:|---:|---:|---:|---:|")
    for r in swarms:
        print(
            f"| {r['n']} | {r['plain_frames']} | {r['auth_frames']} | {r['added_frames']} | "
            f"{r['plain_bytes']} | {r['auth_bytes']} | {r['added_bytes_pct']} |"
        )
    print(
        f"\n(in-memory network, {args.swarm_seconds:g} virtual s, seed 11; all discovered: "
        + ", ".join(
            f"N={r['n']} {r['plain_all_discovered']}/{r['auth_all_discovered']}" for r in swarms
        )
        + ")"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
