"""How fast does the XRCE agent's clock leave Unix time (docs/px4.md, "The agent's clock")?

    .venv/bin/python bench/xrce_clock_drift.py [--seconds S]     (default 60, at most 600)

The XRCE backend reads its agent time as the daemon's loop clock plus one offset taken at
start, Unix time minus loop time (``xrce_backend._clock_offset``). The loop clock is
``rawclock.raw_clock()``: CLOCK_MONOTONIC_RAW, the crystal's count, which NTP never
corrects. So the agent's clock keeps the crystal's rate error against Unix time, plus any
step of the system clock after the start. This samples ``time.time() - raw_clock()`` at
the start and the end of the window and prints the rate in ppm and as seconds a day, and
the kernel's own word on the crystal: the NTP frequency correction ``adjtimex(2)`` holds
(``timex.freq``, ppm with a 16-bit fraction; the kernel caps it at 500 ppm, ``MAXFREQ``
in kernel/time/ntp.c). A reading, not a test: nothing asserted.
"""

from __future__ import annotations

import argparse
import ctypes
import ctypes.util
import time
from typing import Final

from swarmd.rawclock import raw_clock

MAX_SECONDS: Final = 600.0
MAXFREQ_PPM: Final = 500  # kernel/time/ntp.c: the largest frequency correction NTP may set


class _Timex(ctypes.Structure):
    # struct timex (adjtimex(2)), through freq; the rest of the kernel's 208 bytes is padding
    _fields_ = [  # noqa: RUF012 - ctypes wants a plain list
        ("modes", ctypes.c_uint),
        ("offset", ctypes.c_long),
        ("freq", ctypes.c_long),
        ("rest", ctypes.c_byte * 256),
    ]


def ntp_frequency_ppm() -> float | None:
    """The kernel's NTP frequency correction (ppm), read-only (modes 0); None if unknown."""
    name = ctypes.util.find_library("c")
    if name is None:
        return None
    libc = ctypes.CDLL(name, use_errno=True)
    tx = _Timex()
    if libc.adjtimex(ctypes.byref(tx)) < 0:
        return None
    return float(tx.freq) / 65536.0


def offset() -> float:
    return time.time() - raw_clock()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=60.0)
    args = parser.parse_args()
    seconds = min(max(args.seconds, 1.0), MAX_SECONDS)
    t0, o0 = raw_clock(), offset()
    time.sleep(seconds)
    t1, o1 = raw_clock(), offset()
    ppm = (o1 - o0) / (t1 - t0) * 1e6
    freq = ntp_frequency_ppm()
    print(f"window {t1 - t0:.1f} s (raw clock)")
    print(f"Unix time - raw clock moved {(o1 - o0) * 1e6:+.1f} us: {ppm:+.2f} ppm")
    print(f"  = {ppm * 86400 / 1e6:+.3f} s a day between the agent's clock and Unix time")
    if freq is not None:
        print(f"kernel NTP frequency correction (adjtimex freq): {freq:+.3f} ppm")
    print(
        f"bound: the kernel caps that correction at {MAXFREQ_PPM} ppm = "
        f"{MAXFREQ_PPM * 86400 / 1e6:.1f} s a day; a step of the system clock "
        "(an NTP or GPS first fix on a companion without RTC) adds itself once"
    )


if __name__ == "__main__":
    main()
