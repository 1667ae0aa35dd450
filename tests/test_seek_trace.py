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


FADE_N20_R2 = Path(__file__).resolve().parent.parent / (
    "bench/results/flight-stagger/runs/flight-fade-swarmd-n20-r2.json"
)


def test_directed_lists_the_fader_s_answers_to_the_seekers_that_put_ours_off() -> None:
    """Seed 47, uav12 and uav20 (docs/flight-history.md, "The fade's slow return at N = 20
    (session 11)"): uav20 answers each seeker directed; without --directed none is shown."""
    run = json.loads(FADE_N20_R2.read_text())
    lines = trace(run, 47, 11, 19, 47.75, 49.75, directed=True).splitlines()
    answers = [line.split()[-1] for line in lines if "uav20 sends directed to" in line]
    put_off_by = [line.split(" by ")[1].split()[0] for line in lines if "seek put off" in line]
    # the three whose seeks put uav12's off inside the window each got uav20's answer alone
    assert set(put_off_by) == {"uav1", "uav3", "uav16"}
    assert set(put_off_by) <= set(answers)
    assert not any("directed" in line for line in trace(run, 47, 11, 19, 47.75, 49.75).split("\n"))
