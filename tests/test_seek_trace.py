"""``bench/seek_trace.py``: one pair's seeks in a flight replay and what put them off."""

from __future__ import annotations

import json
from pathlib import Path

from bench.seek_trace import main, trace
from swarmd.discovery import receive, seek

RUN = Path(__file__).resolve().parent.parent / (
    "bench/results/flight-stagger-1e20f9e/runs/flight-fly-out-swarmd-n20-r1.json"
)


def test_the_trace_names_each_put_off_seek_s_sender_and_restores_the_engine() -> None:
    heard, receive_heard = seek.Seek.heard, receive.ReceivePath._heard
    text = trace(json.loads(RUN.read_text()), 71, 8, 14, 84.0, 89.0)
    lines = text.splitlines()
    assert lines[0].startswith("uav9 lost uav15 at ")
    assert lines[1].startswith("uav15 lost uav9 at ")
    put_off = [line for line in lines if "seek put off" in line]
    assert put_off and all(" by uav" in line and "range of uav" in line for line in put_off)
    assert any("uav9 multicasts" in line for line in lines)
    # the instrumentation is gone after the run
    assert seek.Seek.heard is heard and receive.ReceivePath._heard is receive_heard


def test_a_bad_pair_stops_with_a_usage_error() -> None:
    assert main([str(RUN), "--seed", "1", "--pair", "9", "9"]) == 64
    assert main([str(RUN), "--seed", "1", "--pair", "0", "9"]) == 64
    assert main([str(RUN) + ".missing", "--seed", "1", "--pair", "1", "2"]) == 66
