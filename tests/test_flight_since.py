"""A per-contender ``--since-commit`` (``flight_cells.Since``): ROS 2 on swarmd judged at the
relay as shipped while swarmd keeps the engine's commit. One rule for the matrix
(``flight_report --matrix``), the campaign's plan (``flight_campaign``) and the docs' block
that the campaign reads it back from (``documented_since``)."""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest

from bench.wifi import flight_campaign as fc
from bench.wifi import flight_matrix as fm
from bench.wifi import flight_report
from tests.test_flight_campaign import _cells, _plan, _record, _write
from tests.test_flight_report_matrix import files, record

RELAY_FIX = fm.Since("mid", (("ros2-swarmd", "new"),))


def _after(since: str, made: str) -> bool:
    """A stand-in history old < mid < new: ``made`` is ``since`` or after it."""
    order = ("old", "mid", "new")
    return order.index(made[:3]) >= order.index(since)


def _counts(since: fm.Since) -> fm.Counts:
    return lambda contender, made: (at := since.of(contender)) is None or _after(at, made)


def test_parse_reads_a_default_and_a_contender_of_its_own() -> None:
    since = fm.parse_since(["7312581", "ros2-swarmd=4de1f9f"])
    assert since == fm.Since("7312581", (("ros2-swarmd", "4de1f9f"),))
    assert since is not None
    assert (since.of("swarmd"), since.of("ros2-swarmd"), since.of("zenoh")) == (
        "7312581", "4de1f9f", None,
    )  # fmt: skip
    assert fm.parse_since(since.args()) == since  # the spelling reads back
    assert str(since) == "7312581, ros2-swarmd=4de1f9f"
    assert since.commits() == ["7312581", "4de1f9f"]
    # a contender's own alone: swarmd's runs count at any commit
    alone = fm.parse_since(["ros2-swarmd=4de1f9f"])
    assert alone is not None and alone.of("swarmd") is None
    assert fm.parse_since([]) is None
    # the order given does not matter: the contenders go in ON_SWARMD's order
    two = fm.parse_since(["ros2-swarmd=b", "swarmd-paper=a"])
    assert two is not None and two.own == (("swarmd-paper", "a"), ("ros2-swarmd", "b"))


@pytest.mark.parametrize(
    ("values", "why"),
    [
        (["a", "b"], "second default"),
        (["ros2-swarmd=a", "ros2-swarmd=b"], "named twice"),
        (["zenoh=a"], "not a contender on swarmd"),  # would be ignored without a word
        (["ros2-swarmd="], "not C or CONTENDER=C"),
        (["=a"], "not C or CONTENDER=C"),
        ([""], "not C or CONTENDER=C"),
    ],
)
def test_parse_refuses_what_would_be_ambiguous_or_ignored(values: list[str], why: str) -> None:
    with pytest.raises(ValueError, match=why):
        fm.parse_since(values)


