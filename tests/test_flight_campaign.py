"""The flight campaign's plan and runner (bench/wifi/flight_campaign.py), with a stand-in
for flight_run: no testbed, no ns-3."""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path
from typing import Any

import pytest

from bench.wifi import flight_campaign as fc
from bench.wifi import flight_matrix as fm
from bench.wifi import flight_schedule
from bench.wifi.contenders import SWARMD_VARIANTS
from bench.wifi.flight_run import ROS2_ON_SWARMD, run_file_name

# a stand-in for `python -m bench.wifi.flight_run`: writes the run file the real one would
# (a valid run of its cell; or fails when the contender is "zenoh"), and records its argv
FAKE = """#!{python}
import json, os, sys
sys.path.insert(0, os.getcwd())  # as `python -m` does: the campaign runs it in the repo
from pathlib import Path
from bench.wifi.flight_run import run_file_name
a = sys.argv[3:]
opt = dict(zip(a[::2], a[1::2]))
Path("{log}").open("a").write(json.dumps(a) + "\\n")
if opt["--contenders"] == "zenoh":
    sys.exit(1)
runs = Path(opt["--out"]) / "runs"
runs.mkdir(parents=True, exist_ok=True)
name = run_file_name(opt["--scenarios"], opt["--contenders"], int(opt["--n"]),
                     int(opt["--first-run"]), float(opt["--dilation"]))
cell = {{"scenario": opt["--scenarios"], "contender": opt["--contenders"],
        "n": int(opt["--n"]), "run": int(opt["--first-run"]), "valid": True}}
(runs / name).write_text(json.dumps(cell))
"""


@pytest.fixture(autouse=True)
def _quick_polls(monkeypatch: pytest.MonkeyPatch) -> None:
    # the stand-in ends in well under a second: look at it often, not every POLL_S
    monkeypatch.setattr(flight_schedule, "POLL_S", 0.05)


def _plan(tmp_path: Path, **kw: object) -> fc.Plan:
    args: dict[str, object] = {
        "repeats": 2,
        "sizes": (10, 20),
        "scenarios": ("split", "blackout"),
        "contenders": ("swarmd", "cyclonedds"),
        "dilation": {10: 3.0, 20: 6.0},
        "swarmd_out": tmp_path / "seek",
        "stock_out": tmp_path / "stock",
    }
    args.update(kw)
    return fc.plan(**args)  # type: ignore[arg-type]


def _record(c: fc.Cell, *, valid: bool = True, commit: str = "new0000000") -> dict[str, Any]:
    """The fields of ``c``'s run file that the plan reads, as flight_run writes them."""
    return {
        "scenario": c.scenario,
        "contender": c.contender,
        "n": c.n,
        "run": c.repeat,
        "valid": valid,
        "invalid_reason": None if valid else "real-time lag p99 20.4 ms > 20.0 ms",
        "rt_lag_p99_ms": 0.5 if valid else 20.36,
        "setup": {"commit": commit},
    }


def _write(path: Path, record: dict[str, Any]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(record))


def _cells(tmp_path: Path, **kw: object) -> list[fc.Cell]:
    return _plan(tmp_path, **kw).cells


def test_plan_takes_every_first_run_before_any_second(tmp_path: Path) -> None:
    cells = _cells(tmp_path)
    assert len(cells) == 2 * 2 * 2 * 2
    assert [c.repeat for c in cells] == [1] * 8 + [2] * 8
    assert [(c.n, c.scenario, c.contender) for c in cells[:4]] == [
        (10, "split", "swarmd"),
        (10, "split", "cyclonedds"),
        (10, "blackout", "swarmd"),
        (10, "blackout", "cyclonedds"),
    ]


