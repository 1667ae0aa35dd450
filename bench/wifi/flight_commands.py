"""Command authority in flight on the testbed (issue 20): the operator's commands, issued
through the real ``swarmctl`` at the scenario's cues, checked against each member's own
journal and the scenario's ground truth.

What runs (``bench/wifi/flight_run.py`` calls ``prepare``, ``CommandScript.tick`` every
step, ``finish`` and ``collect`` at the end, ``attach`` on the run file):

- every drone gets a vehicle: a ``swarmd-vehicle-sim`` (the MAVLink simulator of
  ``lab/swarmd_lab/px4``, the lightest vehicle the daemon flies) in its namespace on
  loopback (``udpout:127.0.0.1:14540``, the daemon ``px4.connection: udpin:...:14540``, as
  PX4 SITL and ``tests/test_flight_netns.py``). Without one a member refuses every command
  (``px4_disabled``) and the commander refuses take-offs: nothing would be *executed*;
- at each ``flight.CommandCue`` the harness starts ``swarmctl <kind> --valid-for S --json``
  on the commander's control socket and keeps its final JSON (what the operator is told).

What is read afterwards, per command (the member's own records, docs/dataplane.md):

- the commander's journal line ``command_sent`` dates the issue (its ``timestamp``: the
  daemon's wall clock, which the harness and every daemon of the run share);
- each member's journal line ``command_received`` is the member deciding to run it (after
  the exactly-once check and the validity check, ``Member.execute``); ``command_expired``
  a copy refused as too late; ``command_outcome`` what it answered. A member's journal is
  one file over all its daemon lives (the harness appends on restart), so a command run
  again by a new life shows as a second ``command_received``.

Measures (pure: ``measure``), per (command, targeted member); ``reach`` from the ground
truth between the issue and the validity's end (the commander and the member in range and
both daemons up, ``flight_measures.reachable``): ``reachable`` if that held for at least
``REACH_MIN_S`` without a break, ``unreachable`` if it never held, else ``marginal``:

- ``executed_twice``: two or more ``command_received`` (target 0);
- ``executed_late``: a ``command_received`` after issue + validity (+ ``LATE_TOLERANCE_S``,
  the stamping delay of a log line) (target 0);
- ``reported_unreachable_but_reachable``: swarmctl said ``unreachable`` for a member that
  was ``reachable`` (target 0);
- ``unreached_not_reported``: a member ``unreachable`` throughout the validity that did not
  run it in time and that swarmctl did not report ``unreachable`` or ``refused``, nor
  ``rejected`` by a member whose journal has the copy refused as too late
  (``command_expired``: it reached the member after its validity, did not run, and the
  operator was told) (target 0);
- ``reported_ran_not_executed``: swarmctl said ``accepted``/``completed`` and the member's
  journal has no ``command_received`` (target 0);
- ``reachable_not_executed``: reachable members that did not run it (the delivery gap);
- ``restarted_not_resent``: members whose daemon restarted while the command was valid,
  reported ``unreachable`` and not run: the copy for the earlier life is not handed to the
  new one (it may have run there: exactly once first; docs/dataplane.md), by design, not
  counted as a false ``unreachable`` or a delivery gap;
- ``ran_while_truth_out_of_range``: members the truth has ``unreachable`` that ran it in time
  (reached in a window shorter than the truth's step): not counted as unreported;
- ``delivery_latency_s``: issue to ``command_received`` at the members that were reachable.
"""

from __future__ import annotations

import json
import subprocess
import sys
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path
from typing import IO, Any, Final

from swarmd_lab.netns import Namespace

from bench.wifi import flight, flight_measures
from bench.wifi.flight_measures import Interval, Truth