def test_a_contenders_own_since_holds_for_it_alone() -> None:
    """ROS 2 on swarmd's runs of the old relay (after the engine's commit) are left out;
    swarmd's at the same commit count; a stock stack's count at any commit."""
    runs = files(
        record(commit="mid0000000"),
        record(run=2, commit="old0000000"),
        record(contender="ros2-swarmd", commit="mid0000000"),
        record(contender="ros2-swarmd", run=2, commit="new0000000"),
        record(contender="ros2-swarmd", run=3, commit="old0000000"),
        record(contender="zenoh", commit="old0000000"),
    )
    sel = fm.select(runs, _counts(RELAY_FIX))
    assert [(f.run["contender"], f.run["run"]) for f in sel.runs] == [
        ("swarmd", 1), ("ros2-swarmd", 2), ("zenoh", 1),
    ]  # fmt: skip
    assert sorted((f.run["contender"], f.run["run"]) for f in sel.older) == [
        ("ros2-swarmd", 1), ("ros2-swarmd", 3), ("swarmd", 2),
    ]  # fmt: skip
    text = fm.block(runs, command="cmd", docs_dir=Path("/nowhere"),
                    counts=_counts(RELAY_FIX), since=RELAY_FIX)  # fmt: skip
    assert "Which runs on swarmd count (`--since-commit mid --since-commit ros2-swarmd=new`" in text
    assert (
        "- swarmd: runs at `mid` or after (the engine as shipped); left out, older: 1 run file(s)"
        in text
    )
    assert (
        "- ROS 2 on swarmd: runs at `new` or after (its own, `ros2-swarmd=new`); left out, "
        "older: 2 run file(s)" in text
    )
    assert "The 3 older run file(s) left out:" in text
    assert (
        "- `mid0000000`: 1 run file(s), 2026-11-26 18:11 UTC (ros2-swarmd N=10: split r1)"
        in (text.split("left out:")[1])
    )
    # only the contender's own: swarmd at any commit
    alone = fm.Since(None, (("ros2-swarmd", "new"),))
    assert len(fm.select(runs, _counts(alone)).older) == 2
    assert "- swarmd: runs at any commit; left out, older: 0" in fm.block(
        runs, command="cmd", docs_dir=Path("/nowhere"), counts=_counts(alone), since=alone
    )


def _history(tmp_path: Path) -> list[str]:
    """A repository of three commits; their short names, oldest first."""

    def git(*args: str) -> str:
        return subprocess.run(
            ["git", "-C", str(tmp_path), *args], check=True, capture_output=True, text=True
        ).stdout.strip()

    git("init", "-q")
    out = []
    for m in ("old", "mid", "new"):
        git("-c", "user.name=t", "-c", "user.email=t@t", "commit", "-q", "--allow-empty", "-m", m)
        out.append(git("rev-parse", "--short=10", "HEAD"))
    return out


def test_since_counts_follows_the_history_per_contender(tmp_path: Path) -> None:
    old, mid, new = _history(tmp_path)
    counts = fm.since_counts(fm.Since(mid, (("ros2-swarmd", new),)), tmp_path)
    assert counts is not None
    assert counts("swarmd", mid) and not counts("swarmd", old)
    assert counts("ros2-swarmd", new + "+dirty") and not counts("ros2-swarmd", mid)
    assert counts("zenoh", old)
    assert fm.since_counts(None, tmp_path) is None
    # a contender's own since before the default would count runs of an older engine
    with pytest.raises(ValueError, match=f"ros2-swarmd={old}: before the default {mid}"):
        fm.since_counts(fm.Since(mid, (("ros2-swarmd", old),)), tmp_path)
    with pytest.raises(ValueError, match="not a commit"):
        fm.since_counts(fm.Since(mid, (("ros2-swarmd", "0123456789"),)), tmp_path)


