"""bench/wifi/flight_matrix.py (``flight_report --matrix``): the flight matrix and swarmd's
targets from synthetic run records."""

from __future__ import annotations

import subprocess
from pathlib import Path
from typing import Any

import pytest

from bench.wifi import flight_matrix as fm
from bench.wifi import flight_report


def record(
    scenario: str = "split",
    contender: str = "swarmd",
    n: int = 10,
    run: int = 1,
    *,
    valid: bool = True,
    loss_p50: float | None = 18.0,
    false: int = 0,
    red_p50: float | None = 0.5,
    red_max: float | None = 1.0,
    per_pair: float | None = 1.0,
    ratio: float | None = 0.995,
    missed: int = 0,
    never: int = 0,
    commit: str = "aaaaaaaaaa",
    started: float = 1_795_716_696.0,
    restarts: list[list[Any]] | None = None,
    seen_max: float | None = None,
    finds_max: float | None = None,
) -> dict[str, Any]:
    """A run file's fields that the matrix reads, nothing more."""
    red_count = 0 if red_p50 is None and red_max is None else 5
    return {
        "scenario": scenario,
        "contender": contender,
        "n": n,
        "run": run,
        "valid": valid,
        "setup": {"commit": commit, "dilation": 1.0},
        "go": {"harness_launch": started},
        "restarts": restarts or [],
        "measures": {
            "loss_latency_s": {"count": 1, "p50": loss_p50, "max": loss_p50},
            "missed_losses": missed,
            "false_losses": false,
            "rediscovery_s": {"count": red_count, "p50": red_p50, "max": red_max},
            "not_rediscovered": never,
            "reboot_seen_by_peers_s": {"count": 1, "p50": seen_max, "max": seen_max},
            "reboot_finds_peers_s": {"count": 1, "p50": finds_max, "max": finds_max},
            "frames_per_rejoining_pair": {} if per_pair is None else {"per_pair": per_pair},
            "readiness_delivery": {"ratio": ratio},
        },
    }


def files(*records: dict[str, Any]) -> list[fm.RunFile]:
    return [fm.RunFile(Path(f"/nowhere/r{k}.json"), r) for k, r in enumerate(records)]


def measure(title: str) -> fm.Measure:
    return next(m for m in fm.MEASURES if m.title.startswith(title))


def test_a_cell_is_the_median_and_range_over_its_valid_runs_only() -> None:
    runs = files(
        record(run=1, red_max=1.0),
        record(run=2, red_max=3.0),
        record(run=3, red_max=2.0),
        record(run=4, red_max=99.0, valid=False),  # would move the median and the range
    )
    assert fm.cell(runs, measure("re-discovery max")) == "2.00 s (1.00-3.00)"
    assert fm.runs_cell(runs) == "3/4 (k 1)"


def test_false_losses_are_summed_over_valid_runs_and_invalid_ones_left_out() -> None:
    runs = files(
        record(run=1, false=1), record(run=2, false=2), record(run=3, false=7, valid=False)
    )
    assert fm.cell(runs, measure("false losses")) == "3"


def test_a_cell_without_a_run_says_not_run_and_one_without_a_valid_run_says_so() -> None:
    assert fm.cell([], measure("readiness")) == "not run"
    assert fm.runs_cell([]) == "not run"
    assert fm.cell(files(record(valid=False)), measure("readiness")) == "no valid run (0/1)"


def test_runs_without_the_measure_are_flagged_not_counted() -> None:
    runs = files(record(run=1, red_p50=None, red_max=None), record(run=2, red_p50=0.25))
    assert fm.cell(runs, measure("re-discovery p50")) == "0.25 s [1/2]"


def test_pairs_never_found_again_make_the_max_never_and_are_counted() -> None:
    runs = files(record(contender="ros2", red_p50=None, red_max=None, never=50))
    assert fm.cell(runs, measure("re-discovery max")) == "never, 50 never found"
    assert fm.cell(files(record(missed=45)), measure("loss reported")) == "18.0 s, 45 missed"


