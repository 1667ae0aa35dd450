"""Time dilation (bench/wifi/dilate.c via bench/wifi/dilation.py) on real processes.

A dilated child must read the harness's experiment clock (``Dilation.exp``) and wait k
times longer in real time for every kind of timeout the testbed's stacks use: Python's
``time.sleep`` (clock_nanosleep, absolute), lock waits (sem_clockwait), selectors
(epoll_wait) and asyncio. Only lower bounds on real time are asserted: a loaded machine can
make a wait longer, never shorter.
"""

from __future__ import annotations

import json
import subprocess
import sys
import time

import pytest

from bench.wifi.dilation import Dilation
from bench.wifi.native import BuildError, dilate_library

K = 3.0
WAIT_S = 0.2

CHILD = f"""
import asyncio, json, selectors, socket, threading, time
w0, m0 = time.time(), time.monotonic()
out = {{"wall_start": w0}}
def exp_elapsed(fn):  # experiment seconds: the child is dilated
    r0 = time.monotonic()
    fn()
    return time.monotonic() - r0
out["sleep"] = exp_elapsed(lambda: time.sleep({WAIT_S}))
out["event_wait"] = exp_elapsed(lambda: threading.Event().wait({WAIT_S}))
sel = selectors.DefaultSelector()
a, b = socket.socketpair()
sel.register(a, selectors.EVENT_READ)
out["select"] = exp_elapsed(lambda: sel.select({WAIT_S}))
out["asyncio"] = exp_elapsed(lambda: asyncio.run(asyncio.sleep({WAIT_S})))
out["wall_end"] = time.time()
print(json.dumps(out))
"""


def _library() -> str:
    try:
        return str(dilate_library())
    except BuildError as exc:
        pytest.skip(f"dilation library cannot be built here: {exc}")


def test_dilated_child_reads_the_experiment_clock_and_waits_k_times_longer() -> None:
    _library()
    dil = Dilation.start(K)
    before = time.time()
    t0 = time.monotonic()
    proc = subprocess.run(
        [sys.executable, "-c", CHILD],
        capture_output=True,
        text=True,
        timeout=120,
        env={**dil.env(), "PATH": "/usr/bin:/bin"},
        check=True,
    )
    real_elapsed = time.monotonic() - t0
    after = time.time()
    out = json.loads(proc.stdout)
    # the child's wall clock is the harness's experiment clock, not its own
    assert dil.exp(before) <= out["wall_start"] <= out["wall_end"] <= dil.exp(after)
    for kind in ("sleep", "event_wait", "select", "asyncio"):
        # in experiment time each wait lasted its timeout...
        assert out[kind] >= WAIT_S * 0.99, kind
    # ...and in real time k times that (four waits)
    assert real_elapsed >= 4 * WAIT_S * K * 0.99


def test_undilated_run_preloads_nothing() -> None:
    dil = Dilation.start(1.0)
    assert dil.env() == {}
    assert dil.exp(1234.5) == 1234.5


def test_experiment_clock_is_slowed_around_the_anchor() -> None:
    dil = Dilation(4.0, anchor_real_ns=1_000_000_000_000, anchor_mono_ns=0)
    assert dil.exp(1000.0) == 1000.0
    assert dil.exp(1040.0) == 1010.0
    assert dil.real_s(60) == 240
    with pytest.raises(ValueError, match="factor"):
        Dilation.start(0.5)
