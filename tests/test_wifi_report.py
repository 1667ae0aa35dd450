"""bench/wifi/report.py: which runs reach the main table and how swarmd is paired."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from bench.wifi import report


def _row(contender: str, n: int, k: float, valid_runs: int) -> dict[str, Any]:
    return {"contender": contender, "n": n, "k": k, "valid_runs": valid_runs}


def _run(
    contender: str,
    n: int,
    k: float,
    run: int,
    peak: int,
    *,
    valid: bool = True,
    commit: str = "abc",
) -> dict[str, Any]:
    return {
        "contender": contender,
        "n": n,
        "run": run,
        "valid": valid,
        "peak_pps": peak,
        "setup": {"dilation": k, "commit": commit},
    }


def test_main_k_is_the_k_with_most_valid_runs_ties_to_the_larger() -> None:
    ks = report.main_k(
        [
            _row("fastdds", 5, 1.0, 3),  # the undilated repeats
            _row("fastdds", 5, 3.0, 1),  # the method's check beside them
            _row("fastdds", 20, 4.0, 0),  # lagged: never main
            _row("fastdds", 20, 6.0, 2),
            _row("zenoh", 10, 2.0, 1),
            _row("zenoh", 10, 3.0, 1),
            _row("cyclonedds", 20, 4.0, 0),
            _row("cyclonedds", 20, 6.0, 0),
        ]
    )
    assert ks[("fastdds", 5)] == 1.0
    assert ks[("fastdds", 20)] == 6.0
    assert ks[("zenoh", 10)] == 3.0
    assert ks[("cyclonedds", 20)] == 6.0  # nothing valid: the largest k, shown as 0/N


def test_pairs_only_valid_runs_of_the_same_repeat_and_k() -> None:
    runs = [
        _run("swarmd", 10, 3.0, 1, 40),
        _run("fastdds", 10, 3.0, 1, 800),
        _run("swarmd", 10, 3.0, 2, 50),
        _run("fastdds", 10, 3.0, 2, 1000, valid=False),  # lagged: no pair
        _run("fastdds", 10, 6.0, 3, 900),  # another k: no pair
        _run("swarmd", 10, 3.0, 3, 45),
    ]
    assert report.paired_ratios(runs, "fastdds", "peak_pps") == {(10, 3.0): [0.05]}
    both = report.paired_ratios(runs, "fastdds", "peak_pps", include_invalid=True)
    assert both == {(10, 3.0): [0.05, 0.05]}


def test_runs_of_different_code_never_pair() -> None:
    runs = [
        _run("swarmd", 20, 6.0, 1, 60, commit="today"),
        _run("zenoh", 20, 6.0, 1, 10000, commit="yesterday"),  # kept from an earlier campaign
        _run("cyclonedds", 20, 6.0, 1, 6000, commit="today"),
    ]
    assert report.paired_ratios(runs, "zenoh", "peak_pps") == {}
    assert report.paired_ratios(runs, "cyclonedds", "peak_pps") == {(20, 6.0): [0.01]}


def _full(
    contender: str,
    n: int,
    run: int,
    pps: list[int],
    *,
    k: float = 3.0,
    valid: bool = True,
    discovery: int = 30,
    success: float = 1.0,
    commit: str | None = "abc1234567",
    classes: dict[str, list[int]] | None = None,
) -> dict[str, Any]:
    """A run file as run.py writes it, reduced to what the report reads."""
    failed = round((1.0 - success) * (n - 1))
    return {
        **_run(contender, n, k, run, max(pps), valid=valid),
        "invalid_reason": None if valid else "real-time lag p99 50.0 ms > 20.0 ms",
        "peak_discovery_pps": max(pps),
        "discovery_frames_60s": discovery,
        "success_rate": success,
        "success": success == 1.0,
        "failed_members": list(range(1, failed + 1)),
        "pps": pps,
        "class_pps": classes if classes is not None else {"other": pps},
        "rt_lag_p99_ms": 0.1 if valid else 50.0,
        "setup": {
            "dilation": k,
            "messages": 20,
            "started_at": 1.8e9 + run,
            **({} if commit is None else {"commit": commit}),
        },
    }


def _verdict(verdicts: list[report.Verdict], n: int, contender: str) -> report.Verdict:
    (v,) = [v for v in verdicts if v.n == n and v.contender == contender]
    return v


def test_peak_target_met_not_met_and_not_known_from_same_run_pairs() -> None:
    runs = [
        # N=10: 40 against 1000 and 45 against 1000 -> 4.0 % and 4.5 %: met in 2 of 2
        _full("swarmd", 10, 1, [40]),
        _full("cyclonedds", 10, 1, [1000]),
        _full("swarmd", 10, 2, [45]),
        _full("cyclonedds", 10, 2, [1000]),
        # N=10 against the server: 40/700 = 5.7 % over, 45/1000 within -> not met, 1 of 2
        _full("fastdds-server", 10, 1, [700]),
        _full("fastdds-server", 10, 2, [1000]),
        # N=20: the stock run lagged, so no pair: not known, never "met"
        _full("swarmd", 20, 1, [100], k=6.0),
        _full("zenoh", 20, 1, [10000], k=6.0, valid=False),
    ]
    verdicts = report.peak_verdicts(runs)
    met = _verdict(verdicts, 10, "cyclonedds")
    assert met.met is True
    assert "2 of 2 pairs within 5 %" in met.text
    assert "4.2 % (4.0-4.5)" in met.text
    over = _verdict(verdicts, 10, "fastdds-server")
    assert over.met is False
    assert "1 of 2 pairs within 5 %" in over.text
    unknown = _verdict(verdicts, 20, "zenoh")
    assert unknown.met is None
    assert "0 valid of 1 at k = 6" in unknown.text
    # at N = 10 and 20 every stock stack is judged, a stack never run there too
    absent = _verdict(verdicts, 20, "fastdds")
    assert absent.met is None
    assert "fastdds: no run" in absent.text
    assert not [v for v in verdicts if v.n == 5]  # nothing ran at N = 5


def test_peak_runs_of_different_campaigns_never_make_a_pair() -> None:
    runs = [
        _full("swarmd", 10, 1, [40], commit="abc1234567"),
        _full("cyclonedds", 10, 1, [1000], commit=None),  # session 2: no commit stamp
    ]
    v = _verdict(report.peak_verdicts(runs), 10, "cyclonedds")
    assert v.met is None
    assert "no same-run pair" in v.text
    assert "made at session-2" in v.text


def test_peak_pairs_at_every_k_not_only_the_main_one() -> None:
    runs = [
        # N=5: swarmd's main k is 3 (ties go to the larger k), zenoh ran only at k = 1;
        # the k = 1 runs are one campaign step all the same
        _full("swarmd", 5, 1, [20], k=1.0),
        _full("swarmd", 5, 1, [22], k=3.0),
        _full("zenoh", 5, 1, [300], k=1.0),
    ]
    v = _verdict(report.peak_verdicts(runs), 5, "zenoh")
    assert v.met is False  # 20 / 300 = 6.7 %
    assert "N=5 (k = 1), zenoh" in v.text
    assert "6.7 %" in v.text


def test_discovery_target_counts_every_valid_swarmd_run_at_n10() -> None:
    ok = [_full("swarmd", 10, 1, [40], discovery=31), _full("swarmd", 10, 2, [40], discovery=50)]
    assert report.discovery_verdict(ok).met is True
    over = [*ok, _full("swarmd", 10, 3, [40], discovery=81)]
    v = report.discovery_verdict(over)
    assert v.met is False
    assert "2 of 3 valid runs ≤ 50" in v.text
    assert "50 (31-81)" in v.text
    # an invalid run never counts, for or against
    lagged = [_full("swarmd", 10, 1, [40], discovery=81, valid=False)]
    assert report.discovery_verdict(lagged).met is None


def test_success_target_per_contender_and_n() -> None:
    runs = [
        _full("swarmd", 20, 1, [100], k=6.0),
        _full("fastdds", 20, 1, [9000], k=6.0),
        _full("fastdds", 20, 2, [9000], k=6.0, success=10 / 19),
        _full("cyclonedds", 20, 1, [9000], k=6.0, valid=False, success=0.0),
    ]
    verdicts = report.success_verdicts(runs)
    assert _verdict(verdicts, 20, "swarmd").met is True
    bad = _verdict(verdicts, 20, "fastdds")
    assert bad.met is False
    assert "1 of 2 valid runs ≥ 99 %" in bad.text
    assert "worst r2: 9 of 19 members" in bad.text
    assert _verdict(verdicts, 20, "cyclonedds").met is None  # its only run lagged


def test_coverage_needs_valid_runs_of_every_stock_stack_at_10_and_20() -> None:
    runs = [
        _full(c, n, 1, [1000], k=3.0 if n == 10 else 6.0)
        for c in ("cyclonedds", "zenoh", "fastdds")
        for n in (10, 20)
    ]
    runs.append(_full("fastdds-server", 10, 1, [700]))
    runs.append(_full("fastdds-server", 20, 1, [700], k=6.0, valid=False))
    by = {v.contender: v for v in report.coverage_verdicts(runs)}
    assert [by[c].met for c in ("cyclonedds", "zenoh", "fastdds")] == [True, True, True]
    assert by["fastdds-server"].met is False
    assert "N=20: 0 valid of 1 at k = 6" in by["fastdds-server"].text
    runs = [r for r in runs if r["contender"] != "zenoh" or r["n"] != 20]
    zenoh = next(v for v in report.coverage_verdicts(runs) if v.contender == "zenoh")
    assert zenoh.met is False
    assert "N=20: no run" in zenoh.text


def test_repeat_lines_name_cells_short_of_three_valid_repeats() -> None:
    runs = [
        *(_full("swarmd", 10, r, [40]) for r in (1, 2, 3)),
        _full("zenoh", 10, 1, [4000]),
        _full("zenoh", 10, 2, [4000], valid=False),
        _full("fastdds", 10, 1, [8000]),
    ]
    text = report.repeat_lines(report.summarise(runs))
    assert "swarmd" not in text
    assert "- zenoh N=10 k=3: 1 of 2 repeats valid, 1 not run\n" in text
    assert "- fastdds N=10 k=3: 1 run only\n" in text


def test_peak_composition_splits_the_busiest_second_and_sums_to_it() -> None:
    pps = [10, 47, 47, 5]
    classes = {
        "rtps_discovery": [8, 2, 30, 0],
        "rtps_user": [0, 16, 10, 0],
        "zenoh": [0, 0, 0, 0],
        "other": [2, 29, 7, 5],
    }
    run = _full("swarmd", 10, 1, pps, classes=classes)
    second, split = report.peak_composition(run)
    assert second == 1  # the first of two equal seconds
    assert split == {"rtps_discovery": 2, "rtps_user": 16, "zenoh": 0, "other": 29}
    # frames no class holds are shown, never silently dropped
    run["class_pps"] = {"rtps_discovery": [8, 2, 30, 0]}
    assert report.peak_composition(run)[1] == {"rtps_discovery": 2, "unclassified": 45}
    table = report.class_table([_full("swarmd", 10, 1, pps, classes=classes)])
    assert (
        "| swarmd | 10 | 3 | r1 (1) | 1 | 47 | 2 (4 %) | 16 (34 %) | 0 (0 %) | 29 (62 %) |" in table
    )


def test_class_table_shows_the_median_repeat() -> None:
    runs = [_full("fastdds", 10, r, [p]) for r, p in ((1, 900), (2, 700), (3, 800))]
    table = report.class_table(runs)
    assert "| fastdds | 10 | 3 | r3 (3) | 0 | 800 |" in table


def test_commit_lines_name_commits_and_unstamped_runs() -> None:
    runs = [
        _full("swarmd", 10, 1, [40], commit="6a8a5d1150"),
        _full("swarmd", 10, 2, [40], commit="6a8a5d1150"),
        _full("cyclonedds", 10, 1, [1000], commit=None),
    ]
    runs[0]["load_avg_at_start"] = [3.5, 2.0, 1.0]
    runs[1]["load_avg_at_start"] = [8.25, 2.0, 1.0]
    text = report.commit_lines(runs)
    assert "load average 3.5-8.2 when" in text
    assert "at `6a8a5d1150`: 2 runs" in text
    assert "N=10 k=3: swarmd r1-2" in text
    assert f"{report.SESSION2}: 1 run" in text


DOC = (
    "# Bench\n\nprose before, kept\r\n"
    "<!-- wifi:begin (bench/wifi/report.py OUT --docs docs/benchmarks.md) -->\n"
    "old generated text\n"
    "<!-- wifi:end -->\n\n"
    "### Not done\n\n- hand-written, kept \u00b5s  \n"
)


def test_replace_block_keeps_everything_outside_the_markers_byte_identical() -> None:
    out = report.replace_block(DOC, "\nnew block\n\n")
    head, _, rest = DOC.partition("old generated text\n")
    assert out == head + "new block\n" + rest
    assert "old generated text" not in out
    assert report.replace_block(out, "new block") == out  # idempotent


def test_replace_block_refuses_missing_or_doubled_markers() -> None:
    with pytest.raises(ValueError, match="wifi:begin"):
        report.replace_block("no markers here\n", "x")
    with pytest.raises(ValueError, match="wifi:end"):
        report.replace_block("<!-- wifi:begin (x) -->\ntext\n", "x")
    doubled = DOC.replace("### Not done", "<!-- wifi:begin (y) -->\n<!-- wifi:end -->\n")
    with pytest.raises(ValueError, match="more than one"):
        report.replace_block(doubled, "x")


def test_load_runs_reads_runs_and_never_superseded(tmp_path: Path) -> None:
    (tmp_path / "runs").mkdir()
    (tmp_path / "superseded").mkdir()
    (tmp_path / "runs" / "swarmd-n10-k3-r1.json").write_text(
        json.dumps(_full("swarmd", 10, 1, [40]))
    )
    (tmp_path / "superseded" / "fastdds-n20-k6-r1.json").write_text(
        json.dumps(_full("fastdds", 20, 1, [9000], k=6.0))
    )
    assert [r["contender"] for r in report.load_runs(tmp_path)] == ["swarmd"]


def test_docs_block_from_runs_rewrites_only_the_block(tmp_path: Path) -> None:
    runs = [
        _full("swarmd", 10, 1, [40], discovery=81),
        _full("cyclonedds", 10, 1, [1000]),
    ]
    docs = tmp_path / "benchmarks.md"
    docs.write_bytes(DOC.encode())
    report.write_docs(docs, runs, "bench/results/wifi-dilated")
    text = docs.read_bytes().decode()  # bytes: a CRLF outside the block must survive
    assert text.startswith(DOC.split("old generated")[0])
    assert text.endswith(DOC.split("<!-- wifi:end -->")[1])
    block = text.split("<!-- wifi:end -->")[0]
    assert "**not met**, 0 of 1 valid run ≤ 50" in block  # 81 discovery frames
    assert "N=10 (k = 3), cyclonedds: **met**, 1 of 1 pair within 5 %" in block


def test_load_runs_names_a_truncated_run_file(tmp_path: Path) -> None:
    (tmp_path / "runs").mkdir()
    (tmp_path / "runs" / "swarmd-n10-k3-r2.json").write_text('{"contender": "swa')
    with pytest.raises(ValueError, match="swarmd-n10-k3-r2.json: not a complete run file"):
        report.load_runs(tmp_path)


def test_docs_benchmarks_block_is_what_the_committed_runs_generate() -> None:
    """issue 13, "Done when": docs/benchmarks.md's commands reproduce its tables. On a
    failure: .venv/bin/python bench/wifi/report.py bench/results/wifi-dilated --docs
    docs/benchmarks.md (after adding or moving run files)."""
    repo = Path(__file__).resolve().parents[1]
    out = "bench/results/wifi-dilated"
    docs = (repo / "docs" / "benchmarks.md").read_bytes().decode()
    block = report.docs_block(report.load_runs(repo / out), out)
    assert report.replace_block(docs, block) == docs