def test_a_reboot_runs_rediscovery_is_the_restarts_either_way() -> None:
    r = record("reboot", red_p50=None, red_max=None, restarts=[[60.0, 3]], seen_max=1.4)
    r["measures"]["reboot_finds_peers_s"]["max"] = 3.9
    assert fm.rediscovery_max(r) == 3.9
    assert fm.rediscovery_p50(r) == 1.4


def test_the_tables_put_every_scenario_and_contender_in_place() -> None:
    runs = files(
        record("blackout", "swarmd", 10, ratio=0.97),
        record("split", "zenoh", 10, ratio=0.91),
        record("split", "zenoh", 20, ratio=0.5),  # the other N: not in N = 10's tables
    )
    lines = fm.tables(runs, 10)
    start = lines.index("**readiness delivery**, N = 10:")
    rows = {line.split(" | ")[0].lstrip("| "): line for line in lines[start + 4 : start + 9]}
    assert (
        rows["blackout"]
        == "| blackout | 97.0 % | not run | not run | not run | not run | not run | not run |"
    )
    assert (
        rows["split"]
        == "| split | not run | not run | not run | not run | 91.0 % | not run | not run |"
    )
    assert set(rows) == set(fm.SCENARIOS)


@pytest.mark.parametrize(
    ("target", "fields", "met"),
    [
        ("false", {"false": 0}, True),
        ("false", {"false": 1}, False),
        ("rediscovery", {"red_max": 2.0}, True),
        ("rediscovery", {"red_max": 2.001}, False),
        ("rediscovery", {"red_max": None, "red_p50": None, "never": 1}, False),
        ("frames", {"per_pair": 4.0}, True),
        ("frames", {"per_pair": 4.01}, False),
        ("readiness", {"ratio": 0.99}, True),
        ("readiness", {"ratio": 0.9899}, False),
    ],
)
def test_targets_at_their_boundaries(target: str, fields: dict[str, Any], met: bool) -> None:
    vs = fm.verdicts(files(record("split", **fields)))
    (v,) = [v for v in vs if v.target == target and v.scenario == "split" and v.n == 10]
    assert v.met is met
    assert ("**met**" if met else "**not met**") in v.text


@pytest.mark.parametrize(
    ("ratio", "shown", "met"),
    [
        (0.9895, "98.9 %", False),  # was shown as 99.0 % beside its "not met"
        (0.98949, "98.9 %", False),
        (0.99, "99.0 %", True),
        (0.99951, "100.0 %", True),  # rounding up elsewhere is kept
        (0.97459, "97.5 %", False),
    ],
)
def test_a_readiness_under_the_target_never_reads_as_the_target(
    ratio: float, shown: str, met: bool
) -> None:
    """ROS 2 on swarmd's blackout at N = 20 (1,195 of 1,208, ratio 0.9895) read 99.0 % in the
    matrix and was judged under 99 %: the figure shown must agree with the verdict."""
    runs = files(record(ratio=ratio))
    assert fm.cell(runs, measure("readiness")) == shown
    (v,) = [
        v
        for v in fm.verdicts(runs)
        if v.target == "readiness" and v.scenario == "split" and v.n == 10
    ]
    assert v.met is met
    assert v.text.endswith(f": {shown}")


@pytest.mark.parametrize(
    ("red_max", "shown", "met"),
    [
        (2.004, "2.01 s", False),  # ".2f" read 2.00 s beside its "not met"
        (2.0, "2.00 s", True),
        (1.996, "2.00 s", True),  # rounding up elsewhere is kept
        (2.021, "2.02 s", False),
    ],
)
def test_a_rediscovery_over_the_target_never_reads_as_the_target(
    red_max: float, shown: str, met: bool
) -> None:
    """The same rule as readiness's, for the 2 s bound: the figure agrees with the verdict."""
    runs = files(record(red_max=red_max))
    assert fm.cell(runs, measure("re-discovery max")) == shown
    (v,) = [
        v
        for v in fm.verdicts(runs)
        if v.target == "rediscovery" and v.scenario == "split" and v.n == 10
    ]
    assert v.met is met
    assert f": {shown}" in v.text


