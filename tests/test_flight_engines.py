"""``bench.flight_engines``: swarmd's cells side by side across engine directories."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from bench import flight_engines


def _measures(p50: float | None, top: float | None, per_pair: float | None) -> dict[str, object]:
    return {
        "rediscovery_s": {"p50": p50, "max": top},
        "reboot_seen_by_peers_s": {"max": 0.5},
        "reboot_finds_peers_s": {"max": 0.7},
        "frames_per_rejoining_pair": {"per_pair": per_pair},
        "lost_reports": {"real": 3, "intermittent": 1, "dropout": 0, "false": 0},
        "readiness_delivery": {"ratio": 0.995},
    }


def _write(root: Path, name: str, measures: dict[str, object]) -> None:
    runs = root / "runs"
    runs.mkdir(parents=True, exist_ok=True)
    (runs / name).write_text(json.dumps({"measures": measures}))


def test_each_cell_reads_every_engine_in_order(tmp_path: Path) -> None:
    old, new = tmp_path / "engine-a", tmp_path / "engine-b"
    _write(old, "flight-split-swarmd-n10-r1.json", _measures(0.3, 2.65, 1.4))
    _write(new, "flight-split-swarmd-n10-r1.json", _measures(0.2, 0.76, 1.96))
    _write(new, "flight-reboot-swarmd-n20-r1.json", _measures(None, None, None))
    lines = flight_engines.table([old, new])
    split10 = next(line for line in lines if line.startswith("| split, N = 10 |"))
    assert "0.30 / 2.65 s → 0.20 / 0.76 s" in split10
    assert "1.40 → 1.96" in split10
    assert "99.5 % → 99.5 %" in split10
    reboot20 = next(line for line in lines if line.startswith("| reboot, N = 20 |"))
    assert "not run → 0.50 / 0.70 s" in reboot20  # the reboot's own timing columns
    assert "not run → -" in reboot20  # no rejoining pair in a reboot
    assert len(lines) == 2 + 10


def test_a_directory_without_runs_is_an_error(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as stop:
        flight_engines.main([str(tmp_path)])
    assert stop.value.code == 2
    assert str(tmp_path) in capsys.readouterr().err