def test_plan_names_the_files_flight_run_writes_in_each_contenders_directory(
    tmp_path: Path,
) -> None:
    by = {(c.repeat, c.n, c.scenario, c.contender): c for c in _cells(tmp_path)}
    swarmd = by[(1, 20, "split", "swarmd")]
    assert swarmd.k == 1.0
    assert swarmd.path == tmp_path / "seek" / "runs" / run_file_name("split", "swarmd", 20, 1, 1)
    assert swarmd.path.name == "flight-split-swarmd-n20-r1.json"
    stock = by[(2, 20, "blackout", "cyclonedds")]
    assert stock.k == 6.0
    assert stock.path.name == "flight-blackout-cyclonedds-n20-k6-r2.json"
    assert stock.path.parent == tmp_path / "stock" / "runs"
    # the argv flight_run gets writes exactly that file (its --out is the directory above runs/)
    argv = stock.argv("py")
    assert argv[argv.index("--out") + 1] == str(tmp_path / "stock")
    assert argv[argv.index("--first-run") + 1] == "2"


def test_estimate_is_the_dilated_window_plus_overhead() -> None:
    # split lasts 150 s; a stock peer runs 5 s past it; k = 6
    assert fc.estimate_s("split", 20, "cyclonedds", 6.0) == (150 + 5) * 6 + fc.OVERHEAD_S
    assert fc.estimate_s("split", 20, "swarmd", 1.0) == 150 + fc.OVERHEAD_S


def test_a_cell_with_a_valid_run_file_is_done_and_leaves_the_plan(tmp_path: Path) -> None:
    first = _cells(tmp_path, repeats=1, sizes=(10,))[0]
    _write(first.path, _record(first))
    lines = fc.plan_lines(_plan(tmp_path, repeats=1, sizes=(10,)))
    assert lines[0].startswith("flight campaign: 1 of 4 valid runs counted")
    assert "3 to run" in lines[0]
    assert not any(first.path.name in line for line in lines)


def test_an_invalid_run_is_kept_listed_and_replaced_by_the_next_free_repeat(
    tmp_path: Path,
) -> None:
    """Stock ROS 2's reboot at N = 20, r1: invalid (ns-3 lag p99 20.36 ms over the 20 ms
    bound). Three valid runs asked, r2 valid: the invalid r1 counts for nothing, so r3 and
    r4 are planned (before, its file made the cell done: only r3 was)."""
    one = dict(repeats=3, sizes=(20,), scenarios=("reboot",), contenders=("ros2",))
    r1, r2, _ = _cells(tmp_path, **one)
    _write(r1.path, _record(r1, valid=False))
    _write(r2.path, _record(r2))
    found = _plan(tmp_path, **one)
    assert [(c.repeat, c.round) for c in found.cells] == [(3, 2), (4, 3)]
    assert found.cells[1].path.name == "flight-reboot-ros2-n20-k6-r4.json"
    assert [(h.repeat, h.status) for h in found.held] == [(1, fc.INVALID), (2, fc.VALID)]
    assert found.counted() == 1
    lines = fc.plan_lines(found)
    assert lines[0].startswith("flight campaign: 1 of 3 valid runs counted")
    (kept,) = [line for line in lines if r1.path.name in line]
    assert "INVALID (real-time lag p99 20.4 ms > 20.0 ms), lag p99 20.36 ms" in kept


def test_a_cell_whose_first_run_was_invalid_flies_its_replacement_in_round_1(
    tmp_path: Path,
) -> None:
    """Every cell's first valid run before any second one: the replacement (file r2) is
    the cell's first valid run, so it is in round 1 beside the other cells' r1."""
    two = dict(repeats=2, sizes=(20,), scenarios=("reboot",), contenders=("ros2", "zenoh"))
    first = _cells(tmp_path, **two)[0]
    _write(first.path, _record(first, valid=False))
    found = _plan(tmp_path, **two)
    assert [(c.contender, c.repeat, c.round) for c in found.cells] == [
        ("ros2", 2, 1),
        ("zenoh", 1, 1),
        ("ros2", 3, 2),
        ("zenoh", 2, 2),
    ]


