"""Whole simulated runs at small N: determinism, swarmd convergence, CLI and calibration."""

from __future__ import annotations

import gc
import json
from pathlib import Path

import pytest
from swarmd_lab.sim.__main__ import main
from swarmd_lab.sim.calibrate import compare, load_testbed
from swarmd_lab.sim.runner import Scenario, run

import swarmd.discovery.received as received_module


def dumps(result: dict[str, object]) -> str:
    return json.dumps(result, sort_keys=True)


@pytest.mark.parametrize("protocol", ["swarmd", "cyclone-model", "zenoh-model"])
def test_same_seed_gives_byte_identical_json(protocol: str) -> None:
    scenario = Scenario(protocol, 6, seed=7, window_s=20.0)
    first, second = run(scenario), run(scenario)
    assert dumps(first) == dumps(second)


def test_another_seed_gives_another_run() -> None:
    a = run(Scenario("swarmd", 6, seed=1, window_s=20.0))
    b = run(Scenario("swarmd", 6, seed=2, window_s=20.0))
    assert dumps(a) != dumps(b)


@pytest.mark.parametrize("n", [2, 5, 12])
def test_swarmd_engines_converge(n: int) -> None:
    r = run(Scenario("swarmd", n, seed=3))
    assert r["success_rate"] == 1.0
    assert r["all_discovered"] is True
    assert r["delivery_success"] == 1.0


@pytest.mark.parametrize("n", [5, 12])
def test_swarmd_stays_under_ten_discovery_frames_per_node(n: int) -> None:
    r = run(Scenario("swarmd", n, seed=3))
    # the target (PHY frames incl. ACKs, first 60 s); a baseline is far above it
    assert r["frames_per_node_60s"] < 10
    stock = run(Scenario("cyclone-model", n, seed=3))
    assert stock["frames_per_node_60s"] > 10


def test_swarmd_on_a_paper_line_in_paper_mode_converges() -> None:
    r = run(Scenario("swarmd", 8, seed=4, placement="line", spacing_m=1.0, swarmd_mode="paper"))
    assert r["success_rate"] == 1.0
    # paper mode waits out U(0, 8..20 s) before announcing
    assert r["all_discovered_s"] is not None and r["all_discovered_s"] > 0


def test_the_engines_shared_decode_memo_changes_nothing(monkeypatch: pytest.MonkeyPatch) -> None:
    # the engine memoises decoding per datagram (one multicast reaches N - 1 engines of a
    # run); without the memo every receiver decodes its own copy, with the same outcome
    scenario = Scenario("swarmd", 5, seed=9, window_s=15.0)
    memo = run(scenario)
    monkeypatch.setattr(received_module, "decode", received_module.decode_fresh)
    plain = run(scenario)
    assert dumps(plain) == dumps(memo)


def test_a_swarmd_run_suspends_the_cyclic_collector_and_restores_it() -> None:
    seen: list[tuple[bool, tuple[int, int, int]]] = []

    def progress(_fraction: float) -> None:
        seen.append((gc.isenabled(), gc.get_threshold()))

    thresholds = gc.get_threshold()
    assert gc.isenabled()
    run(Scenario("swarmd", 4, seed=1, window_s=3.0), progress)
    assert seen and not any(enabled for enabled, _ in seen)
    assert gc.isenabled() and gc.get_threshold() == thresholds
    # a baseline model leaves cycles: its young collections go on, its full ones wait
    seen.clear()
    run(Scenario("zenoh-model", 4, seed=1, window_s=3.0), progress)
    assert seen and all(on and t[2] > 10**9 and t[:2] == thresholds[:2] for on, t in seen)
    assert gc.isenabled() and gc.get_threshold() == thresholds
    gc.disable()
    try:  # a caller that had it off (the CLI) keeps it off; a model's run still collects
        run(Scenario("swarmd", 4, seed=1, window_s=3.0))
        assert not gc.isenabled()
        seen.clear()
        run(Scenario("zenoh-model", 4, seed=1, window_s=3.0), progress)
        assert seen and all(on for on, _ in seen)
        assert not gc.isenabled() and gc.get_threshold() == thresholds
    finally:
        gc.enable()