PX4_CONNECTION: Final = "udpin:127.0.0.1:14540"
SIM_CONNECT: Final = "udpout:127.0.0.1:14540"
REACH_MIN_S: Final = 3.0  # re-discovery (issue 20's target: 2 s) and a readiness period (1 s)
LATE_TOLERANCE_S: Final = 0.05  # a journal line is stamped after the decision it records
# swarmctl waits for the outcomes until the validity and the commander's grace for late
# answers (swarmd.swarm.commander.UNREACHABLE_GRACE_S) end; then this much for the
# take-off's climb or the land to be confirmed
FOLLOW_S: Final = 15.0
FINISH_CAP_S: Final = 60.0  # at most this long waiting for swarmctl after the window
JOURNAL_EVENTS: Final = frozenset(
    {"command_sent", "command_received", "command_expired", "command_outcome"}
)
VEHICLE_EVENTS: Final = frozenset({"armed", "disarmed", "mode"})
REPORTED_UNREACHED: Final = frozenset({"unreachable", "refused"})
# a member that got the copy after its validity refuses it (``command_expired``) and
# answers; swarmctl shows that answer as ``rejected``: the operator is told it did not run
REPORTED_LATE: Final = "rejected"
REPORTED_RAN: Final = frozenset({"accepted", "completed"})


def px4_section() -> str:
    """The ``px4:`` section every flight daemon gets (its simulator on loopback)."""
    return f"px4:\n  enabled: true\n  connection: {PX4_CONNECTION}\n  takeoff_alt_m: 5\n"


def start_vehicles(
    drones: Sequence[Namespace], work: Path, env: Mapping[str, str], seed: int
) -> list[IO[bytes]]:
    """One ``swarmd-vehicle-sim`` per drone namespace (stopped with the namespace's other
    children); the log files, for the caller to close."""
    logs: list[IO[bytes]] = []
    for i, drone in enumerate(drones):
        log = (work / f"uav{i + 1}-vehicle.log").open("wb")
        logs.append(log)
        drone.popen(
            [
                sys.executable, "-m", "swarmd_lab.px4.vehicle_sim", "--connect", SIM_CONNECT,
                "--sysid", str(i + 1), "--seed", str(seed * 100 + i), "--gps-fix-after", "1",
                "--json-log",
            ],
            env=env, stdout=log, stderr=subprocess.STDOUT,
        )  # fmt: skip
    return logs


@dataclass
class Issued:
    """One cue's swarmctl: when it was started (seconds since the release), its process."""

    cue: flight.CommandCue
    started_s: float
    argv: list[str]
    proc: subprocess.Popen[bytes]
    out: Path