def test_one_failing_valid_run_fails_the_cell_and_an_invalid_one_does_not() -> None:
    ok, bad = record(run=1, red_max=1.0), record(run=2, red_max=5.0)
    invalid_bad = record(run=3, red_max=50.0, valid=False)
    vs = fm.verdicts(files(ok, bad))
    assert next(v for v in vs if v.target == "rediscovery" and v.scenario == "split").met is False
    vs = fm.verdicts(files(ok, invalid_bad))
    v = next(v for v in vs if v.target == "rediscovery" and v.scenario == "split")
    assert v.met is True
    assert "1 of 1 valid run" in v.text


def test_verdicts_are_for_swarmd_only_and_not_known_without_a_valid_run() -> None:
    vs = fm.verdicts(
        files(record("split", "cyclonedds", red_max=30.0), record("fade", valid=False))
    )
    split = [v for v in vs if v.scenario == "split" and v.n == 10]
    assert {v.met for v in split} == {None}
    fade = next(v for v in vs if v.target == "false" and v.scenario == "fade" and v.n == 10)
    assert fade.met is None
    assert "no valid run (0 of 1)" in fade.text
    # no frames target where there is no heal
    assert not [v for v in vs if v.target == "frames" and v.scenario in ("fade", "reboot")]


def newer(_: str, made: str) -> bool:
    """A stand-in for ``since_counts``: the commits named "new..." are the since's or after."""
    return made.startswith("new")


def test_since_commit_drops_older_runs_on_swarmd_only() -> None:
    """ROS 2 on swarmd's daemon is swarmd: its runs at an older engine are left out like
    swarmd's own (before, they mixed into its medians); a stock stack's never are."""
    runs = files(
        record(commit="old0000000"),
        record(run=2, commit="new0000000+dirty"),
        record(contender="ros2-swarmd", commit="old1111111"),
        record(contender="ros2-swarmd", run=2, commit="new0000000"),
        record(contender="zenoh", commit="old0000000"),
        record(n=5),  # outside the matrix
    )
    sel = fm.select(runs, newer)
    assert [(f.run["contender"], f.run["run"]) for f in sel.runs] == [
        ("swarmd", 2), ("ros2-swarmd", 2), ("zenoh", 1),
    ]  # fmt: skip
    assert [(f.run["contender"], fm.commit(f.run)) for f in sel.older] == [
        ("swarmd", "old0000000"), ("ros2-swarmd", "old1111111"),
    ]  # fmt: skip
    assert len(sel.outside) == 1
    text = fm.block(runs, command="cmd", docs_dir=Path("/nowhere"), counts=newer,
                    since=fm.Since("new0000"))  # fmt: skip
    assert (
        "- swarmd: runs at `new0000` or after (the engine as shipped); left out, older: 1" in text
    )
    assert "- ROS 2 on swarmd: runs at `new0000` or after (the engine as shipped); left" in text
    assert (
        "- `old1111111`: 1 run file(s), 2026-11-26 18:11 UTC (ros2-swarmd N=10: split r1)" in text
    )