def test_the_report_takes_the_spelling_and_refuses_a_wrong_one(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    head = subprocess.run(
        ["git", "rev-parse", "--short", "HEAD"],  # noqa: S607
        capture_output=True, text=True, check=True, cwd=Path(__file__).parent,
    ).stdout.strip()  # fmt: skip
    argv = ["--matrix", str(tmp_path), "--since-commit", head]
    assert flight_report.main([*argv, "--since-commit", f"ros2-swarmd={head}"]) == 0
    assert f"(its own, `ros2-swarmd={head}`)" in capsys.readouterr().out
    assert flight_report.main([*argv, "--since-commit", f"cyclonedds={head}"]) == 2
    assert "not a contender on swarmd" in capsys.readouterr().err


def _docs(tmp_path: Path, command: str) -> Path:
    docs = tmp_path / "b.md"
    docs.write_text(f"{fm.BEGIN}\nGenerated by `{command}`; ...\n{fm.END}\n")
    return docs


def test_documented_since_reads_every_since_the_block_names(tmp_path: Path) -> None:
    base = "python -m bench.wifi.flight_report --matrix d"
    both = f"{base} --since-commit abc1234 --since-commit ros2-swarmd=def5678 --write-docs b.md"
    assert fm.documented_since(_docs(tmp_path, both)) == fm.Since(
        "abc1234", (("ros2-swarmd", "def5678"),)
    )
    eq = f"{base} --since-commit=ros2-swarmd=def5678"  # argparse's other spelling
    assert fm.documented_since(_docs(tmp_path, eq)) == fm.Since(None, (("ros2-swarmd", "def5678"),))
    # the repository's own block names ROS 2 on swarmd's relay as shipped
    ours = fm.documented_since(fc.DOCS)
    assert ours is not None and ours.of("ros2-swarmd") != ours.of("swarmd")


def test_the_docs_round_trip_keeps_the_since(tmp_path: Path) -> None:
    """The block written with a since names it in its command; the campaign reads it back."""
    docs = tmp_path / "b.md"
    docs.write_text(f"{fm.SECTION}\n\nintro\n")
    command = (
        ".venv/bin/python -m bench.wifi.flight_report --matrix d --since-commit mid "
        "--since-commit ros2-swarmd=new --write-docs b.md"
    )
    runs = files(record(contender="ros2-swarmd", commit="mid0000000"))
    fm.write_docs(docs, fm.block(runs, command=command, docs_dir=tmp_path,
                                 counts=_counts(RELAY_FIX), since=RELAY_FIX))  # fmt: skip
    assert fm.documented_since(docs) == RELAY_FIX


def test_the_plan_counts_each_contender_from_its_own_since(tmp_path: Path) -> None:
    """The campaign plans again the cells of ROS 2 on swarmd whose runs are of the old
    relay, not swarmd's at the same commit, and says which since it counts from."""
    three = dict(repeats=1, sizes=(10,), scenarios=("split",),
                 contenders=("swarmd", "ros2-swarmd", "cyclonedds"))  # fmt: skip
    for c in _cells(tmp_path, **three):
        _write(c.path, _record(c, commit="mid0000000"))
    found = _plan(tmp_path, **three, counts=_counts(RELAY_FIX), since=RELAY_FIX)
    assert [(c.contender, c.repeat) for c in found.cells] == [("ros2-swarmd", 2)]
    assert {h.contender: h.status for h in found.held} == {
        "swarmd": fc.VALID, "ros2-swarmd": fc.OLDER, "cyclonedds": fc.VALID,
    }  # fmt: skip
    lines = fc.plan_lines(found)
    assert "runs on swarmd from mid on; ros2-swarmd from new on" in lines[0]
    assert any("older: made at mid0000000, before its --since-commit" in x for x in lines)


def test_the_campaign_takes_the_docs_since_unless_told(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    _, mid, new = _history(tmp_path)
    monkeypatch.setattr(fc, "REPO", tmp_path)
    monkeypatch.setattr(
        fc, "DOCS",
        _docs(tmp_path, f"x --matrix d --since-commit {mid} --since-commit ros2-swarmd={new}"),
    )  # fmt: skip
    cells = _cells(tmp_path, repeats=1, sizes=(10,), scenarios=("split",),
                   contenders=("swarmd", "ros2-swarmd"), swarmd_out=tmp_path / "d",
                   stock_out=tmp_path / "d")  # fmt: skip
    for c in cells:
        _write(c.path, _record(c, commit=mid))
    out = str(tmp_path / "d")
    base = ["--swarmd-out", out, "--stock-out", out, "--n", "10", "--scenarios", "split",
            "--contenders", "swarmd,ros2-swarmd", "--repeats", "1"]  # fmt: skip
    assert fc.main(base) == 0
    out = capsys.readouterr().out
    assert f"ros2-swarmd from {new} on" in out and "1 to run" in out
    assert fc.main([*base, "--since-commit", mid]) == 0  # told: the docs' are not read
    assert "0 to run" in capsys.readouterr().out
    assert fc.main([*base, "--since-commit", "any"]) == 0
    assert "runs of every commit" in capsys.readouterr().out
    with pytest.raises(SystemExit):
        fc.main([*base, "--since-commit", "any", "--since-commit", mid])
    assert "alone" in capsys.readouterr().err