def test_cli_turns_vouching_off(capsys: pytest.CaptureFixture[str]) -> None:
    args = ["--n", "6", "--window", "40", "--json", "--no-wall", "--quiet"]
    assert main(args) == 0
    vouched = json.loads(capsys.readouterr().out)
    assert main([*args, "--no-vouch"]) == 0
    plain = json.loads(capsys.readouterr().out)
    assert "vouch" not in vouched["scenario"]  # the default's JSON is as before the switch
    assert plain["scenario"]["vouch"] is False
    # vouched members stop renewing once the commander vouches for them
    assert plain["discovery_frames"] > vouched["discovery_frames"]
    assert plain["success_rate"] == vouched["success_rate"] == 1.0


def test_cli_prints_one_json_object_per_run(capsys: pytest.CaptureFixture[str]) -> None:
    code = main(
        [
            "--n",
            "3,4",
            "--protocol",
            "swarmd",
            "--repeat",
            "2",
            "--window",
            "10",
            "--json",
            "--no-wall",
            "--quiet",
        ]
    )
    assert code == 0
    lines = capsys.readouterr().out.splitlines()
    objs = [json.loads(line) for line in lines]
    assert [(o["n"], o["seed"]) for o in objs] == [(3, 1), (3, 2), (4, 1), (4, 2)]
    for o in objs:
        for key in (
            "protocol",
            "n",
            "seed",
            "success_rate",
            "all_discovered_s",
            "frames_per_node_60s",
            "peak_pps",
        ):
            assert key in o
        assert "wall_s" not in o


def test_cli_writes_results_and_plots(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code = main(
        [
            "--n",
            "3",
            "--protocol",
            "swarmd,cyclone-model",
            "--window",
            "5",
            "--quiet",
            "--out",
            str(tmp_path),
            "--plots",
        ]
    )
    assert code == 0
    runs = (tmp_path / "runs.jsonl").read_text().splitlines()
    assert len(runs) == 2
    assert "wall_s" in json.loads(runs[0])
    for name in (
        "summary.json",
        "rate_over_time_n3.png",
        "success_vs_n.png",
        "frames_per_node_vs_n.png",
    ):
        assert (tmp_path / name).stat().st_size > 0
    assert "| swarmd | 3 |" in capsys.readouterr().out


def test_cli_rejects_an_unknown_protocol_in_one_line(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        main(["--protocol", "rti"])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert "unknown protocol 'rti'" in err[-1]


def test_calibration_compares_matching_cells(tmp_path: Path) -> None:
    testbed = tmp_path / "testbed.jsonl"
    testbed.write_text(
        '{"protocol": "cyclonedds", "n": 10, "peak_pps": 1000, "discovery_frames": 5000}\n'
        '{"protocol": "cyclonedds", "n": 10, "peak_pps": 3000, "discovery_frames": 5000}\n'
    )
    reference = load_testbed(testbed)
    sim = [{"protocol": "cyclone-model", "n": 10, "peak_pps": 2500.0, "discovery_frames": 2000}]
    rows = {r["metric"]: r for r in compare(sim, reference, tolerance=0.3)}
    assert rows["peak_pps"]["rel_error"] == pytest.approx(0.25)
    assert rows["peak_pps"]["within_tolerance"] is True
    assert rows["discovery_frames"]["within_tolerance"] is False


def test_calibration_reads_testbed_run_files_and_skips_invalid_runs(tmp_path: Path) -> None:
    runs = tmp_path / "runs"
    runs.mkdir()
    (runs / "cyclonedds-n10-r1.json").write_text(
        '{"contender": "cyclonedds", "n": 10, "valid": true, "peak_pps": 3000,'
        ' "discovery_frames_60s": 4000}'
    )
    (runs / "cyclonedds-n10-r2.json").write_text(
        '{"contender": "cyclonedds", "n": 10, "valid": false, "peak_pps": 9, '
        '"discovery_frames_60s": 9}'
    )
    (runs / "notes.txt").write_text("ignored")
    assert load_testbed(runs) == [
        {
            "protocol": "cyclone-model",
            "n": 10,
            "valid": True,
            "peak_pps": 3000,
            "discovery_frames": 4000,
        }
    ]


def test_calibration_names_the_bad_line(tmp_path: Path) -> None:
    bad = tmp_path / "bad.jsonl"
    bad.write_text('{"protocol": "zenoh", "n": 5}\nnot json\n')
    with pytest.raises(ValueError, match=r"bad.jsonl: line 2"):
        load_testbed(bad)