def test_a_cell_with_only_older_runs_says_so_not_not_run() -> None:
    # flown, but every run of the cell is older than --since-commit: "not run" would read as
    # never flown (a reader takes it literally); the count says how many were left out
    runs = files(
        record("fade", commit="old0000000"),
        record("fade", run=2, commit="old0000000"),
        record("split", commit="new0000000"),
        record("split", contender="ros2-swarmd", commit="old1111111"),
    )
    text = fm.block(runs, command="cmd", docs_dir=Path("/nowhere"), counts=newer,
                    since=fm.Since("new0000"))  # fmt: skip
    runs_table = text.split("**runs, valid/total (time dilation k)**, N = 10:")[1]
    cells = [[c.strip() for c in line.strip("|").split("|")] for line in runs_table.split("\n")]
    rows = {row[0]: row for row in cells[3:8]}
    assert rows["fade"][1] == "older runs only (2)"  # swarmd's column
    assert rows["split"][1] == "1/1 (k 1)"
    assert rows["split"][7] == "older runs only (1)"  # ROS 2 on swarmd's column
    assert rows["reboot"][1] == "not run"  # never flown at all
    sel = fm.select(runs, newer)
    readiness = fm.tables(sel.runs, 10, sel.older)
    start = readiness.index("**readiness delivery**, N = 10:")
    assert "| fade | older runs only (2) | not run |" in readiness[start + 4 + 1]
    assert 'says "older runs only (n)", not "not run". The 3 older run file(s) left out:' in text
    # without --since-commit every run counts: the cell is measured, not "older"
    assert "older runs only" not in fm.block(
        runs, command="cmd", docs_dir=Path("/nowhere"), counts=None, since=None
    )


