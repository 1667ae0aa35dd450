"""``bench/edge_trace.py``: a slow pair's frames in a flight replay, from the return to the
re-discovery, and what became of each (docs/benchmarks.md, "Where it stands (session 13)")."""

from __future__ import annotations

import json
from pathlib import Path

from swarmd_lab import memnet

from bench.edge_trace import _deliveries, main, trace_seed
from bench.flight_fade_replay import Replay
from swarmd.discovery import sending

RUN = Path(__file__).resolve().parent.parent / (
    "bench/results/flight-stagger/runs/flight-fade-swarmd-n10-r3.json"
)
FATES = {"crossed", "lost at the edge", "out of range"}


def test_the_trace_lists_the_pair_s_frames_with_their_fate_and_restores_the_engine() -> None:
    """Seed 98 of the fade at N = 10, run 3, with edge loss: uav7 finds the fader 6.95 s
    after a return of 0.25 s (the one slow pair left on the branch)."""
    send, push = sending.Sender.send, memnet.MemNet._push
    replay = Replay(json.loads(RUN.read_text()), 1.5, 0.5, every_observer=True)
    with _deliveries():
        [row] = trace_seed(replay, 98, [(6.95, 6, 9, 147.75)])
    frames = row["frames"]
    assert frames and {f[4] for f in frames} <= FATES
    assert {f[1] for f in frames} <= {6, 9}  # the pair's frames only
    assert any(f[4] == "crossed" for f in frames)  # the re-discovery's frame crossed
    # the instrumentation is gone after the run
    assert sending.Sender.send is send and memnet.MemNet._push is push


def test_a_missing_run_file_stops_with_its_code() -> None:
    assert main([str(RUN) + ".missing"]) == 66