@dataclass
class CommandScript:
    """Issues a scenario's commands through ``swarmctl`` on the commander's socket."""

    cues: Sequence[flight.CommandCue]
    commander: Namespace
    sock: Path
    names: Sequence[str]
    work: Path
    env: Mapping[str, str]
    real_s: Callable[[float], float]  # experiment seconds -> real (dilation)
    issued: list[Issued] = field(default_factory=list)
    vehicle_logs: list[IO[bytes]] = field(default_factory=list)
    _pending: list[flight.CommandCue] = field(default_factory=list)

    def __post_init__(self) -> None:
        self._pending = sorted(self.cues, key=lambda c: c.t)

    def argv(self, cue: flight.CommandCue) -> list[str]:
        timeout = cue.valid_for_s + 2.0 + FOLLOW_S  # experiment seconds (swarmctl is dilated)
        only = ["--only", *(self.names[i] for i in cue.only)] if cue.only else []
        return [
            sys.executable, "-m", "swarmd.cli.swarmctl", cue.kind, "--socket", str(self.sock),
            "--valid-for", f"{cue.valid_for_s:g}", "--timeout", f"{timeout:g}", "--json", *only,
        ]  # fmt: skip

    def tick(self, t: float) -> None:
        """Start every cue due at ``t`` (seconds since the release)."""
        while self._pending and t >= self._pending[0].t:
            cue = self._pending.pop(0)
            k = len(self.issued) + 1
            out = self.work / f"swarmctl-{k}.json"
            argv = self.argv(cue)
            with out.open("wb") as f, (self.work / f"swarmctl-{k}.log").open("wb") as err:
                proc = self.commander.popen(argv, env=self.env, stdout=f, stderr=err)
            self.issued.append(Issued(cue, round(t, 3), argv, proc, out))

    def finish(self, clock: Callable[[], float]) -> None:
        """Wait for every swarmctl to print its final JSON (bounded; a stuck one is killed
        and recorded without a report)."""
        deadline = clock() + self.real_s(FINISH_CAP_S)
        for it in self.issued:
            try:
                it.proc.wait(timeout=max(0.1, deadline - clock()))
            except subprocess.TimeoutExpired:
                it.proc.kill()
                it.proc.wait(timeout=10)
        for log in self.vehicle_logs:
            log.close()

    def records(self, go_wall: float) -> list[dict[str, Any]]:
        """``collect`` over this run's swarmctl reports and the daemons' journals."""
        journals = [journal(self.work / f"{name}.log") for name in self.names]
        return collect(self.reports(), journals, self.names, go_wall)

    def vehicles(self, go_wall: float) -> dict[str, list[list[Any]]]:
        """What each simulator did, ``[t since go, event, new mode]`` (``armed``,
        ``disarmed``, ``mode``): the vehicle's side of an executed command."""
        return {
            str(i): vehicle_events(self.work / f"{name}-vehicle.log", go_wall)
            for i, name in enumerate(self.names)
        }

    def reports(self) -> list[dict[str, Any]]:
        out = []
        for it in self.issued:
            try:
                report: Any = json.loads(it.out.read_text() or "null")
            except (OSError, ValueError):
                report = None
            out.append(
                {
                    "t": it.cue.t,
                    "started_s": it.started_s,
                    "kind": it.cue.kind,
                    "valid_for_s": it.cue.valid_for_s,
                    "only": list(it.cue.only),
                    "why": it.cue.why,
                    "argv": it.argv[2:],
                    "exit_code": it.proc.returncode,
                    "report": report if isinstance(report, dict) else None,
                }
            )
        return out


def prepare(
    contender: Any,
    scenario: flight.Scenario,
    work: Path,
    env: Mapping[str, str],
    real_s: Callable[[float], float],
) -> CommandScript | None:
    """Vehicles and the command script for a swarmd contender (call before it starts);
    None for a stack without swarmd's commands."""
    from bench.wifi.contenders import SwarmdContender

    if not isinstance(contender, SwarmdContender) or not scenario.commands:
        return None
    contender.extra_config = px4_section()
    names = [f"uav{i + 1}" for i in range(scenario.n)]
    script = CommandScript(
        scenario.commands, contender.drones[0], contender.socks[0], names, work, env, real_s
    )
    script.vehicle_logs = start_vehicles(contender.drones, work, env, scenario.seed)
    return script


# -- the journals ----------------------------------------------------------------------------


def journal_wall(stamp: str) -> float:
    """A journal line's ``timestamp`` (structlog's ISO 8601, UTC) in seconds since the epoch."""
    return datetime.fromisoformat(stamp).timestamp()


def journal(path: Path) -> list[dict[str, Any]]:
    """The command lines of one daemon's JSON log (all its lives), each with ``wall``: its
    timestamp in seconds since the epoch. Other lines, and torn ones, are skipped."""
    out: list[dict[str, Any]] = []
    try:
        text = path.read_text(errors="replace")
    except OSError:
        return out
    for line in text.splitlines():
        start = line.find("{")
        if start < 0:
            continue
        try:
            rec = json.loads(line[start:])
        except ValueError:
            continue
        if not isinstance(rec, dict) or rec.get("event") not in JOURNAL_EVENTS:
            continue
        try:
            rec["wall"] = journal_wall(str(rec["timestamp"]))
        except (KeyError, ValueError):
            continue
        out.append(rec)
    return out


