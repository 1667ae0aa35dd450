"""A captured member's ACKNACK flood at the commander: what comes back to its locator.

    .venv/bin/python -m bench.acknack_flood [--rate 400] [--seconds 1]

The scenario of ``tests/test_dataplane_acknack_flood.py`` (virtual time, in-memory network:
no timing in it): m01, captured, sends fresh, genuinely sealed ACKNACKs asking for 64 SNs of
the command writer; the commander answers them to the locator m01 signed, which may be any
victim's unicast address (docs/security-history.md, "Network paths end to end").
"""

from __future__ import annotations

import argparse

from tests.test_dataplane_acknack_flood import acknack_flood


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rate", type=int, default=400, help="ACKNACKs a second")
    ap.add_argument("--seconds", type=float, default=1.0, help="flood length (virtual)")
    args = ap.parse_args()
    sent, sent_bytes, back, back_bytes = acknack_flood(args.rate, args.seconds)
    print(
        f"{sent} ACKNACKs ({sent_bytes} B) in {args.seconds} s -> {back} datagrams "
        f"({back_bytes} B) to the captured member's locator, x{back_bytes / sent_bytes:.2f} bytes"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
