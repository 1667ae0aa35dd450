"""``bench/flight_graph_replay.py``: swarmd's own re-discoveries through the relay's graph
writer (swarmd.ros2.graph) and the flight peer's graph poll, on a cut swarmd run
(tests/fixtures/flight/README.md)."""

from __future__ import annotations

import json
from pathlib import Path

from bench.flight_graph_replay import (
    RESPONSE_S,
    flight_participants,
    graph_arrivals,
    main,
    replay,
)

CUT = Path(__file__).resolve().parent / "fixtures" / "flight"
SWARMD_CUT = CUT / "fly-out-swarmd-n20-r4-cut.json"


def test_drones_found_a_tenth_of_a_second_apart_reach_the_graph_at_the_first_nack() -> None:
    # the fly-out's heal: the commander's swarmd finds uav2, uav3, uav4 0.1 s apart; each
    # sample reaches the node's graph reader one heartbeat response after it is published
    # (before, the second and third waited for the next heartbeat, 0.5 s)
    found = [(93.0, 1), (93.1, 2), (93.2, 3)]
    arrived = graph_arrivals(flight_participants(4), 0, found)
    assert sorted(arrived) == [0, 1, 2]
    for k, (t, _) in enumerate(found):
        assert t <= arrived[k] <= t + RESPONSE_S + 1e-9


def test_the_poll_and_the_writer_only_ever_add_time() -> None:
    out = replay([json.loads(SWARMD_CUT.read_text())], seeds=3)
    assert len(out["own"]) == 49 and len(out["poll"]) == len(out["graph"]) == 3 * 49
    # each later stage is at least as late, pair by pair, so in order too
    own = sorted(out["own"] * 3)
    assert all(p >= o for p, o in zip(sorted(out["poll"]), own, strict=True))
    assert all(g >= p for g, p in zip(out["graph"], out["poll"], strict=True))


def test_a_missing_run_file_is_one_line(tmp_path: Path) -> None:
    assert main([str(tmp_path / "none.json")]) == 66
