"""A kept decision's time is bounded where the state file is read (session 15).

The state file keeps the member's decisions with the Unix time each was received
(``decisions``, docs/dataplane.md, "Outcomes across a restart"). Its check took any finite
number, so a hand-edited or damaged ``1e300`` (or a time years ahead) was restored and
only ``swarmctl outcomes``' view was hardened against it; NaN or infinity dropped every
kept decision with it. Now each decision whose time cannot be right (NaN, infinite,
negative, later than the wall clock by more than ``DECISION_CLOCK_SLACK_S``; its answer's
likewise) is dropped alone and counted, the rest kept, one log line; and its
(commander, id) stays in the executed set, added if missing, so the command never runs
twice (the time is wrong, the id is not). Each test fails on main.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import structlog
from structlog.testing import capture_logs

from swarmd import statefile
from swarmd.auth.keys import KeyRing
from swarmd.bundle.loader import load_bundle
from swarmd.config import load_config
from swarmd.daemon_setup import load_node_secrets
from swarmd.statefile import DECISION_CLOCK_SLACK_S
from swarmd.swarm.commander import KeptDecision
from swarmd.swarmapp import SwarmApp
from tests.daemon_support import loopback_config, run_domain, run_swarmd, write_bundle

WALL_NOW = 1_790_000_000.0  # the wall clock at load, fixed


def _entry(command_id: int, received_at: Any, done_s: Any = 0.5) -> list[Any]:
    return [3, "lead", command_id, "hold", "completed", "", received_at, done_s]


def _write(path: Path, executed: list[list[Any]], decisions: list[Any]) -> None:
    body = {"boot": 3, "executed": executed, "decisions": decisions}
    # json.dumps writes NaN and Infinity as Python's json.loads reads them back
    path.write_text(json.dumps(body), "utf-8")


BAD = [
    _entry(2, float("nan")),
    _entry(3, float("inf")),
    _entry(4, -1.0),
    _entry(5, 1e300),
    _entry(6, 10**400),  # an integer past a double: json.loads gives an int
    _entry(7, WALL_NOW + DECISION_CLOCK_SLACK_S + 1.0),
    _entry(8, WALL_NOW - 10.0, float("nan")),
    _entry(9, WALL_NOW - 10.0, -0.5),
    _entry(10, WALL_NOW, DECISION_CLOCK_SLACK_S + 1.0),  # its answer after the slack
]
GOOD = [
    _entry(1, WALL_NOW - 3600.0),
    _entry(11, WALL_NOW + DECISION_CLOCK_SLACK_S - 1.0, None),  # a clock behind, in slack
    _entry(12, 0.0, 1.0),  # 1970: a clock at zero wrote it; a time, and shown as one
]


def test_each_decision_with_an_impossible_time_is_dropped_alone(tmp_path: Path) -> None:
    path = statefile.state_path(tmp_path, "m01")
    executed = [["lead", i] for i in range(1, 13)]
    _write(path, executed, [GOOD[0], *BAD, *GOOD[1:]])
    state = statefile.load(path, WALL_NOW)
    assert [d.command_id for d in state.decisions] == [1, 11, 12]
    assert state.decisions_dropped == len(BAD)
    assert state.decisions_problem is not None and "0x2" in state.decisions_problem
    assert state.recovered_from is None  # nothing else of the file is lost
    assert state.executed == [("lead", i) for i in range(1, 13)]  # every id, once
    assert state.decision_ids_kept == 0


def test_a_dropped_decisions_id_is_kept_as_executed(tmp_path: Path) -> None:
    """A decision whose id the executed list lacks (the file edited, or written by a build
    that evicted it): its time is dropped, its id is added, so that command is refused
    as already run, never run twice; ``boot`` writes the id back."""
    path = statefile.state_path(tmp_path, "m01")
    _write(path, [["lead", 1]], [GOOD[0], _entry(5, 1e300), _entry(1, float("nan"))])
    state = statefile.load(path, WALL_NOW)
    assert state.executed == [("lead", 1), ("lead", 5)]
    assert (state.decisions_dropped, state.decision_ids_kept) == (2, 1)
    booted = statefile.boot(tmp_path, "m01", wall_now=WALL_NOW)
    body = json.loads(path.read_text("utf-8"))
    assert body["executed"] == [["lead", 1], ["lead", 5]]
    assert [d[2] for d in body["decisions"]] == [1]  # the dropped ones are not written back
    assert booted.boot == 4


def test_a_kept_decision_within_the_slack_round_trips(tmp_path: Path) -> None:
    path = statefile.state_path(tmp_path, "m01")
    kept = KeptDecision(3, "lead", 7, "hold", "completed", "", WALL_NOW + 60.0, 0.5)
    statefile.NodeState(path, 3, [("lead", 7)], [], [kept]).save()
    state = statefile.load(path, WALL_NOW)
    assert state.decisions == [kept] and state.decisions_dropped == 0


def _setup(workdir: Path) -> tuple[Path, Path]:
    files = write_bundle(workdir, 2, domain_id=run_domain() + 16)
    state = workdir / "state"
    state.mkdir(mode=0o700)
    cfg = loopback_config(
        workdir, files, extra=f"dataplane:\n  enabled: true\n  state_dir: {state}\n"
    )
    path = statefile.state_path(state, "uav1")
    now = 1_790_000_000.0  # any time today's clock is past
    # 10**400: on main, float() of it raised OverflowError out of the load (a traceback,
    # exit 1, from check-config and run alike)
    decisions = [_entry(1, now), _entry(5, 1e300), _entry(6, float("inf")), _entry(7, 10**400)]
    _write(path, [["uav2", 1]], decisions)
    return cfg, path


def test_check_config_warns_of_the_dropped_decisions_and_writes_nothing(workdir: Path) -> None:
    cfg, path = _setup(workdir)
    before = path.read_bytes()
    proc = run_swarmd("check-config", "--config", str(cfg), timeout_s=20.0)
    assert proc.returncode == 0, proc.stderr
    (warning,) = [line for line in proc.stderr.splitlines() if "dropped" in line]
    assert warning.startswith("swarmd: warning: ") and "3 earlier decision(s)" in warning
    assert "3 of them added" in warning
    assert path.read_bytes() == before


def test_run_drops_them_in_one_log_line_and_the_plane_keeps_their_ids(workdir: Path) -> None:
    """``run``'s start (``SwarmApp``'s data plane boot): one ``state_decisions_dropped``
    line; the plane's dedup set holds the dropped decisions' ids, so a copy of one of those
    commands is taken as already run."""
    cfg, path = _setup(workdir)
    config = load_config(cfg)
    bundle = load_bundle(config.bundle.path, config.bundle.trusted_key, allow_dev=True)
    secrets = load_node_secrets(config, bundle)
    keys = KeyRing.from_bundle(bundle, config.node, secrets)
    app = SwarmApp(
        config,
        bundle,
        log=structlog.get_logger(),
        link_q=lambda: 0.8,
        keys=keys,
        epoch=7,
        node_secrets=secrets,
    )
    with capture_logs() as logs:
        app._boot_dataplane()
    dropped = [e for e in logs if e["event"] == "state_decisions_dropped"]
    assert len(dropped) == 1 and (dropped[0]["dropped"], dropped[0]["ids_kept"]) == (3, 3)
    assert app.plane is not None and app.state is not None
    ids = {("uav2", 1), ("lead", 5), ("lead", 6), ("lead", 7)}
    assert set(app.plane.executed_command_ids) == ids
    assert [d.command_id for d in app.state.decisions] == [1]
    assert ["lead", 5] in json.loads(path.read_text("utf-8"))["executed"]