@pytest.mark.parametrize(
    ("body", "why"),
    [
        ('{"scenario": "split", "contend', "unreadable: cannot be read"),  # cut short
        ("[]", "unreadable: holds a JSON list"),
        ('{"scenario": "fade", "contender": "zenoh", "n": 10, "run": 1, "valid": true}',
         "unreadable: holds ('fade', 'zenoh', 10, 1)"),
    ],
)  # fmt: skip
def test_a_file_that_cannot_be_read_is_reported_not_counted(
    tmp_path: Path, body: str, why: str
) -> None:
    one = dict(repeats=1, sizes=(10,), scenarios=("split",), contenders=("cyclonedds",))
    (cell,) = _cells(tmp_path, **one)
    cell.path.parent.mkdir(parents=True)
    cell.path.write_text(body)
    found = _plan(tmp_path, **one)
    assert [(c.repeat, c.round) for c in found.cells] == [(2, 1)]
    (held,) = found.held
    assert held.status == fc.UNREADABLE and not held.counted
    assert held.why.startswith(why)
    assert any(why in line and cell.path.name in line for line in fc.plan_lines(found))


def test_runs_on_swarmd_before_since_commit_are_not_counted(tmp_path: Path) -> None:
    """ROS 2 on swarmd's daemon is swarmd: its runs at an older engine count no more than
    swarmd's own; a stock stack's run counts at any commit."""
    three = dict(repeats=1, sizes=(10,), scenarios=("split",),
                 contenders=("swarmd", "ros2-swarmd", "cyclonedds"))  # fmt: skip
    for c in _cells(tmp_path, **three):
        _write(c.path, _record(c, commit="old0000000"))
    found = _plan(
        tmp_path, **three, counts=lambda _, made: made.startswith("new"), since=fm.Since("new")
    )
    assert [(c.contender, c.repeat, c.round) for c in found.cells] == [
        ("swarmd", 2, 1),
        ("ros2-swarmd", 2, 1),
    ]
    assert {h.contender: h.status for h in found.held} == {
        "swarmd": fc.OLDER,
        "ros2-swarmd": fc.OLDER,
        "cyclonedds": fc.VALID,
    }
    assert "older: made at old0000000" in "\n".join(fc.plan_lines(found))
    # without --since-commit every commit counts
    assert _plan(tmp_path, **three).cells == []


def test_the_plan_counts_exactly_the_runs_the_matrix_uses(tmp_path: Path) -> None:
    """One rule, shared: per cell, the plan's counted runs are the matrix's valid runs
    (``flight_matrix.select`` and ``valid``) over the same files."""
    wide = dict(repeats=3, sizes=(10, 20), scenarios=("split", "reboot"),
                contenders=("swarmd", "ros2-swarmd", "zenoh"),
                swarmd_out=tmp_path / "d", stock_out=tmp_path / "d")  # fmt: skip
    for k, cell in enumerate(_cells(tmp_path, **wide)):
        if k % 4 != 3:  # some cells short, some runs invalid, some older
            _write(cell.path, _record(cell, valid=k % 5 != 0, commit=("old", "new")[k % 3 != 0]))

    def newer(_: str, made: str) -> bool:
        return made.startswith("new")

    found = _plan(tmp_path, **wide, counts=newer, since=fm.Since("new"))
    assert {h.status for h in found.held} == {fc.VALID, fc.INVALID, fc.OLDER}
    sel = fm.select(fm.load([tmp_path / "d"]), newer)
    for n in (10, 20):
        for s in ("split", "reboot"):
            for c in ("swarmd", "ros2-swarmd", "zenoh"):
                used = {f.path for f in fm.valid(fm.cell_runs(sel.runs, s, c, n))}
                counted = {
                    h.path for h in found.held if (h.n, h.scenario, h.contender) == (n, s, c)
                    and h.counted
                }  # fmt: skip
                assert counted == used, (n, s, c)
                planned = [x for x in found.cells if (x.n, x.scenario, x.contender) == (n, s, c)]
                assert len(planned) == 3 - len(used)


def test_on_swarmd_lists_every_contender_whose_daemon_is_swarmd() -> None:
    assert set(fm.ON_SWARMD) == {*SWARMD_VARIANTS, *ROS2_ON_SWARMD}


def _fake_python(tmp_path: Path) -> tuple[str, Path]:
    log = tmp_path / "argv.log"
    fake = tmp_path / "fakepy"
    fake.write_text(FAKE.format(python=sys.executable, log=log))
    fake.chmod(0o755)
    return str(fake), log