def vehicle_events(path: Path, go_wall: float) -> list[list[Any]]:
    """A vehicle simulator's JSON log: its ``armed``/``disarmed``/``mode`` lines."""
    out: list[list[Any]] = []
    try:
        lines = path.read_text(errors="replace").splitlines()
    except OSError:
        return out
    for line in lines:
        try:
            rec = json.loads(line)
            if not isinstance(rec, dict) or rec.get("event") not in VEHICLE_EVENTS:
                continue
            t = round(journal_wall(str(rec["timestamp"])) - go_wall, 3)
        except (KeyError, ValueError):
            continue
        out.append([t, rec["event"], rec.get("new")])
    return out


def collect(
    reports: Sequence[Mapping[str, Any]],
    journals: Sequence[Sequence[Mapping[str, Any]]],
    names: Sequence[str],
    go_wall: float,
) -> list[dict[str, Any]]:
    """One record per command the operator issued: its id, issue time (the commander's
    ``command_sent``; seconds since go), targets, what swarmctl reported per member, and
    per member the times of its ``command_received`` and ``command_expired`` lines."""
    index = {name: i for i, name in enumerate(names)}
    sent = {
        r.get("command_id"): r["wall"] - go_wall
        for r in (journals[0] if journals else ())
        if r["event"] == "command_sent"
    }
    out = []
    for rep in reports:
        body = rep.get("report") or {}
        cid = body.get("command_id")
        nodes = body.get("nodes") or {}
        record: dict[str, Any] = {
            k: rep[k] for k in ("t", "kind", "valid_for_s", "only", "why", "exit_code")
        }
        record["command_id"] = cid
        record["issued_s"] = None if cid not in sent else round(sent[cid], 3)
        targets = [index[n] for n in nodes if n in index]
        record["targets"] = sorted(targets)
        record["reported"] = {
            str(index[n]): str(v.get("state")) for n, v in nodes.items() if n in index
        }
        executed: dict[str, list[float]] = {}
        expired: dict[str, list[float]] = {}
        for i, lines in enumerate(journals):
            for r in lines:
                if cid is None or r.get("command_id") != cid:
                    continue
                if r["event"] == "command_received":
                    executed.setdefault(str(i), []).append(round(r["wall"] - go_wall, 3))
                elif r["event"] == "command_expired":
                    expired.setdefault(str(i), []).append(round(r["wall"] - go_wall, 3))
        record["executed"] = executed
        record["expired"] = expired
        out.append(record)
    return out


# -- the measures (pure) -----------------------------------------------------------------------


def reach(
    truth: Truth,
    down: Mapping[int, Sequence[Interval]],
    member: int,
    start: float,
    end: float,
    commander: int = 0,
) -> str:
    """``reachable`` | ``unreachable`` | ``marginal`` between ``start`` and ``end`` (module
    doc). The commander's own drone is reachable while its daemon is up."""
    if member == commander:
        samples = [(t, not any(a <= t < b for a, b in down.get(commander, ()))) for t, _ in truth]
    else:
        samples = flight_measures.reachable(truth, down, commander, member)
    inside = [(t, up) for t, up in samples if start <= t <= end]
    if not any(up for _, up in inside):
        return "unreachable"
    longest = max((b - a for a, b, up in flight_measures.spans(inside) if up), default=0.0)
    return "reachable" if longest >= REACH_MIN_S else "marginal"


