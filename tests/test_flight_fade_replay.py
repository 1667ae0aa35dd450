"""``bench/flight_fade_replay.py``: the N = 20 fade's geometry on MemNet (docs/discovery.md,
"A peer that lost us while we kept it", "The residual")."""

from __future__ import annotations

import json
import re
from pathlib import Path

from bench.flight_fade_replay import Replay, main, report

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