def test_run_starts_only_what_fits_before_until_and_each_run_once(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    python, log = _fake_python(tmp_path)
    cells = _cells(tmp_path, repeats=1, sizes=(10,), scenarios=("blackout",))
    swarmd, cyclone = cells  # blackout: ~166 s undilated, ~393 s at k = 3
    assert swarmd.estimate_s < 300 < cyclone.estimate_s
    assert fc.run_cells(cells, time.time() + 300, python) == 0
    assert swarmd.path.exists() and not cyclone.path.exists()
    assert len(log.read_text().splitlines()) == 1
    out = capsys.readouterr().out
    assert "skip n=10 blackout cyclonedds r1 k=3" in out
    # a second campaign finds the swarmd cell done and runs only the other
    assert fc.run_cells(cells, time.time() + 3600, python) == 0
    assert cyclone.path.exists()
    assert len(log.read_text().splitlines()) == 2


def test_a_run_that_writes_no_file_is_a_failure_and_the_campaign_goes_on(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    python, _ = _fake_python(tmp_path)
    cells = _cells(tmp_path, repeats=1, sizes=(10,), contenders=("zenoh", "swarmd"))
    assert fc.run_cells(cells, time.time() + 3600, python) == 1
    assert [c.done for c in cells] == [False, True, False, True]
    assert "no run file (exit 1)" in capsys.readouterr().out


def test_cli_plan_as_json_and_run_needs_a_deadline(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    base = ["--swarmd-out", str(tmp_path / "a"), "--stock-out", str(tmp_path / "b")]
    assert fc.main([*base, "--json", "--repeats", "1", "--n", "10", "--scenarios", "split"]) == 0
    rows = json.loads(capsys.readouterr().out)
    assert len(rows) == len(fc.CONTENDERS)
    assert {r["contender"] for r in rows} == set(fc.CONTENDERS)
    assert not any(r["done"] for r in rows)
    assert {r["status"] for r in rows} == {"to run"}
    # a file in a cell's place is a row of its own, with its status and why
    zenoh = next(c for c in _cells(tmp_path, stock_out=tmp_path / "b") if c.contender != "swarmd")
    _write(zenoh.path, _record(zenoh, valid=False))
    argv = [*base, "--json", "--repeats", "1", "--n", str(zenoh.n), "--scenarios",
            zenoh.scenario, "--contenders", zenoh.contender, "--since-commit", "any"]  # fmt: skip
    assert fc.main(argv) == 0
    kept, todo = json.loads(capsys.readouterr().out)
    assert (kept["status"], kept["done"], kept["counted"]) == ("invalid", True, False)
    assert kept["why"].startswith("INVALID (real-time lag p99")
    assert (todo["status"], todo["repeat"], todo["round"]) == ("to run", 2, 1)
    with pytest.raises(SystemExit) as stop:
        fc.main([*base, "--run"])
    assert stop.value.code == 2
    with pytest.raises(SystemExit):
        fc.main([*base, "--contenders", "opendds"])
    assert "no flight observer" in capsys.readouterr().err


def test_since_commit_defaults_to_the_documented_matrix_and_must_be_a_commit(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The plan counts what docs/benchmarks.md's matrix counts unless told otherwise; a
    commit the repository does not know would make every run on swarmd older (all of them
    planned again), so it is refused."""
    docs = tmp_path / "b.md"
    command = "flight_report --matrix d --since-commit abc1234 --write-docs b.md"
    docs.write_text(f"{fm.BEGIN}\nGenerated by `{command}`; ...\n{fm.END}\n")
    assert fm.documented_since(docs) == fm.Since("abc1234")
    docs.write_text("no block\n")
    assert fm.documented_since(docs) is None
    assert fm.documented_since(tmp_path / "absent.md") is None
    assert fm.documented_since(fc.DOCS) is not None  # the repository's own matrix names one
    base = ["--swarmd-out", str(tmp_path / "a"), "--stock-out", str(tmp_path / "b")]
    with pytest.raises(SystemExit) as stop:
        fc.main([*base, "--since-commit", "0123456789abcdef"])
    assert stop.value.code == 2
    assert "not a commit" in capsys.readouterr().err
