"""``bench/flight_fade_replay.py``: the N = 20 fade's geometry on MemNet (docs/discovery.md,
"A peer that lost us while we kept it", "The residual")."""

from __future__ import annotations

import json
import re
from pathlib import Path

from bench.flight_fade_replay import (
    Replay,
    losses_line,
    main,
    rediscoveries,
    report,
    run_losses_line,
)

RUN = Path(__file__).resolve().parent.parent / (
    "bench/results/flight-lost-us/runs/flight-fade-swarmd-n20-r1.json"
)


def test_the_replay_rebuilds_the_traced_pairs_window() -> None:
    replay = Replay(json.loads(RUN.read_text()))
    # uav6 (index 5) and uav20 after uav20 lost it at 62.9 s: back at 64.25 s by the
    # geometry (-81.1 dBm), out again at 65.5 s (-82.3 dBm); the next 71.25-72.5 s
    assert replay.window(5, 62.9) == (64.25, 1.25)
    assert replay.window(5, 66.0) == (71.25, 1.25)
    assert not replay.crosses(5, 19, 63.9) and replay.crosses(5, 19, 64.3)


def test_the_report_counts_and_classes_the_fader_s_rediscoveries() -> None:
    text = report(RUN, 3)
    first = text.splitlines()[0]
    found = re.search(r"3 seeds on MemNet: (\d+) re-discoveries by uav20, (\d+) over 2 s", first)
    assert found is not None, first
    assert int(found.group(1)) > 0 and int(found.group(2)) <= int(found.group(1))


def test_a_missing_run_file_is_one_line_and_a_nonzero_exit(tmp_path: Path) -> None:
    assert main([str(tmp_path / "none.json")]) == 66


FLY_OUT = Path(__file__).resolve().parent.parent / (
    "bench/results/flight-stagger-1e20f9e/runs/flight-fly-out-swarmd-n20-r1.json"
)


def test_the_fly_out_is_replayed_for_every_drone_and_its_slow_pair_s_window() -> None:
    replay = Replay(json.loads(FLY_OUT.read_text()))
    assert replay.observers == list(range(20))
    # uav12 (index 11) and uav14 (index 13) after uav14 lost uav12 at 52.9 s: back at 89.0 s
    # by the geometry (-81.7 dBm), in range from then on
    start, length = replay.window(11, 52.9, 13)
    assert start == 89.0 and length > 40.0


def test_edge_loss_hits_multicasts_at_the_edge_only() -> None:
    replay = Replay(json.loads(FLY_OUT.read_text()), edge_db=1.5, edge_loss=0.5)
    assert replay.loss(11, 13, 88.0, True) == 1.0  # -82.8 dBm: out of range
    assert replay.loss(11, 13, 89.0, True) == 0.5  # -81.7 dBm: the edge
    assert replay.loss(11, 13, 89.0, False) == 0.5**4  # directed: MAC retries
    assert replay.loss(11, 13, 91.5, True) == 0.0  # -78.5 dBm: clear


def test_the_fly_out_report_counts_every_drone_s_rediscoveries() -> None:
    text = report(FLY_OUT, 1)
    found = re.search(r"(\d+) re-discoveries by every drone, (\d+) over 2 s", text)
    assert found is not None, text
    assert int(found.group(1)) > 100


def test_a_scenario_that_is_not_the_run_file_s_is_refused() -> None:
    assert main([str(FLY_OUT), "--scenario", "fade"]) == 65


def test_the_losses_line_counts_per_seed_bursts_and_quick_returns() -> None:
    burst = [(104.578, 19, peer) for peer in range(6)]  # a vouched lease's end: 6 at once
    losses = {1: [*burst, (130.0, 19, 7)], 2: [], 3: [(50.0, 19, 3)]}
    rows = [(1, 0.3), (1, 0.9), (1, 2.5), (3, 1.0)]  # (seed, latency): one over 2 s
    line = losses_line(losses, rows)
    assert "8 in 3 seeds (per seed min 0, p50 1, max 7; at most 1 in 2)" in line
    assert "1 bursts of 5+ at one instant (largest 6)" in line
    assert line.endswith("re-discovered within 2 s: 3")


def test_the_report_lists_the_fader_s_losses_found_again_or_not() -> None:
    replay = Replay(json.loads(RUN.read_text()))
    losses: list[tuple[float, int, int]] = []
    rows = rediscoveries(replay, 1, losses=losses)
    assert losses and {i for _, i, _ in losses} == {19}
    # every re-discovery follows one of these losses
    assert len(rows) <= len(losses)
    assert {(lost_at, j) for *_, j, _, _, lost_at in rows} <= {(t, j) for t, _, j in losses}


def test_the_run_s_own_losses_are_set_beside_the_replay_s() -> None:
    run = json.loads(RUN.read_text())  # flight-lost-us: uav20 lost 11, five of them at once
    line = run_losses_line(run, [19])
    assert line == "  the run itself: PeerLost by the observers 11; bursts of 5+: 5 at 62.904 s"
    assert run_losses_line(run, [0]).endswith("bursts of 5+: none")


def test_the_time_in_range_skips_the_seconds_between_windows() -> None:
    """uav6 and uav20 (the traced pair above): in range 64.25-65.5 s and 71.25-72.5 s, so
    from 64.25 s to 72.0 s the pair was in range 1.25 + 0.75 s, not 7.75 s."""
    replay = Replay(json.loads(RUN.read_text()))
    assert replay.in_range_s(5, 19, 64.25, 72.0) == 2.0
    assert replay.in_range_s(19, 5, 64.25, 65.0) == 0.75
    assert replay.in_range_s(5, 19, 66.0, 70.0) == 0.0
    assert replay.in_range_s(5, 19, 72.0, 64.25) == 0.0


def test_every_observer_of_a_fade_counts_the_fader_s_peers_finding_it() -> None:
    replay = Replay(json.loads(RUN.read_text()), every_observer=True)
    assert replay.observers == list(range(20))
    text = report(RUN, 1, every_observer=True)
    assert "re-discoveries by every drone of uav20" in text.splitlines()[0]
    assert "by the time in range from the return:" in text
