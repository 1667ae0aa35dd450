"""The flight campaign's plan and runner (bench/wifi/flight_campaign.py), with a stand-in
for flight_run: no testbed, no ns-3."""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import pytest

from bench.wifi import flight_campaign as fc
from bench.wifi import flight_schedule
from bench.wifi.flight_run import run_file_name

# a stand-in for `python -m bench.wifi.flight_run`: writes the run file the real one would
# (or fails when the contender is "zenoh"), and records its argv
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
(runs / name).write_text("{{}}")
"""


@pytest.fixture(autouse=True)
def _quick_polls(monkeypatch: pytest.MonkeyPatch) -> None:
    # the stand-in ends in well under a second: look at it often, not every POLL_S
    monkeypatch.setattr(flight_schedule, "POLL_S", 0.05)


def _cells(tmp_path: Path, **kw: object) -> list[fc.Cell]:
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


def test_a_cell_with_a_run_file_is_done_and_leaves_the_plan(tmp_path: Path) -> None:
    cells = _cells(tmp_path, repeats=1, sizes=(10,))
    first = cells[0]
    first.path.parent.mkdir(parents=True)
    first.path.write_text("{}")
    lines = fc.plan_lines(_cells(tmp_path, repeats=1, sizes=(10,)))
    assert lines[0].startswith("flight campaign: 1 of 4 cells have a run file; 3 missing")
    assert not any(first.path.name in line for line in lines)


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
    with pytest.raises(SystemExit) as stop:
        fc.main([*base, "--run"])
    assert stop.value.code == 2
    with pytest.raises(SystemExit):
        fc.main([*base, "--contenders", "opendds"])
    assert "no flight observer" in capsys.readouterr().err