def measure(
    commands: Sequence[Mapping[str, Any]],
    truth: Truth,
    down: Mapping[int, Sequence[Interval]],
) -> dict[str, Any]:
    """The command measures of one run (module doc); JSON-ready."""
    twice: list[list[Any]] = []
    late: list[list[Any]] = []
    false_unreachable: list[list[Any]] = []
    not_reported: list[list[Any]] = []
    ran_not_executed: list[list[Any]] = []
    reachable_missed: list[list[Any]] = []
    not_resent: list[list[Any]] = []
    ran_out_of_range: list[list[Any]] = []
    latency: list[float] = []
    pairs = 0
    classes = {"reachable": 0, "marginal": 0, "unreachable": 0}
    unissued = 0
    for c in commands:
        issued = c.get("issued_s")
        if issued is None:
            unissued += 1
            continue
        deadline = float(issued) + float(c["valid_for_s"])
        cid = c.get("command_id")
        for m in c["targets"]:
            pairs += 1
            ran = sorted(c["executed"].get(str(m), []))
            state = c["reported"].get(str(m))
            kind = reach(truth, down, m, float(issued), deadline)
            classes[kind] += 1
            if len(ran) >= 2:
                twice.append([cid, m, ran])
            if any(t > deadline + LATE_TOLERANCE_S for t in ran):
                late.append([cid, m, ran, round(deadline, 3)])
            in_time = [t for t in ran if t <= deadline + LATE_TOLERANCE_S]
            # the member's daemon started a new life while the command was valid: the copy
            # addressed to the earlier life is not handed to the new one (docs/dataplane.md,
            # "Rejoining while a command is valid": it may have run there) and the operator
            # is told `unreachable`; by design, counted apart
            restarted = any(a < deadline and b > float(issued) for a, b in down.get(m, ()))
            if restarted and state == "unreachable" and not ran:
                not_resent.append([cid, m])
            elif state == "unreachable" and kind == "reachable":
                false_unreachable.append([cid, m])
            # a member the truth has out of range that ran the command in time was reached (in
            # a window shorter than the truth's step, or below its -82 dBm edge): the report
            # that it ran is right
            told = state in REPORTED_UNREACHED or (
                state == REPORTED_LATE and bool(c.get("expired", {}).get(str(m)))
            )
            if kind == "unreachable" and not told and not in_time:
                not_reported.append([cid, m, state])
            if kind == "unreachable" and in_time:
                ran_out_of_range.append([cid, m])
            if state in REPORTED_RAN and not ran:
                ran_not_executed.append([cid, m, state])
            if kind == "reachable":
                if ran:
                    latency.append(ran[0] - float(issued))
                elif [cid, m] not in not_resent:
                    reachable_missed.append([cid, m, state])
    return {
        "commands": len(commands),
        "not_issued": unissued,
        "pairs": pairs,
        "reach": classes,
        "executed_twice": len(twice),
        "executed_late": len(late),
        "reported_unreachable_but_reachable": len(false_unreachable),
        "unreached_not_reported": len(not_reported),
        "reported_ran_not_executed": len(ran_not_executed),
        "reachable_not_executed": len(reachable_missed),
        "restarted_not_resent": len(not_resent),
        "ran_while_truth_out_of_range": len(ran_out_of_range),
        "delivery_latency_s": flight_measures._summary(latency),
        "examples": {
            "twice": twice[:10],
            "late": late[:10],
            "reported_unreachable_but_reachable": false_unreachable[:10],
            "unreached_not_reported": not_reported[:10],
            "reported_ran_not_executed": ran_not_executed[:10],
            "reachable_not_executed": reachable_missed[:10],
            "restarted_not_resent": not_resent[:10],
            "ran_while_truth_out_of_range": ran_out_of_range[:10],
        },
    }


def attach(
    record: dict[str, Any],
    commands: Sequence[Mapping[str, Any]],
    scenario: flight.Scenario,
    vehicles: Mapping[str, Any] | None = None,
) -> None:
    """Put the commands, the vehicles' events and the command measures in a run file's
    record (``down`` from it)."""
    down = {int(i): [(a, b) for a, b in v] for i, v in record.get("down", {}).items()}
    record["commands"] = list(commands)
    if vehicles is not None:
        record["vehicles"] = dict(vehicles)
    record["measures"]["commands"] = measure(commands, scenario.truth(), down)


def one_line(measures: Mapping[str, Any]) -> str:
    c = measures.get("commands")
    if not c:
        return ""
    lat = c["delivery_latency_s"]
    return (
        f"commands {c['commands']} ({c['pairs']} pairs): twice {c['executed_twice']}, "
        f"late {c['executed_late']}, unreachable-but-reachable "
        f"{c['reported_unreachable_but_reachable']}, unreached-not-reported "
        f"{c['unreached_not_reported']}, reachable-not-run {c['reachable_not_executed']}, "
        f"delivery p50 {lat['p50']} max {lat['max']} s"
    )
