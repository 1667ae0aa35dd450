"""What a forged SPDP datagram under an invented prefix costs to decode, by size (review 16).

    nice -n 10 .venv/bin/python bench/foreign_decode_cost.py [--tree /work/main] [--flood-s 5]

A datagram whose RTPS header names a prefix outside the bundle is decoded, within the
foreign decode budget, to be listed as a foreign participant (docs/security.md, "Foreign
participants and floods"). The forger chooses its size and shape:
``tests.attacker.forge.bloated_participant`` is a stock-vendor DATA(p) padded with empty
parameters (4 octets each) and one swarmd vendor PID. Reported, CPU time
(``time.process_time``):

- ``decode_spdp`` of one such datagram of 1,400 octets (one Wi-Fi frame) and 65,507 (the
  largest UDP payload), of one of 1,024 minimal DATA(p)s (``forge.many_samples``), against
  stock Cyclone DDS 0.10.2's DATA(p) (the golden capture); then each through a fresh
  authenticated engine's ``receive_datagram``, its events drained;
- the authenticated engine's ``receive_datagram`` under a flood of the 65,507-octet kind at
  ``--rate`` a second for ``--flood-s`` virtual seconds: CPU seconds per second of flood,
  and how many were decoded.

``--tree DIR`` imports ``swarmd`` from another checkout (e.g. main, for "before"); the
forgery is built by this checkout's ``tests/attacker/forge.py`` with that tree's codec.
Only reports; the tests (``tests/test_foreign_decode_cost.py``) assert on counts, not time.
"""

from __future__ import annotations

import argparse
import importlib.util
import statistics
import sys
import time
from collections.abc import Callable
from functools import partial
from pathlib import Path
from types import ModuleType

ROOT = Path(__file__).resolve().parent.parent


def _clear_memo(received: ModuleType) -> None:
    """Empty the decode memo of whichever tree is imported (``clear_memo`` since session 16:
    the memo counts its octets; before, the dict alone)."""
    clear = getattr(received, "clear_memo", None)
    if clear is not None:
        clear()
    else:
        received._memo.clear()  # noqa: SLF001 - a tree from before clear_memo


def _forge() -> ModuleType:
    """This checkout's forger, importing whichever ``swarmd`` is first on the path."""
    spec = importlib.util.spec_from_file_location("h16_forge", ROOT / "tests/attacker/forge.py")
    if spec is None or spec.loader is None:
        raise ImportError(f"cannot load {spec}")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _cpu(fn: Callable[[], object], repeat: int) -> float:
    """Median CPU time of ``fn``; a decode that refuses its input counts all the same."""
    runs = []
    for _ in range(repeat):
        start = time.process_time()
        try:
            fn()
        except ValueError:  # DecodeError: refused, at whatever it cost to find out
            pass
        runs.append(time.process_time() - start)
    return statistics.median(runs)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--tree", type=Path, default=ROOT, help="checkout to import swarmd from")
    ap.add_argument("--repeat", type=int, default=5, help="runs per decode; the median")
    ap.add_argument("--rate", type=float, default=100.0, help="forged datagrams a second")
    ap.add_argument("--flood-s", type=float, default=5.0, help="virtual seconds of flood")
    args = ap.parse_args()
    sys.path[:0] = [str(args.tree.resolve()), str(args.tree.resolve() / "lab")]
    from swarmd_lab.testing import auth_for, engine_for, make_bundle  # noqa: PLC0415

    import swarmd  # noqa: PLC0415
    from swarmd.discovery import received  # noqa: PLC0415 - after --tree
    from swarmd.rtps import decode_spdp  # noqa: PLC0415
    from swarmd.rtps.types import GuidPrefix  # noqa: PLC0415

    forge = _forge()
    print(f"swarmd from {Path(swarmd.__file__).parent}")
    cyclone = (ROOT / "tests/fixtures/cyclone-0.10.2/spdp-alive.bin").read_bytes()
    cases = {"Cyclone 0.10.2 DATA(p)": cyclone}
    for size in (1400, forge.MAX_UDP_PAYLOAD):
        cases[f"forged, {size:,} octets"] = forge.bloated_participant(
            GuidPrefix(bytes(12)), size=size
        )
    if hasattr(forge, "many_samples"):
        cases["forged, 1,024 DATA(p)s"] = forge.many_samples(GuidPrefix(bytes(12)), 1024)
    for name, datagram in cases.items():
        repeat = args.repeat if len(datagram) < 8000 else max(1, args.repeat // 2)
        cost = _cpu(partial(decode_spdp, datagram), repeat)
        print(
            f"decode_spdp {name:28} {len(datagram):6} octets  {cost * 1e3:9.3f} ms"
            f"  ({cost * 1e6 / len(datagram):.3f} us an octet)"
        )
    bundle = make_bundle(10)
    for name, datagram in cases.items():
        # the whole receive path, once per datagram (a fresh engine: its budgets full)
        costs: list[float] = []
        for _ in range(max(1, args.repeat // 2)):
            _clear_memo(received)
            fresh = engine_for(bundle, 0, auth=auth_for(bundle, 0))
            start = time.process_time()
            fresh.receive_datagram(datagram, ("10.7.0.9", 7400), 0.0)
            while fresh.next_event() is not None:
                pass
            costs.append(time.process_time() - start)
        cost = statistics.median(costs)
        print(
            f"engine receive {name:25} {len(datagram):6} octets  {cost * 1e3:9.3f} ms"
            f"  ({cost * 1e6 / len(datagram):.3f} us an octet)"
        )
    engine = engine_for(bundle, 0, auth=auth_for(bundle, 0))
    count = int(args.rate * args.flood_s)
    pool = [
        forge.bloated_participant(GuidPrefix(b"\xf0\x0d" + i.to_bytes(10, "big"))) for i in range(8)
    ]
    start = time.process_time()
    for i in range(count):
        _clear_memo(received)  # each forgery new to the decoder, as a real flood's would be
        engine.receive_datagram(pool[i % len(pool)], ("10.7.0.9", 7400), i / args.rate)
    spent = time.process_time() - start
    dropped = engine.counters()["dropped"]
    print(
        f"engine, {count} forged {len(pool[0]):,}-octet datagrams in {args.flood_s:g} virtual s: "
        f"{spent / args.flood_s:.3f} CPU s a second; decoded {dropped['not_in_bundle']}, "
        f"refused unread {dropped['foreign_budget']}"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