def test_a_run_file_cut_short_is_named_and_judges_nothing(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    (tmp_path / "flight-split-swarmd-n10-r1.json").write_text('{"scenario": "spl')
    with pytest.raises(ValueError, match="flight-split-swarmd-n10-r1.json: cannot be read"):
        fm.load([tmp_path])
    assert flight_report.main(["--matrix", str(tmp_path)]) == 2
    assert "flight-split-swarmd-n10-r1.json" in capsys.readouterr().err


def test_a_run_read_twice_counts_once() -> None:
    sel = fm.select(files(record(), record()), None)
    assert len(sel.runs) == 1
    assert sel.duplicates == 1


def test_git_descends_follows_the_history(tmp_path: Path) -> None:
    def git(*args: str) -> str:
        return subprocess.run(
            ["git", "-C", str(tmp_path), *args], check=True, capture_output=True, text=True
        ).stdout.strip()

    git("init", "-q")
    git("-c", "user.name=t", "-c", "user.email=t@t", "commit", "-q", "--allow-empty", "-m", "a")
    first = git("rev-parse", "--short=10", "HEAD")
    git("-c", "user.name=t", "-c", "user.email=t@t", "commit", "-q", "--allow-empty", "-m", "b")
    second = git("rev-parse", "--short=10", "HEAD")
    since_second = fm.git_descends(second, tmp_path)
    assert since_second(second + "+dirty")
    assert not since_second(first)
    assert fm.git_descends(first, tmp_path)(second)
    assert not since_second("0123456789")  # unknown to the repository: does not count
    # a --since-commit the repository does not know would leave every run on swarmd out
    with pytest.raises(ValueError, match="not a commit"):
        fm.git_descends("0123456789", tmp_path)


def test_the_figure_is_the_median_run_of_three_and_links_from_docs(tmp_path: Path) -> None:
    runs_dir = tmp_path / "bench" / "results" / "x" / "runs"
    runs_dir.mkdir(parents=True)
    chosen = []
    for k, slow in enumerate((3.0, 1.0, 2.0), start=1):
        path = runs_dir / f"flight-split-swarmd-n10-r{k}.json"
        path.with_suffix(".png").write_bytes(b"")
        chosen.append(fm.RunFile(path, record(run=k, red_max=slow)))
    assert fm.figure_run(chosen) is chosen[2]
    (line,) = [x for x in fm.figure_lines(chosen, tmp_path / "docs") if x.startswith("- split")]
    assert "[swarmd r3](../bench/results/x/runs/flight-split-swarmd-n10-r3.png)" in line


def docs_text() -> str:
    return (
        "# B\n\n## Flight (issue 20)\n\nIntro.\n\n### Old history\n\nkept\n\n"
        "## Security\n\nkept too\n"
    )


def test_write_docs_puts_the_block_after_the_intro_and_rewrites_it_idempotently(
    tmp_path: Path,
) -> None:
    docs = tmp_path / "docs" / "benchmarks.md"
    docs.parent.mkdir()
    docs.write_text(docs_text())
    runs = files(record())
    text = fm.block(runs, command="cmd", docs_dir=docs.parent, counts=None, since=None)
    fm.write_docs(docs, text)
    once = docs.read_text()
    assert once.index("Intro.") < once.index(fm.BEGIN) < once.index("### Old history")
    assert once.endswith("### Old history\n\nkept\n\n## Security\n\nkept too\n")
    fm.write_docs(docs, text)
    assert docs.read_text() == once
    other = fm.block(
        files(record(red_max=9.0)), command="cmd", docs_dir=docs.parent, counts=None, since=None
    )
    fm.write_docs(docs, other)
    again = docs.read_text()
    assert again.count(fm.BEGIN) == 1
    assert "9.00 s" in again
    assert again.split(fm.END)[1] == once.split(fm.END)[1]
    assert again.split(fm.BEGIN)[0] == once.split(fm.BEGIN)[0]


def test_the_cli_names_its_command_commits_and_dates_in_the_block(tmp_path: Path) -> None:
    import json

    runs = tmp_path / "runs"
    runs.mkdir()
    (runs / "a.json").write_text(json.dumps(record(commit="abcdef1234")))
    docs = tmp_path / "benchmarks.md"
    docs.write_text(docs_text())
    argv = ["--matrix", str(tmp_path), "--write-docs", str(docs)]
    assert flight_report.main(argv) == 0
    text = docs.read_text()
    assert f"`.venv/bin/python -m bench.wifi.flight_report --matrix {tmp_path} " in text
    assert "`abcdef1234`: 1 run file(s), 2026-11-26 18:11 UTC" in text
    before = text
    assert flight_report.main(argv) == 0
    assert docs.read_text() == before


def test_write_docs_without_a_flight_section_refuses(tmp_path: Path) -> None:
    docs = tmp_path / "b.md"
    docs.write_text("# nothing here\n")
    with pytest.raises(ValueError, match="Flight"):
        fm.write_docs(docs, f"{fm.BEGIN}\n{fm.END}")
    assert docs.read_text() == "# nothing here\n"


@pytest.mark.parametrize("page", ["benchmarks.md", "flight-lockstep.md"])
def test_docs_flight_matrix_is_what_the_committed_runs_generate(page: str) -> None:
    """issue 20, "Done when": docs/benchmarks.md's flight matrix (the staggered runs) and
    docs/flight-lockstep.md's (the lockstep runs before them) are what their own commands
    make of the committed run files. On a failure, rerun the command the block names
    (after adding, moving or re-measuring run files)."""
    import re
    import shlex
    import subprocess

    from bench.wifi import flight_matrix

    repo = Path(__file__).resolve().parents[1]
    docs = (repo / "docs" / page).read_text()
    found = re.search(
        r"Generated by `\.venv/bin/python -m bench\.wifi\.flight_report ([^`]*)`", docs
    )
    assert found, f"no generated flight matrix in docs/{page}"
    raw = shlex.split(found.group(1))
    assert "--matrix" in raw
    since = flight_matrix.parse_since(flight_matrix.since_args(raw))
    shallow = subprocess.run(
        ["git", "-C", str(repo), "rev-parse", "--is-shallow-repository"],  # noqa: S607
        capture_output=True, text=True, check=False,
    ).stdout.strip()  # fmt: skip
    if since is not None and shallow != "false":
        pytest.skip(f"a shallow or git-less checkout cannot tell which runs descend from {since}")
    skip = {"--matrix", "--since-commit", "--write-docs", f"docs/{page}"}
    skip |= set(flight_matrix.since_args(raw))
    paths = [repo / a for a in raw if a not in skip]
    counts = flight_matrix.since_counts(since, repo)
    text = flight_matrix.block(
        flight_matrix.load(paths),
        command=".venv/bin/python -m bench.wifi.flight_report " + shlex.join(raw),
        docs_dir=repo / "docs", counts=counts, since=since,
    )  # fmt: skip
    assert text in docs


def test_every_run_in_the_staggered_matrix_was_flown_staggered() -> None:
    """The staggered matrix (docs/benchmarks.md) reads ``bench/results/flight-stagger/``
    alone: a lockstep run there (``setup.stagger_s`` 0 or absent, as every run before
    ``flight_run --stagger-s`` existed) would be judged as a staggered one. Session 9 found
    one such file copied in by hand; lockstep runs go to ``flight-stock-lockstep/``."""
    import json

    runs = sorted(
        (Path(__file__).resolve().parents[1] / "bench/results/flight-stagger/runs").glob("*.json")
    )
    assert runs
    lockstep = [
        run.name for run in runs if not json.loads(run.read_text())["setup"].get("stagger_s")
    ]
    assert lockstep == []


def test_the_runs_table_counts_the_runs_that_flew_beside_another() -> None:
    shared = {**record(run=2), "concurrent_runs": 1}
    older = record(run=3)  # a file from before the field: alone
    assert fm.beside(older) == 0 and fm.beside(shared) == 1
    assert fm.runs_cell(files(record(run=1), shared, older)) == "3/3 (k 1; 1 beside another)"
    assert fm.runs_cell(files(record(run=1))) == "1/1 (k 1)"


def test_the_runs_table_of_flight_report_shows_beside_per_run() -> None:
    from bench.wifi import flight, flight_measures

    m = flight_measures.measure(flight.make("split", 3).truth(), {}, {}, n=3, lease_s=10.0)
    base = {"scenario": "split", "contender": "cyclonedds", "n": 3, "valid": True,
            "rt_lag_p99_ms": 0.5, "measures": m}  # fmt: skip
    runs = [{**base, "run": 1}, {**base, "run": 2, "concurrent_runs": 1}]
    head, _, alone, shared = flight_report.table(runs)
    col = head.split(" | ").index("beside")
    assert alone.split(" | ")[col] == "0" and shared.split(" | ")[col] == "1"


def test_lag_table_sets_runs_flown_beside_another_apart(tmp_path: Path) -> None:
    def dilated(run: int, p99: float, **extra: Any) -> dict[str, Any]:
        r = record(contender="cyclonedds", n=20, run=run, **extra)
        r["setup"] = {**r["setup"], "dilation": 6.0}
        return {**r, "rt_lag_p99_ms": p99, "rt_lag_max_ms": 10 * p99,
                "load_avg_at_start": [0.5 + run, 0.0, 0.0]}  # fmt: skip

    solo = files(dilated(1, 0.05), dilated(2, 0.07), dilated(3, 0.09))
    by_field = fm.RunFile(tmp_path / "a.json", {**dilated(4, 0.5), "concurrent_runs": 1})
    by_hand = fm.RunFile(tmp_path / "b.json", dilated(5, 0.7))  # started by hand, no field
    undilated = files(record(run=6))  # k = 1: never flown beside, not in the table
    lines = flight_report.lag_table([*solo, by_field, by_hand, *undilated], [by_hand.path])
    alone = "| 6 | 20 | alone | 3 (3) | 0.07 (0.05-0.09) | 0.70 (0.50-0.90) | 2.50 |"
    beside = "| 6 | 20 | beside another | 2 (2) | 0.60 (0.50-0.70) | 6.00 (5.00-7.00) | 5.00 |"
    assert lines[2:] == [alone, beside]
