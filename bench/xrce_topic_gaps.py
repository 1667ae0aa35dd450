"""How often a PX4-like client publishes each topic, as swarmd's agent receives it.

    .venv/bin/python bench/xrce_topic_gaps.py [TAP.jsonl]

Replays the PX4-like client's datagrams of a recorded session (default: the golden one,
``tests/fixtures/xrce/px4-1.16-core.tap.jsonl``, 40 s with PX4 1.16's uxrce_dds_client call
for call; docs/px4.md) into swarmd's ``XrceAgent`` at their recorded times and prints, per
topic, the samples and the gap between two in a row (min, median, max). The gap of
``vehicle_status`` bounds how soon a command can be confirmed over XRCE: the first sample
received an ack timeout after the send does it (docs/px4.md, "Fresh state"). A reading, not
a test: nothing asserted.
"""

from __future__ import annotations

import json
import sys
from collections import defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from swarmd.xrce.events import SampleReceived  # noqa: E402
from tests.test_xrce_golden import replay_into_agent  # noqa: E402

TAP = ROOT / "tests" / "fixtures" / "xrce" / "px4-1.16-core.tap.jsonl"


def gaps(path: Path) -> dict[str, list[float]]:
    """topic name -> the arrival times (s from the first datagram) of its samples."""
    records = [json.loads(line) for line in path.read_text().splitlines()]
    px4 = records[0]["client"]  # the PX4-like client speaks first
    arrivals: dict[str, list[float]] = defaultdict(list)
    for now, agent in replay_into_agent(records, px4):
        agent.datagrams_to_send()
        while (event := agent.next_event()) is not None:
            if isinstance(event, SampleReceived):
                arrivals[event.topic_name].append(now)
    return arrivals


def main() -> None:
    path = Path(sys.argv[1]) if len(sys.argv) > 1 else TAP
    for topic, times in sorted(gaps(path).items()):
        deltas = sorted(b - a for a, b in zip(times, times[1:], strict=False))
        if not deltas:
            print(f"{topic}: 1 sample")
            continue
        print(
            f"{topic}: {len(times)} samples over {times[-1] - times[0]:.1f} s, gap min "
            f"{deltas[0]:.3f} s, median {deltas[len(deltas) // 2]:.3f} s, max {deltas[-1]:.3f} s"
        )


if __name__ == "__main__":
    main()
