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
    "bench/results/flight-stagger-c294800/runs/flight-fade-swarmd-n20-r2.json"
)


def test_the_seekers_that_put_ours_off_draw_the_fader_s_multicast_answer() -> None:
    """Seed 47, uav12 and uav20 (docs/flight-history.md, "The fade's slow return at N = 20
    (session 11)"). On main (33b4934) uav20 answered each seeker that put uav12's seek off
    (uav1, uav3, uav16) with a DATA(p) directed to it alone, and uav12 found uav20 18.90 s
    after the return. Since h-seek-answer the answer to uav1's seek is a multicast that
    uav12 hears: found 0.71 s after the return. --directed still lists directed frames."""
    run = json.loads(FADE_N20_R2.read_text())
    lines = trace(run, 47, 11, 19, 46.0, 50.5, directed=True).splitlines()
    head = lines[0].split()
    assert head[0:3] == ["uav12", "lost", "uav20"]
    found_after_s = float(head[-2].strip("(+"))
    assert found_after_s <= 2.0, lines[0]
    put_off = next(i for i, line in enumerate(lines) if "put off" in line and "by uav1 " in line)
    assert "uav20 multicasts (reaches uav12)" in lines[put_off + 1]
    assert any("uav20 sends directed to" in line for line in lines)
    assert not any("directed" in line for line in trace(run, 47, 11, 19, 46.0, 50.5).split("\n"))
